"""Bad inputs at every entry point and the error each gives: the table in results/robustness.md.

    python -m tools.robustness --out results/robustness.md

Each case is what a user could type (task keywords through `suite.load` and `gymnasium.make`, arguments of
every `mjdrive` subcommand, files given as checkpoints and logs) with a fragment of the error it must give.
`tests/test_robustness.py` runs every case and fails if one is accepted, raises anything but the documented
error (a `ValueError`, `mjdrive.ConfigError` for keywords; on the command line one line and exit status 2)
or no longer names what is wrong. A second kind of case (`status` set) is a situation a command must handle
and go on: a damaged log, an interrupted run's leftovers, a signal, a task with no route completion. It must
end with that exit status, without a traceback, printing a line with the fragment.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import pickle
import sys
import tempfile
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FIXTURE_LOG = ROOT / "tests" / "data" / "waypoints-straight_7_00000.mcap"
MARKER = "payload_ran"  # the file a malicious checkpoint's payload would create


@dataclass(frozen=True)
class Case:
    entry: str  # entry point: suite.load, gymnasium.make, env.step, mjdrive SUBCOMMAND, ...
    shown: str  # the input as the user gave it
    expect: str  # a fragment of the error message (of a line printed, for a handled case)
    run: Callable[[], object]  # raises the error (or, for the CLI, returns its exit status)
    status: int | None = None  # a handled case: the exit status it must end with (None: a bad input)


@dataclass(frozen=True)
class Outcome:
    kind: str  # "error" (the documented kind), "handled" (a handled case as documented), "accepted" (no
    # error where one was due) or "crash" (anything else)
    message: str

    def expected(self, case: Case) -> bool:
        """The outcome the case documents, naming what it must."""
        return self.kind == ("error" if case.status is None else "handled") and case.expect in self.message


def _load(domain: str, task: str, **kwargs) -> Callable[[], object]:
    def run():
        from mjdrive import suite

        return suite.load(domain, task, kwargs)

    return run


def _load_env(domain: str, task: str, environment_kwargs: dict) -> Callable[[], object]:
    def run():
        from mjdrive import suite

        return suite.load(domain, task, {"random": 0}, environment_kwargs)

    return run


def _gym(env_id: str, **kwargs) -> Callable[[], object]:
    def run():
        import gymnasium

        import mjdrive  # noqa: F401  (registers the ids)

        return gymnasium.make(env_id, **kwargs)

    return run


def _step(action) -> Callable[[], object]:
    def run():
        from mjdrive import suite

        env = suite.load("waypoints", "straight", {"random": 0})
        env.reset()
        return env.step(action)

    return run


def _cli(*argv: str) -> Callable[[], object]:
    def run():
        from mjdrive.cli import main

        try:
            return main(list(argv))
        except SystemExit as stop:  # argparse's usage errors
            return stop.code

    return run


def _tool(name: str, *argv: str) -> Callable[[], object]:
    """`python -m tools.NAME ARGV...` in this process: its exit status (argparse's usage errors included)."""

    def run():
        import importlib

        from mjdrive.cli import run_reporting_errors

        module = importlib.import_module(f"tools.{name}")
        program, sys.argv[0] = sys.argv[0], f"{name}.py"  # argparse's prog, as `python -m tools.NAME` shows it
        try:
            return run_reporting_errors(f"{name}.py", lambda: module.main(list(argv)))
        except SystemExit as stop:  # argparse's usage errors
            return stop.code
        finally:
            sys.argv[0] = program

    return run


def _step_discrete(env_id: str, actions: str, action) -> Callable[[], object]:
    def run():
        import gymnasium

        import mjdrive  # noqa: F401  (registers the ids)

        env = gymnasium.make(env_id, actions=actions)
        env.reset(seed=0)
        try:
            return env.step(action)
        finally:
            env.close()

    return run


def _holding_live_part(folder: str, run: Callable[[], object]) -> Callable[[], object]:
    """`run` while this process holds the writer's lock on an unfinished log in `folder` (a run in progress)."""

    def wrapped():
        from mjdrive.run_folder import lock_part

        Path(folder).mkdir(exist_ok=True)
        descriptor = lock_part(os.open(Path(folder) / "waypoints-straight_5_00000.mcap.part", os.O_CREAT | os.O_WRONLY))
        try:
            return run()
        finally:
            os.close(descriptor)

    return wrapped


def _without_matplotlib(run: Callable[[], object]) -> Callable[[], object]:
    """`run` as if matplotlib were not installed."""

    def wrapped():
        saved = {name: module for name, module in sys.modules.items() if name.split(".")[0] == "matplotlib"}
        sys.modules.update({name: None for name in saved} | {"matplotlib": None})
        try:
            return run()
        finally:
            for name in [name for name in sys.modules if name.split(".")[0] == "matplotlib"]:
                del sys.modules[name]
            sys.modules.update(saved)

    return wrapped


def _drive_stopped(how: str) -> Callable[[], object]:
    """`mjdrive drive` under a fresh Xvfb display, stopped after 1.5 s by `how` (SIGINT, SIGTERM, or
    windowclose: its window destroyed with xdotool); its exit status, its stderr passed on."""

    def run():
        import signal
        import subprocess
        import time

        number = next(n for n in range(90, 200) if not Path(f"/tmp/.X{n}-lock").exists())
        server = subprocess.Popen(["Xvfb", f":{number}", "-screen", "0", "800x600x24", "-nolisten", "tcp"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        env = {**os.environ, "DISPLAY": f":{number}"}
        command = None
        try:
            while not Path(f"/tmp/.X11-unix/X{number}").exists():
                time.sleep(0.1)
            command = subprocess.Popen([sys.executable, "-m", "mjdrive.cli", "drive", "--task", "waypoints/straight",
                                        "--out", f"drive_{how}"], env=env, stdout=subprocess.DEVNULL,
                                       stderr=subprocess.PIPE, text=True)
            window = subprocess.run(["xdotool", "search", "--sync", "--name", "MuJoCo"], env=env, capture_output=True,
                                    text=True, timeout=120).stdout.split()[0]
            time.sleep(1.5)
            if how == "windowclose":
                subprocess.run(["xdotool", "windowclose", window], env=env, timeout=30)
            else:
                command.send_signal(getattr(signal, how))
            _, err = command.communicate(timeout=60)
            print(err, file=sys.stderr, end="")
            return command.returncode
        finally:
            if command is not None and command.poll() is None:
                command.kill()
                command.wait()
            server.terminate()
            server.wait(10)

    return run


def _schema_check(domain: str, task: str) -> Callable[[], object]:
    """Record an autopilot episode of `domain/task` and validate its JSON messages with jsonschema; prints
    what it validated; exit status 0 when every message matches its channel's schema, else 1."""

    def run():
        import json

        import jsonschema

        from mjdrive.envs import make_env
        from mjdrive.policies import make_policy
        from mjdrive.record import RecordEpisodes
        from mjdrive.record.reader import read_episode

        env = RecordEpisodes(make_env(domain, task, time_limit=3.0), "schema_logs")
        policy = make_policy("autopilot", env, 0)
        observation, info = env.reset(seed=0)
        done = False
        while not done:
            observation, _, terminated, truncated, info = env.step(policy(observation))
            done = terminated or truncated
        env.close()
        episode = read_episode(info["record_path"])
        counts, errors = {}, 0
        for topic, encoding in episode.message_encodings.items():
            if encoding == "json":
                schema = json.loads(episode.schemas[topic][2])
                validator = jsonschema.validators.validator_for(schema)(schema)
                messages = [json.loads(data) for _, data in episode.messages[topic]]
                counts[topic] = len(messages)
                errors += sum(1 for message in messages for _ in validator.iter_errors(message))
        nulls = sum(json.loads(data)["scenario"] is None for _, data in episode.messages["/ego/state"])
        scenario = json.loads(episode.schemas["/ego/state"][2])["properties"]["scenario"]["type"]
        print(f"{sum(counts.values())} messages of {len(counts)} JSON channels checked with jsonschema, {errors} "
              f"not matching their schema; /ego/state scenario is {scenario}, null in {nulls}")
        return 0 if errors == 0 else 1

    return run


class _Payload:
    """A pickle payload that would create MARKER when unpickled (a checkpoint must never run it)."""

    def __reduce__(self):
        return (Path(MARKER).touch, ())


def make_files(folder: Path) -> None:
    """The bad files the cases refer to (relative names, so that messages do not depend on the folder)."""
    import torch

    torch.save({"algo": "sac", "state": _Payload()}, folder / "evil.pt")  # a zip checkpoint, as shared ones are
    (folder / "evil.pkl.pt").write_bytes(pickle.dumps({"algo": "sac", "state": _Payload()}))  # a bare pickle
    (folder / "notes.pt").write_text("not a checkpoint\n")
    (folder / "empty.pt").write_bytes(b"")
    (folder / "folder.pt").mkdir()
    (folder / "notes.mcap").write_text("not a log\n")
    (folder / "cut.mcap").write_bytes(FIXTURE_LOG.read_bytes()[:2000])
    (folder / "empty_logs").mkdir()
    (folder / "a_file").write_text("x\n")
    (folder / "broken_map.yaml").write_text("crossroad: [\n")
    (folder / "broken.xodr").write_text("<OpenDRIVE><road")
    (folder / "scenario.xosc").write_text("<OpenSCENARIO/>\n")
    # checkpoints evaluated on tasks they were not trained on
    checkpoints = ROOT / "results" / "checkpoints"
    (folder / "waypoints_policy.pt").write_bytes((checkpoints / "ppo_features_straight.pt").read_bytes())
    (folder / "roundabout_policy.pt").write_bytes((checkpoints / "sac_features_roundabout.pt").read_bytes())
    _untrained_policy(folder / "urban_policy.pt", "urban/merge")
    # a finished log with 100 bytes flipped near its end (its summary section), and the same file intact
    data = FIXTURE_LOG.read_bytes()
    (folder / "damaged_logs").mkdir()
    flipped = bytes(b ^ 0xFF if len(data) - 200 <= i < len(data) - 100 else b for i, b in enumerate(data))
    (folder / "damaged_logs" / "damaged.mcap").write_bytes(flipped)
    (folder / "damaged_logs" / "intact.mcap").write_bytes(data)
    # an evaluation killed mid-episode: its logs folder holds only an unfinished log, whose writer is gone
    (folder / "killed_eval").mkdir()
    (folder / "killed_eval" / "waypoints-straight_10000_00000.mcap.part").write_bytes(data[:2000])


def _untrained_policy(path: Path, task: str) -> None:
    """A PPO policy.pt for `task` (features) that never trained: what eval reads, in a moment."""
    from mjdrive.agents.algorithms import agent_class
    from mjdrive.agents.checkpoints import save_checkpoint
    from mjdrive.agents.config import load_config
    from mjdrive.envs import make_env
    from mjdrive.suite import split_task

    config = {**load_config("ppo"), "task": task, "task_kwargs": {"observation": "features"}}
    env = make_env(*split_task(task), actions=config["actions"], **config["task_kwargs"])
    agent = agent_class("ppo")(config, env.observation_space, env.action_space)
    env.close()
    save_checkpoint(path, "ppo", config, {"actor_state_dict": agent.actor.state_dict()}, 0, {"inference_only": True})


def cases() -> list[Case]:
    """Every bad input, by entry point."""
    c = Case
    out = [
        # --- suite.load: task keywords -------------------------------------------------------------------
        c("suite.load", "waypoints/straight time_limit=-5", "time_limit=-5: must be > 0", _load("waypoints", "straight", time_limit=-5)),
        c("suite.load", "waypoints/straight time_limit=0", "time_limit=0: must be > 0", _load("waypoints", "straight", time_limit=0)),
        c("suite.load", "waypoints/straight time_limit=nan", "must be a finite number", _load("waypoints", "straight", time_limit=float("nan"))),
        c("suite.load", "waypoints/straight time_limit='20'", "time_limit='20': must be a number", _load("waypoints", "straight", time_limit="20")),
        c("suite.load", "waypoints/straight image_size=0", "image_size=0: must be >= 16", _load("waypoints", "straight", image_size=0)),
        c("suite.load", "waypoints/straight image_size=64.5", "image_size=64.5: must be an integer", _load("waypoints", "straight", image_size=64.5)),
        c("suite.load", "waypoints/straight waypoint_spacing=0", "waypoint_spacing=0: must be >= 0.5", _load("waypoints", "straight", waypoint_spacing=0)),
        c("suite.load", "waypoints/straight waypoint_spacing=-1", "waypoint_spacing=-1: must be >= 0.5", _load("waypoints", "straight", waypoint_spacing=-1)),
        c("suite.load", "waypoints/straight random='abc'", "random='abc': must be an integer", _load("waypoints", "straight", random="abc")),
        c("suite.load", "waypoints/straight random=-1", "random=-1: must be >= 0", _load("waypoints", "straight", random=-1)),
        c("suite.load", "waypoints/straight random=2**40", "must be >= 0 and <= 4294967295", _load("waypoints", "straight", random=2**40)),
        c("suite.load", "waypoints/straight random=True", "random=True: must be an integer", _load("waypoints", "straight", random=True)),
        c("suite.load", "waypoints/straight observation='lidar'", "must be one of 'features', 'camera'", _load("waypoints", "straight", observation="lidar")),
        c("suite.load", "waypoints/straight vehicle='truck'", "must be one of 'sedan', 'suv'", _load("waypoints", "straight", vehicle="truck")),
        c("suite.load", "waypoints/straight buildings='yes'", "buildings='yes': must be true or false", _load("waypoints", "straight", buildings="yes")),
        c("suite.load", "waypoints/straight start_noise=[1]", "must have 2 elements", _load("waypoints", "straight", start_noise=[1])),
        c("suite.load", "waypoints/straight start_noise=(-1, 0)", "element 0 (-1) must be >= 0", _load("waypoints", "straight", start_noise=(-1, 0))),
        c("suite.load", "waypoints/straight visible_waypoints=-1", "visible_waypoints=-1: must be >= 0", _load("waypoints", "straight", visible_waypoints=-1)),
        c("suite.load", "waypoints/straight physics_dt=0", "physics_dt=0: must be >= 0.0005", _load("waypoints", "straight", physics_dt=0)),
        c("suite.load", "waypoints/straight physics_dt=0.05", "physics_dt=0.05: must be >= 0.0005 and <= 0.01", _load("waypoints", "straight", physics_dt=0.05)),
        c("suite.load", "waypoints/straight physics_dt=0.003", "whole multiple of physics_dt=0.003", _load("waypoints", "straight", physics_dt=0.003)),
        c("suite.load", "waypoints/straight time_limt=20", "unknown keyword 'time_limt' for waypoints/straight (did you mean 'time_limit'?)", _load("waypoints", "straight", time_limt=20)),
        c("suite.load", "waypoints/straight town_blocks=(2, 2)", "unknown keyword 'town_blocks'", _load("waypoints", "straight", town_blocks=(2, 2))),
        c("suite.load", "waypoints/straight sensors=['lidar']", "element 'lidar' is not one of 'depth', 'segmentation', 'range'", _load("waypoints", "straight", sensors=["lidar"])),
        c("suite.load", "waypoints/straight sensors='depth,lidr'", "element 'lidr' is not one of 'depth', 'segmentation', 'range'", _load("waypoints", "straight", sensors="depth,lidr")),
        c("suite.load", "waypoints/straight sensors=['depth', 'depth']", "must not repeat an element", _load("waypoints", "straight", sensors=["depth", "depth"])),
        c("suite.load", "waypoints/straight sensors=1", "sensors=1: must be a list", _load("waypoints", "straight", sensors=1)),
        c("suite.load", "roundabout/d120 sensor_size=4", "sensor_size=4: must be >= 8 and <= 512 [px]", _load("roundabout", "d120", sensor_size=4)),
        c("suite.load", "roundabout/d120 sensor_size=1000", "sensor_size=1000: must be >= 8 and <= 512 [px]", _load("roundabout", "d120", sensor_size=1000)),
        c("suite.load", "roundabout/d120 range_rays=0", "range_rays=0: must be >= 1", _load("roundabout", "d120", range_rays=0)),
        c("suite.load", "roundabout/d120 range_max=0", "range_max=0: must be > 0", _load("roundabout", "d120", range_max=0)),
        c("suite.load", "roundabout/d120 sensor=['depth']", "unknown keyword 'sensor' for roundabout/d120 (did you mean 'sensors'?)", _load("roundabout", "d120", sensor=["depth"])),
        c("suite.load", "waypoints/random_routes town_blocks=(0, 3)", "element 0 (0) must be >= 1", _load("waypoints", "random_routes", town_blocks=(0, 3))),
        c("suite.load", "waypoints/random_routes town_blocks=3", "town_blocks=3: must be a list", _load("waypoints", "random_routes", town_blocks=3)),
        c("suite.load", "roundabout/d120 road_users={'car': -1}", "['car']=-1 must be >= 0", _load("roundabout", "d120", road_users={"car": -1})),
        c("suite.load", "roundabout/d120 road_users={'truck': 2}", "unknown key 'truck'", _load("roundabout", "d120", road_users={"truck": 2})),
        c("suite.load", "roundabout/d120 road_users=[3]", "must be a mapping", _load("roundabout", "d120", road_users=[3])),
        c("suite.load", "roundabout/d120 warmup=-5", "warmup=-5: must be >= 0", _load("roundabout", "d120", warmup=-5)),
        c("suite.load", "roundabout/d120 lanes=0", "lanes=0: must be >= 1", _load("roundabout", "d120", lanes=0)),
        c("suite.load", "roundabout/d120 frames=0", "frames=0: must be >= 1", _load("roundabout", "d120", frames=0)),
        c("suite.load", "roundabout/d120 exits=[4] arms=3", "exits=(4,): must be in 1..3", _load("roundabout", "d120", exits=[4], arms=3)),
        c("suite.load", "roundabout/d120 exits=[]", "exits=[]: must not be empty", _load("roundabout", "d120", exits=[])),
        c("suite.load", "roundabout/d120 exits=[1, 1]", "must not repeat an element", _load("roundabout", "d120", exits=[1, 1])),
        c("suite.load", "roundabout/d120 entries=[7]", "entries=(7,): arms are numbered 0..3", _load("roundabout", "d120", entries=[7])),
        c("suite.load", "roundabout/d120 radius=6 lanes=4", "leaves an island under 3 m", _load("roundabout", "d120", radius=6, lanes=4)),
        c("suite.load", "roundabout/d120 destination_offset=60", "must lie inside the arm", _load("roundabout", "d120", destination_offset=60)),
        c("suite.load", "roundabout/d120 off_route=0", "off_route=0: must be > 0", _load("roundabout", "d120", off_route=0)),
        c("suite.load", "roundabout/d120 collision_penalty=-1", "collision_penalty=-1: must be >= 0", _load("roundabout", "d120", collision_penalty=-1)),
        c("suite.load", "roundabout/d120 camera='rear'", "must be one of 'front', 'front_wide'", _load("roundabout", "d120", camera="rear")),
        c("suite.load", "roundabout/d120 destination_frame='car'", "must be one of 'world', 'ego'", _load("roundabout", "d120", destination_frame="car")),
        c("suite.load", "roundabout/d120 traffic_config={'min_gap': -1}", "min_gap=-1: must be >= 0.5", _load("roundabout", "d120", traffic_config={"min_gap": -1})),
        c("suite.load", "roundabout/d120 traffic_config={'min_gp': 3}", "unknown keyword 'min_gp' (did you mean 'min_gap'?)", _load("roundabout", "d120", traffic_config={"min_gp": 3})),
        c("suite.load", "roundabout/d120 traffic_config={'pedestrian_wait': [9, 1]}", "the minimum must not exceed the maximum", _load("roundabout", "d120", traffic_config={"pedestrian_wait": [9, 1]})),
        c("suite.load", "roundabout/d120 traffic_config=5", "must be a mapping of TrafficConfig keywords", _load("roundabout", "d120", traffic_config=5)),
        # --- maps as data, OpenDRIVE, junction control (urban tasks) -----------------------------------------
        c("suite.load", "urban/concatenated map={'order': ['crossroad', 'bridge']}", "element 'bridge' is not one of 'roundabout', 'road', 'crossroad', 'merge'", _load("urban", "concatenated", map={"order": ["crossroad", "bridge"]})),
        c("suite.load", "urban/concatenated map={'crossroad': {'lane_width': 6}}", "map.crossroad.lane_width=6: must be >= 2.5 and <= 5 [m]", _load("urban", "concatenated", map={"crossroad": {"lane_width": 6}})),
        c("suite.load", "urban/concatenated map={'roundabout': {'radiuss': 20}}", "map.roundabout: unknown keyword 'radiuss' (did you mean 'radius'?)", _load("urban", "concatenated", map={"roundabout": {"radiuss": 20}})),
        c("suite.load", "urban/concatenated map={'order': ['crossroad', 'merge'], 'crossroad': {'lane_width': 3}}", "lane widths 3.0 m and 3.5 m differ", _load("urban", "concatenated", map={"order": ["crossroad", "merge"], "crossroad": {"lane_width": 3}})),
        c("suite.load", "urban/merge map={'order': ['crossroad']}", "urban/merge needs the 'merge' piece in the order", _load("urban", "merge", map={"order": ["crossroad"]})),
        c("suite.load", "urban/concatenated map='missing_map.yaml'", "map: cannot read the file 'missing_map.yaml'", _load("urban", "concatenated", map="missing_map.yaml")),
        c("suite.load", "urban/concatenated map='broken_map.yaml' (a YAML syntax error)", "map: the file 'broken_map.yaml' is not YAML or JSON (line 2", _load("urban", "concatenated", map="broken_map.yaml")),
        c("suite.load", "urban/opendrive opendrive='missing.xodr'", "opendrive='missing.xodr': cannot read the file", _load("urban", "opendrive", opendrive="missing.xodr")),
        c("suite.load", "urban/opendrive opendrive='broken.xodr' (cut XML)", "opendrive='broken.xodr': not an XML file", _load("urban", "opendrive", opendrive="broken.xodr")),
        c("suite.load", "urban/opendrive opendrive='scenario.xosc' (OpenSCENARIO)", "the root element is <OpenSCENARIO>, not <OpenDRIVE>", _load("urban", "opendrive", opendrive="scenario.xosc")),
        c("suite.load", "urban/opendrive opendrive='four_way' route_points=[0, 0, 0]", "route_points=[0, 0, 0]: must have 4 elements, got 3", _load("urban", "opendrive", route_points=[0, 0, 0])),
        c("suite.load", "urban/crossroad opendrive='four_way'", "only urban/opendrive takes it", _load("urban", "crossroad", opendrive="four_way")),
        c("suite.load", "urban/crossroad junction_control='roundabout'", "must be one of 'give_way', 'stop', 'lights', 'map', 'random'", _load("urban", "crossroad", junction_control="roundabout")),
        c("suite.load", "urban/crossroad signals={'amber': 0}", "signals.amber=0: must be >= 1", _load("urban", "crossroad", signals={"amber": 0})),
        c("suite.load", "urban/crossroad collision_reward=5", "collision_reward=5: must be >= -100 and <= 0", _load("urban", "crossroad", collision_reward=5)),
        c("python -m tools.urban_traffic", "python -m tools.urban_traffic --map '{order: [bridge]}'", "argument --map: --map.order=['bridge']: element 'bridge' is not one of", _tool("urban_traffic", "--map", "{order: [bridge]}")),
        c("suite.load", "roundabout/d999", "unknown task roundabout/d999", _load("roundabout", "d999")),
        c("suite.load", "roundabout/d21", "did you mean roundabout/d210?", _load("roundabout", "d21")),
        c("suite.load", "highway/merge", "unknown domain 'highway'", _load("highway", "merge")),
        c("suite.load", "environment_kwargs control_timestep=0", "control_timestep=0: must be > 0", _load_env("waypoints", "straight", {"control_timestep": 0})),
        c("suite.load", "environment_kwargs time_limit=5", "unknown keyword 'time_limit'", _load_env("waypoints", "straight", {"time_limit": 5})),
        # --- gymnasium.make ----------------------------------------------------------------------------
        c("gymnasium.make", "mjdrive/Waypoints-Straight-v0 actions='table9'", "unknown action set 'table9'", _gym("mjdrive/Waypoints-Straight-v0", actions="table9")),
        c("gymnasium.make", "mjdrive/Waypoints-Straight-v0 render_mode='human'", "render_mode must be None or 'rgb_array'", _gym("mjdrive/Waypoints-Straight-v0", render_mode="human")),
        c("gymnasium.make", "mjdrive/Waypoints-Straight-v0 foo=1", "unknown keyword 'foo'", _gym("mjdrive/Waypoints-Straight-v0", foo=1)),
        c("gymnasium.make", "mjdrive/Roundabout-D120-v0 time_limit=0", "time_limit=0: must be > 0", _gym("mjdrive/Roundabout-D120-v0", time_limit=0)),
        c("gymnasium.make", "mjdrive/Roundabout-D120-v0 sensors=['lidar']", "element 'lidar' is not one of", _gym("mjdrive/Roundabout-D120-v0", sensors=["lidar"])),
        c("gymnasium.make", "mjdrive/Roundabout-D120-v0 neighbours=0", "neighbours=0: must be >= 1", _gym("mjdrive/Roundabout-D120-v0", neighbours=0)),
        # --- env.step -----------------------------------------------------------------------------------
        c("env.step", "action [nan, 0, 0]", "finite", _step(np.array([np.nan, 0.0, 0.0]))),
        c("env.step", "action of shape (2,)", "shape (3,)", _step(np.zeros(2))),
        # --- command line -------------------------------------------------------------------------------
        c("mjdrive", "mjdrive frobnicate", "invalid choice: 'frobnicate'", _cli("frobnicate")),
        c("mjdrive list", "mjdrive list --kwargs nope", "expected DOMAIN/TASK", _cli("list", "--kwargs", "nope")),
        c("mjdrive list", "mjdrive list --kwargs roundabout/d999", "unknown task roundabout/d999", _cli("list", "--kwargs", "roundabout/d999")),
        c("mjdrive run", "mjdrive run --task nope", "expected DOMAIN/TASK", _cli("run", "--task", "nope")),
        c("mjdrive run", "mjdrive run --task waypoints/nope", "unknown task waypoints/nope", _cli("run", "--task", "waypoints/nope")),
        c("mjdrive run", "mjdrive run --episodes 0", "argument --episodes: must be >= 1, got 0", _cli("run", "--episodes", "0")),
        c("mjdrive run", "mjdrive run --episodes two", "expected an integer, got 'two'", _cli("run", "--episodes", "two")),
        c("mjdrive run", "mjdrive run --seed -1", "argument --seed: must be in 0..4294967295", _cli("run", "--seed", "-1")),
        c("mjdrive run", "mjdrive run --policy fast", "argument --policy: invalid choice: 'fast'", _cli("run", "--policy", "fast")),
        c("mjdrive run", "mjdrive run --record-camera-every -1", "must be >= 0", _cli("run", "--record-camera-every", "-1")),
        c("mjdrive run", "mjdrive run --record-image-format gif", "invalid choice: 'gif'", _cli("run", "--record-image-format", "gif")),
        c("mjdrive run", "mjdrive run --task-kwarg time_limit", "--task-kwarg expects KEY=VALUE", _cli("run", "--task-kwarg", "time_limit")),
        c("mjdrive run", "mjdrive run --task-kwarg time_limt=3", "unknown keyword 'time_limt'", _cli("run", "--task-kwarg", "time_limt=3")),
        c("mjdrive run", "mjdrive run --task-kwarg random=abc", "random='abc': must be an integer", _cli("run", "--task-kwarg", "random=abc")),
        c("mjdrive run", "mjdrive run --task-kwarg start_noise=[1,\"a\"]", "element 1 ('a') must be a number", _cli("run", "--task-kwarg", 'start_noise=[1,"a"]')),
        c("mjdrive run", "mjdrive run --sensors lidar", "unknown sensor 'lidar'", _cli("run", "--sensors", "lidar")),
        c("mjdrive run", "mjdrive run --sensors depth --task-kwarg sensors=[\"range\"]", "give the sensors once", _cli("run", "--sensors", "depth", "--task-kwarg", 'sensors=["range"]')),
        c("mjdrive run", "mjdrive run --live-port 99999999", "argument --live-port: must be in 0..65535", _cli("run", "--live-port", "99999999")),
        c("mjdrive run", "mjdrive run --realtime -1", "argument --realtime: must be a finite number >= 0", _cli("run", "--realtime", "-1")),
        c("mjdrive drive", "mjdrive drive --task nope", "expected DOMAIN/TASK", _cli("drive", "--task", "nope")),
        c("mjdrive drive", "mjdrive drive --task-kwarg time_limit=0", "time_limit=0: must be > 0", _cli("drive", "--task-kwarg", "time_limit=0")),
        c("mjdrive train", "mjdrive train --workers -1", "argument --workers: must be in 0..1024", _cli("train", "--workers", "-1")),
        c("mjdrive eval", "mjdrive eval --workers -2", "argument --workers", _cli("eval", "--checkpoint", "notes.pt", "--workers", "-2")),
        c("mjdrive replay", "mjdrive replay missing.mcap", "missing.mcap: no such file", _cli("replay", "missing.mcap")),
        c("mjdrive replay", "mjdrive replay empty_logs (a folder)", "empty_logs is a folder, not a file", _cli("replay", "empty_logs")),
        c("mjdrive replay", "mjdrive replay notes.mcap (a text file)", "notes.mcap is not a readable MCAP file", _cli("replay", "notes.mcap")),
        c("mjdrive replay", "mjdrive replay cut.mcap (a truncated log)", "cut.mcap", _cli("replay", "cut.mcap")),
        c("mjdrive logs", "mjdrive logs nope/", "nope/: no such folder", _cli("logs", "nope/")),
        c("mjdrive logs", "mjdrive logs a_file", "a_file is a file, not a folder", _cli("logs", "a_file")),
        c("mjdrive logs", "mjdrive logs empty_logs", "no .mcap logs in empty_logs", _cli("logs", "empty_logs")),
        c("mjdrive bench", "mjdrive bench --seconds 0", "argument --seconds: must be a finite number > 0", _cli("bench", "--seconds", "0")),
        c("mjdrive bench", "mjdrive bench --tasks waypoints/nope", "unknown task waypoints/nope", _cli("bench", "--tasks", "waypoints/nope")),
        c("mjdrive bench", "mjdrive bench --roundabout d999", "invalid choice: 'd999'", _cli("bench", "--roundabout", "d999")),
        c("mjdrive bench", "mjdrive bench --image-size 4", "argument --image-size: must be in 16..1024", _cli("bench", "--image-size", "4")),
        c("mjdrive train", "mjdrive train --algo a2c", "argument --algo: invalid choice: 'a2c'", _cli("train", "--algo", "a2c")),
        c("mjdrive train", "mjdrive train --steps 0", "argument --steps: must be >= 1", _cli("train", "--steps", "0")),
        c("mjdrive train", "mjdrive train --num-envs 0", "argument --num-envs: must be in 1..1024", _cli("train", "--num-envs", "0")),
        c("mjdrive train", "mjdrive train --task roundabout/d1", "unknown task roundabout/d1", _cli("train", "--task", "roundabout/d1")),
        c("mjdrive eval", "mjdrive eval --checkpoint missing.pt", "missing.pt: no such file", _cli("eval", "--checkpoint", "missing.pt")),
        c("mjdrive eval", "mjdrive eval --checkpoint folder.pt (a folder)", "folder.pt is a folder", _cli("eval", "--checkpoint", "folder.pt")),
        c("mjdrive eval", "mjdrive eval --checkpoint notes.pt (a text file)", "notes.pt", _cli("eval", "--checkpoint", "notes.pt", "--episodes", "1", "--no-record")),
        c("mjdrive eval", "mjdrive eval --checkpoint empty.pt (an empty file)", "empty.pt", _cli("eval", "--checkpoint", "empty.pt", "--episodes", "1", "--no-record")),
        c("mjdrive eval", "mjdrive eval --checkpoint evil.pt (a pickle whose payload runs code)", "evil.pt", _cli("eval", "--checkpoint", "evil.pt", "--episodes", "1", "--no-record")),
        c("mjdrive eval", "mjdrive eval --checkpoint evil.pkl.pt (a bare pickle whose payload runs code)", "evil.pkl.pt", _cli("eval", "--checkpoint", "evil.pkl.pt", "--episodes", "1", "--no-record")),
        c("mjdrive eval", "mjdrive eval --episodes 0", "argument --episodes: must be >= 1", _cli("eval", "--checkpoint", "notes.pt", "--episodes", "0")),
        c("mjdrive ensemble", "mjdrive ensemble evil.pt notes.pt --out e.pt", "evil.pt", _cli("ensemble", "evil.pt", "notes.pt", "--out", "e.pt")),
        c("mjdrive ensemble", "mjdrive ensemble missing.pt --out e.pt", "missing.pt: no such file", _cli("ensemble", "missing.pt", "--out", "e.pt")),
        # --- the study tools (python -m tools.NAME) -------------------------------------------------------
        c("python -m tools.urban_table2", "python -m tools.urban_table2 --episodes 0", "argument --episodes: must be >= 1", _tool("urban_table2", "--episodes", "0")),
        c("python -m tools.urban_table2", "python -m tools.urban_table2 --workers -1", "argument --workers: must be >= 0", _tool("urban_table2", "--workers", "-1")),
        c("python -m tools.urban_difficulty", "python -m tools.urban_difficulty --policy bogus", "invalid choice: 'bogus'", _tool("urban_difficulty", "--policy", "bogus")),
        c("python -m tools.roundabout_table3", "python -m tools.roundabout_table3 --agent A missing.pt", "checkpoint missing.pt does not exist", _tool("roundabout_table3", "--agent", "A", "missing.pt")),
        c("python -m tools.roundabout_baselines", "python -m tools.roundabout_baselines --seed -1", "argument --seed: must be >= 0", _tool("roundabout_baselines", "--seed", "-1")),
        c("python -m tools.select_checkpoint", "python -m tools.select_checkpoint empty_logs", "no checkpoints/step_N.pt", _tool("select_checkpoint", "empty_logs")),
        c("python -m tools.urban_traffic", "python -m tools.urban_traffic --minutes 0", "argument --minutes: must be a finite number > 0", _tool("urban_traffic", "--minutes", "0")),
        c("python -m tools.urban_figures", "python -m tools.urban_figures (matplotlib not installed)", "this needs matplotlib, which is not installed: pip install 'mjdrive[plot]'", _without_matplotlib(_tool("urban_figures", "--time-limit", "1", "--out", "figures"))),
        # --- discrete action sets: an index, never a truncated float or a string ----------------------------
        c("env.step", "mjdrive/Waypoints-Straight-v0 actions='table2': step(2.5)", "action set 'table2': an action is an integer index in 0..26", _step_discrete("mjdrive/Waypoints-Straight-v0", "table2", 2.5)),
        c("env.step", "mjdrive/Waypoints-Straight-v0 actions='table1': step(6.9)", "action set 'table1': an action is an integer index in 0..3", _step_discrete("mjdrive/Waypoints-Straight-v0", "table1", 6.9)),
        c("env.step", "mjdrive/Waypoints-Straight-v0 actions='table2': step('3')", "got '3' (str)", _step_discrete("mjdrive/Waypoints-Straight-v0", "table2", "3")),
        c("env.step", "mjdrive/Roundabout-D120-v0 actions='roundabout7': step(np.float32(3.0))", "action set 'roundabout7': an action is an integer index in 0..6", _step_discrete("mjdrive/Roundabout-D120-v0", "roundabout7", np.float32(3.0))),
        c("env.step", "mjdrive/Roundabout-D120-v0 actions='roundabout7': step(np.array([3]))", "array of dtype int64, shape (1,)", _step_discrete("mjdrive/Roundabout-D120-v0", "roundabout7", np.array([3]))),
        c("env.step", "mjdrive/Roundabout-D120-v0 actions='roundabout7': step(7)", "action index must be in 0..6, got 7", _step_discrete("mjdrive/Roundabout-D120-v0", "roundabout7", 7)),
        # --- a checkpoint on a task it cannot run on: refused before anything is written ---------------------
        c("mjdrive eval", "mjdrive eval --checkpoint waypoints_policy.pt --task urban/concatenated", "cannot read that of urban/concatenated: no 'heading_error'", _cli("eval", "--checkpoint", "waypoints_policy.pt", "--task", "urban/concatenated", "--out", "never")),
        c("mjdrive eval", "mjdrive eval --checkpoint roundabout_policy.pt --task urban/roundabout", "with the task keyword exits=[1], which urban/roundabout does not take", _cli("eval", "--checkpoint", "roundabout_policy.pt", "--task", "urban/roundabout", "--out", "never")),
        c("mjdrive eval", "mjdrive eval --checkpoint waypoints_policy.pt --task-kwarg actions=pedal", "'actions' is not a task keyword", _cli("eval", "--checkpoint", "waypoints_policy.pt", "--task-kwarg", "actions=pedal", "--out", "never")),
        c("mjdrive train", "mjdrive train --task-kwarg actions=pedal", "'actions' is not a task keyword: the action set is the config's `actions`", _cli("train", "--task-kwarg", "actions=pedal", "--out", "never")),
        c("mjdrive eval", "mjdrive eval --checkpoint waypoints_policy.pt --out busy_ev (a running evaluation writes busy_ev/)", "is in use: a running process is writing", _holding_live_part("busy_ev", _cli("eval", "--checkpoint", "waypoints_policy.pt", "--episodes", "1", "--out", "busy_ev"))),
    ]  # fmt: skip
    out += handled_cases()
    return out


def handled_cases() -> list[Case]:
    """Situations a command must handle and go on from: (entry, what happened, a line it prints, run, status)."""
    c = Case
    return [
        c("mjdrive eval", "mjdrive eval --checkpoint urban_policy.pt --task urban/merge --episodes 1 (no route completion)", "| success % | collision % | avg reward | avg time (s) | avg speed (m/s) | avg distance (m) | avg steps |", _cli("eval", "--checkpoint", "urban_policy.pt", "--task", "urban/merge", "--episodes", "1", "--task-kwarg", "time_limit=1", "--no-record"), 0),
        c("mjdrive eval", "mjdrive eval --checkpoint waypoints_policy.pt --out killed_eval (its folder holds a killed run's .mcap.part)", "note: removed 1 unfinished log (waypoints-straight_10000_00000.mcap.part) left in killed_eval by an interrupted run", _cli("eval", "--checkpoint", "waypoints_policy.pt", "--episodes", "1", "--task-kwarg", "time_limit=1", "--record-dir", "killed_eval"), 0),
        c("mjdrive logs", "mjdrive logs damaged_logs (100 bytes flipped near the end of damaged.mcap)", "damaged.mcap is damaged: its summary section", _cli("logs", "damaged_logs"), 0),
        c("mjdrive logs", "mjdrive logs damaged_logs: the damaged file's row", "| damaged.mcap (damaged) | waypoints/straight | 7 | 20 |", _cli("logs", "damaged_logs"), 0),
        c("mjdrive replay", "mjdrive replay damaged_logs/damaged.mcap", "Read from the start: the data section passes its CRC check, 20 steps are readable", _cli("replay", "damaged_logs/damaged.mcap"), 1),
        c("mjdrive drive", "mjdrive drive, then SIGINT (Ctrl-C)", "mjdrive drive: stopped: SIGINT", _drive_stopped("SIGINT"), 0),
        c("mjdrive drive", "mjdrive drive, then SIGTERM", "mjdrive drive: stopped: SIGTERM", _drive_stopped("SIGTERM"), 0),
        c("mjdrive drive", "mjdrive drive, then its window destroyed (xdotool windowclose)", "mjdrive drive: stopped: the viewer's window failed (X error 9", _drive_stopped("windowclose"), 0),
        c("MCAP schemas", "the JSON channels of a roundabout/d120 episode, validated with jsonschema", "not matching their schema; /ego/state scenario is ['string', 'null']", _schema_check("roundabout", "d120"), 0),
    ]  # fmt: skip


def run_case(case: Case) -> Outcome:
    """Run one case in the current folder (which must hold `make_files`' files)."""
    err, out = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            result = case.run()
    except ValueError as error:
        return Outcome("error", " ".join(str(error).split()))
    except Exception:  # noqa: BLE001  (anything else is a defect the table must show)
        return Outcome("crash", traceback.format_exc(limit=3))
    if case.status is not None:  # handled: its status, no traceback, the line that says what happened
        printed = [line.strip() for line in (out.getvalue() + err.getvalue()).splitlines() if line.strip()]
        said = [line for line in printed if case.expect in line]
        if result == case.status and said and "Traceback" not in err.getvalue():
            return Outcome("handled", f"exit {result}: {said[0].removeprefix('- ')}")
        return Outcome("crash", f"exit {result}: " + " / ".join(printed[-3:])[:300])
    if case.entry.startswith(("mjdrive", "python -m tools.")):
        lines = [line for line in err.getvalue().splitlines() if line.strip()]
        if result == 2 and len(lines) == 1 and "Traceback" not in err.getvalue():
            return Outcome("error", lines[0])
        return Outcome("crash" if lines else "accepted", f"exit {result}: " + " / ".join(lines)[:300])
    return Outcome("accepted", repr(result)[:100])


def run_all(progress: bool = False) -> list[tuple[Case, Outcome]]:
    """Every case, run in a fresh temporary folder; also checks that no payload ran."""
    previous = os.getcwd()
    all_cases = cases()
    with tempfile.TemporaryDirectory() as tmp:
        os.chdir(tmp)
        try:
            make_files(Path(tmp))
            results = []
            for i, case in enumerate(all_cases, 1):
                if progress:
                    print(f"[{i}/{len(all_cases)}] {case.entry}: {case.shown}", file=sys.stderr, flush=True)
                results.append((case, run_case(case)))
            if Path(MARKER).exists():
                raise RuntimeError("a checkpoint's pickle payload ran")
        finally:
            os.chdir(previous)
    return results


def markdown(results: list[tuple[Case, Outcome]]) -> str:
    bad = [(case, outcome) for case, outcome in results if case.status is None]
    handled = [(case, outcome) for case, outcome in results if case.status is not None]
    lines = [
        "# Bad inputs and the errors they give",
        "",
        "Every row is a bad input tried at one entry point and the error mjdrive gives today, produced by",
        "`python -m tools.robustness --out results/robustness.md`; `tests/test_robustness.py` runs the same cases.",
        "Python entry points raise `ValueError` (task keywords: its subclass `mjdrive.ConfigError`); the command",
        "line (`mjdrive` and the study tools, `python -m tools.NAME`) prints one line on stderr and exits with",
        "status 2, without a traceback. A checkpoint whose pickle",
        "would run code is refused before anything in it runs (the cases check that its payload never ran).",
        "A checkpoint evaluated on a task it cannot run on is refused before any file is written.",
        "",
        f"{len(bad)} cases, {sum(o.expected(c) for c, o in bad)} with a clear error.",
        "",
        "| # | entry point | input | error |",
        "| ---: | --- | --- | --- |",
    ]
    lines += _rows(bad, 1)
    lines += [
        "",
        "## Damaged logs, interrupted runs, signals: handled",
        "",
        "Situations a command must handle and go on from, with the exit status it ends with and the line it prints",
        "(the same tool and test): a task without route completion, an unfinished log a killed run left, a log",
        "whose summary section is damaged (100 bytes flipped near its end: `logs` still reads its row and marks",
        "it, `replay` checks every step and exits with status 1), `mjdrive drive` stopped by a signal or by its",
        "window destroyed from outside (under Xvfb; the episode logged as interrupted, summary.json written),",
        "and the logs' JSON schemas against their messages.",
        "",
        f"{len(handled)} cases, {sum(o.expected(c) for c, o in handled)} handled as documented.",
        "",
        "| # | entry point | situation | exit status and line printed |",
        "| ---: | --- | --- | --- |",
    ]
    lines += _rows(handled, len(bad) + 1)
    return "\n".join(lines) + "\n"


def _rows(results: list[tuple[Case, Outcome]], first: int) -> list[str]:
    rows = []
    for i, (case, outcome) in enumerate(results, first):
        text = outcome.message if outcome.expected(case) else f"**{outcome.kind}**: {outcome.message}"
        cells = [str(i), case.entry, f"`{case.shown}`", text.replace("|", "\\|").replace("\n", " ")]
        rows.append("| " + " | ".join(cells) + " |")
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=None, help="write the markdown table here")
    args = parser.parse_args(argv)
    results = run_all(progress=True)
    table = markdown(results)
    if args.out:
        Path(args.out).write_text(table)
        print(f"wrote {args.out}")
    else:
        print(table)
    return 0 if all(o.expected(c) for c, o in results) else 1


if __name__ == "__main__":
    from mjdrive.cli import run_reporting_errors

    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
