"""A hash of every task's trajectories: a regression guard for refactors that must not move a number.

    python -m tools.trajectory_hash                       # every case, 3 seeds, 400 steps each
    python -m tools.trajectory_hash --steps 40 --seeds 1  # a quick look
    python -m tools.trajectory_hash --out hashes.json     # ... and keep them; --check hashes.json compares

Each case drives one task with a scripted policy (the traffic-aware autopilot, the traffic-blind always_go, or
pure pursuit on the waypoint tasks) through the gymnasium env for `--steps` control steps per seed (an episode
that ends is followed by the next seed's); every step adds to a SHA-256: the observation, the reward and the
episode's end, the ego's physics state (qpos, qvel, mocap poses), and the traffic as its public queries show
it (poses, speeds, present slots, intentions), and at an episode's end its `info`. A `batched` case steps two
roundabout copies in a `BatchedEnv`.
The same code gives the same hashes on every run (determinism); a change of any number changes them.
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from mjdrive.cli import ArgumentParser, int_at_least, run_reporting_errors

# (domain, task, policy): the roundabout at every density (pedestrians included; a random driver too), every
# urban task with the careful and the blind driver, the waypoint tasks (no traffic: the ego's physics and
# observations)
CASES: tuple[tuple[str, str, str], ...] = (
    ("roundabout", "d120", "autopilot"), ("roundabout", "d140", "autopilot"), ("roundabout", "d160", "autopilot"),
    ("roundabout", "d210", "autopilot"), ("roundabout", "d210", "random"),
    ("urban", "roundabout", "autopilot"), ("urban", "lane_change", "autopilot"), ("urban", "crossroad", "autopilot"),
    ("urban", "merge", "autopilot"), ("urban", "concatenated", "autopilot"),
    ("urban", "roundabout", "always_go"), ("urban", "lane_change", "always_go"), ("urban", "crossroad", "always_go"),
    ("urban", "merge", "always_go"), ("urban", "concatenated", "always_go"),
    ("waypoints", "straight", "pure_pursuit"), ("waypoints", "four_routes", "pure_pursuit"),
)
BATCHED = ("roundabout", ("d120", "d210"), "autopilot")  # two copies stepped together
FIRST_SEED = 100
NEW_INFO = ("exit_number",)  # info keys added after the hashes were first recorded (b4686a2): left out, so that a
# new metric does not move the guard (a changed number of the old keys does)


def _state_bytes(env) -> Iterator[bytes]:
    """The ego's physics state and the traffic's public view of itself now."""
    data = env.unwrapped.dm_env.physics.raw_data
    for array in (np.array([data.time]), data.qpos, data.qvel, data.mocap_pos, data.mocap_quat):
        yield np.ascontiguousarray(array).tobytes()
    traffic = getattr(env.unwrapped.task, "traffic", None)
    if traffic is not None:
        for array in (traffic.poses(), traffic.speeds(), traffic.present, traffic.intentions()):
            yield np.ascontiguousarray(array).tobytes()


def _step_bytes(observation: dict, reward: float, terminated: bool, truncated: bool, info: dict) -> Iterator[bytes]:
    for key in sorted(observation):
        yield key.encode() + np.ascontiguousarray(observation[key]).tobytes()
    yield np.array([reward], np.float64).tobytes() + bytes([terminated, truncated])
    if terminated or truncated:  # the episode's metrics: their values (numpy's scalars as Python's), exact reprs
        plain = sorted((k, v.item() if isinstance(v, np.generic) else v) for k, v in info.items() if k not in NEW_INFO)
        yield repr([(k, v) for k, v in plain if isinstance(v, (bool, int, float, str))]).encode()


def case_hash(domain: str, task: str, policy: str, seed: int, steps: int) -> str:
    """SHA-256 (hex, 16 digits) of `steps` control steps of `domain/task` driven by `policy` from `seed`."""
    from mjdrive.envs import make_env
    from mjdrive.policies import make_policy

    digest = hashlib.sha256()
    env = make_env(domain, task)
    try:
        act = make_policy(policy, env, seed)
        observation, _ = env.reset(seed=seed)
        episode = 0
        for chunk in _state_bytes(env):
            digest.update(chunk)
        for _ in range(steps):
            observation, reward, terminated, truncated, info = env.step(act(observation))
            for chunk in (*_step_bytes(observation, reward, terminated, truncated, info), *_state_bytes(env)):
                digest.update(chunk)
            if terminated or truncated:
                episode += 1
                observation, _ = env.reset(seed=seed + 1000 * episode)
    finally:
        env.close()
    return digest.hexdigest()[:16]


def batched_hash(seed: int, steps: int) -> str:
    """The same for `BATCHED`'s copies stepped together (threads backend, auto-reset)."""
    from mjdrive.envs.batched import BatchedEnv
    from mjdrive.policies import make_policy

    domain, tasks, policy = BATCHED
    digest = hashlib.sha256()
    env = BatchedEnv(domain, list(tasks), num_envs=len(tasks), nthread=2, backend="threads")
    try:
        acts = [make_policy(policy, copy, seed) for copy in env.envs]
        observations, _ = env.reset(seed=seed)
        for _ in range(steps):
            actions = np.stack([act({}) for act in acts])
            observations, rewards, terminated, truncated, _ = env.step(actions)
            for key in sorted(observations):
                digest.update(np.ascontiguousarray(observations[key]).tobytes())
            digest.update(rewards.tobytes() + terminated.tobytes() + truncated.tobytes())
            for copy in env.envs:
                for chunk in _state_bytes(copy):
                    digest.update(chunk)
    finally:
        env.close()
    return digest.hexdigest()[:16]


def hashes(steps: int, seeds: int, cases=CASES, batched: bool = True, report=None) -> dict[str, str]:
    """{"domain/task policy seed": hash} for every case and seed (and the batched case)."""
    out = {}
    for domain, task, policy in cases:
        for seed in range(FIRST_SEED, FIRST_SEED + seeds):
            start = time.perf_counter()
            key = f"{domain}/{task} {policy} {seed}"
            out[key] = case_hash(domain, task, policy, seed, steps)
            if report:
                report(key, out[key], time.perf_counter() - start)
    if batched:
        start = time.perf_counter()
        key = f"batched {BATCHED[0]}/{'+'.join(BATCHED[1])} {BATCHED[2]} {FIRST_SEED}"
        out[key] = batched_hash(FIRST_SEED, steps)
        if report:
            report(key, out[key], time.perf_counter() - start)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int_at_least(1), default=400, help="control steps per case and seed")
    parser.add_argument("--seeds", type=int_at_least(1), default=3, help=f"seeds {FIRST_SEED}, {FIRST_SEED + 1}, ...")
    parser.add_argument("--only", default=None, help="only the cases whose 'domain/task policy' contains this")
    parser.add_argument("--out", default=None, help="write the hashes as JSON")
    parser.add_argument("--check", default=None, help="compare with the hashes of this JSON file (exit 1 if any "
                        "differs)")
    args = parser.parse_args(argv)
    cases = [c for c in CASES if args.only is None or args.only in f"{c[0]}/{c[1]} {c[2]}"]
    batched = args.only is None or args.only in "batched"
    result = hashes(args.steps, args.seeds, cases, batched,
                    lambda key, value, wall: print(f"{value}  {key}  ({wall:.1f} s)", flush=True))
    total = hashlib.sha256(json.dumps(result, sort_keys=True).encode()).hexdigest()[:16]
    print(f"{total}  all {len(result)} ({args.steps} steps each)")
    if args.out:
        Path(args.out).write_text(json.dumps({"steps": args.steps, "hashes": result, "all": total}, indent=1) + "\n")
    if args.check:
        expected = json.loads(Path(args.check).read_text())
        if expected["steps"] != args.steps:
            print(f"{args.check} holds hashes of {expected['steps']} steps, not {args.steps}")
            return 1
        differ = [key for key, value in result.items() if expected["hashes"].get(key) != value]
        print(f"differ from {args.check}: {differ or 'none'}")
        return 1 if differ else 0
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
