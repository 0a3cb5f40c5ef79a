"""Several trained policies acting as one (`mjdrive ensemble`): every member acts on the same observation and
a rule combines their actions.

Rules:
- "mean": the members' mean action.
- "min_pedal" (the "pedal" action set only): the most cautious member's pedal (the smallest: braking beats
  coasting beats throttle) with the members' mean steer. The car speeds up only where every member wants to,
  so a road user that one member misjudges is braked for if another one sees it.

An ensemble file is a small checkpoint (algo "ensemble") that names its member files (relative to its own
folder, with their SHA-256, so a moved or changed member is an error rather than another policy), and
`mjdrive eval`, tools/roundabout_table3.py and tools/collision_report.py read it like any policy.pt:

    python -m mjdrive.cli ensemble --rule min_pedal --out results/checkpoints/ENSEMBLE.pt A.pt B.pt C.pt

Members must see identical observations (checked on a reset and a step of the task) and use the same
continuous action set. Task settings they differ on that leave the observation unchanged (e.g. a fine-tune's
`collision_penalty`) take the task's defaults in the ensemble's config.
"""

from __future__ import annotations

import copy
import hashlib
import os
from pathlib import Path
from typing import Any

import numpy as np

from mjdrive.agents.algorithms import agent_from_payload
from mjdrive.agents.checkpoints import CheckpointError, load_checkpoint, save_checkpoint
from mjdrive.suite import split_task

RULES = ("mean", "min_pedal")
CONTINUOUS_ACTIONS = ("continuous", "pedal")  # action sets whose actions can be averaged


def check_rule(rule: str) -> None:
    """ValueError naming the valid rules for an unknown one."""
    if rule not in RULES:
        raise ValueError(f"unknown ensemble rule {rule!r}; valid: {', '.join(RULES)}")


def describe(ensemble: dict) -> str:
    """One line for reports from an ensemble checkpoint's `config["ensemble"]`: rule and members."""
    members = ensemble["members"]
    return (f"an ensemble of {len(members)}, rule {ensemble['rule']!r}, of "
            + ", ".join(f"`{m['checkpoint']}` ({m['algo']}, {m['step']:,} steps)" for m in members))


class EnsembleAgent:
    """Acts like one agent: `act(obs, deterministic)` combines the members' actions by `rule`."""

    def __init__(self, members: list[Any], rule: str):
        check_rule(rule)
        self.members, self.rule = members, rule

    def act(self, obs: dict[str, np.ndarray], deterministic: bool = True) -> np.ndarray:
        """Env actions (N, A) for batched observations."""
        actions = np.stack([member.act(obs, deterministic) for member in self.members])  # (M, N, A)
        combined = actions.mean(axis=0)
        if self.rule == "min_pedal":
            combined[:, 0] = actions[:, :, 0].min(axis=0)  # the pedal: (pedal, steer) of PedalActions
        return combined


def ensemble_agent(payload: dict, path: str | Path) -> EnsembleAgent:
    """The acting ensemble of the ensemble checkpoint at `path` (its loaded `payload`)."""
    state = payload["state"]
    if state.get("rule") not in RULES:
        raise CheckpointError(f"{path}: an ensemble with the rule {state.get('rule')!r}; valid: {', '.join(RULES)}")
    entries = state.get("members")
    if not isinstance(entries, list) or not entries or not all(
            isinstance(m, dict) and isinstance(m.get("path"), str) and isinstance(m.get("sha256"), str)
            for m in entries):
        raise CheckpointError(f"{path}: an ensemble's 'members' must be a list of {{'path', 'sha256'}} entries")
    members = []
    for member in entries:
        member_path = Path(path).parent / member["path"]
        if not member_path.is_file():
            raise CheckpointError(f"{path}: its member {member['path']} is missing (looked for {member_path})")
        if _sha256(member_path) != member["sha256"]:
            raise CheckpointError(f"{path}: its member {member_path} has changed since the ensemble was made "
                                  "(SHA-256 differs); make the ensemble again")
        members.append(agent_from_payload(load_checkpoint(member_path), str(member_path)))
    return EnsembleAgent(members, payload["state"]["rule"])


def _sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _first_observation(config: dict, task_kwargs: dict, seed: int = 0) -> list[dict]:
    """The observations of a reset and one idle step of `config`'s task with `task_kwargs`."""
    from mjdrive.envs import make_env

    env = make_env(*split_task(config["task"]), actions=config["actions"], **task_kwargs)
    try:
        first, _ = env.reset(seed=seed)
        second = env.step(np.zeros(env.action_space.shape, np.float32))[0]
    finally:
        env.close()
    return [first, second]


def _same_observations(a: list[dict], b: list[dict]) -> bool:
    return all(x.keys() == y.keys() and all(np.array_equal(x[k], y[k]) for k in x) for x, y in zip(a, b, strict=True))


def save_ensemble(members: list[str | Path], rule: str, out: str | Path) -> Path:
    """Write an ensemble checkpoint of `members` (policy.pt or full checkpoints, which must stay where they
    are) combined by `rule`."""
    check_rule(rule)
    if len(members) < 2:
        raise ValueError(f"an ensemble needs at least 2 members, got {len(members)}")
    payloads = [load_checkpoint(path) for path in members]
    for path, payload in zip(members, payloads, strict=True):
        actions = payload["config"].get("actions", "continuous")
        if payload["algo"] == "ensemble":
            raise CheckpointError(f"{path} is an ensemble already; list its members instead")
        if actions not in CONTINUOUS_ACTIONS:
            raise CheckpointError(f"{path} acts with the discrete action set {actions!r}; an ensemble averages "
                                  f"actions, so its members need one of {CONTINUOUS_ACTIONS}")
        if rule == "min_pedal" and actions != "pedal":
            raise CheckpointError(f"rule 'min_pedal' needs members with the 'pedal' action set; {path} uses "
                                  f"{actions!r}")
    first = payloads[0]["config"]
    for path, payload in zip(members[1:], payloads[1:], strict=True):
        config = payload["config"]
        if (split_task(config["task"])[0], config["actions"]) != (split_task(first["task"])[0], first["actions"]):
            raise CheckpointError(f"{path} ({config['task']}, actions {config['actions']!r}) does not match "
                                  f"{members[0]} ({first['task']}, actions {first['actions']!r})")
    member_kwargs = [payload["config"].get("task_kwargs", {}) for payload in payloads]
    reference = _first_observation(first, member_kwargs[0])
    for path, kwargs in zip(members[1:], member_kwargs[1:], strict=True):
        if not _same_observations(reference, _first_observation(first, kwargs)):
            raise CheckpointError(f"{path} sees another observation than {members[0]} (task kwargs {kwargs} "
                                  f"against {member_kwargs[0]}); an ensemble's members must see the same inputs")
    shared = {key: value for key, value in member_kwargs[0].items()
              if all(key in kwargs and kwargs[key] == value for kwargs in member_kwargs)}
    if not _same_observations(reference, _first_observation(first, shared)):
        raise CheckpointError(f"the members' task kwargs differ where it changes the observation "
                              f"({member_kwargs}); give them the same")

    tasks = list(dict.fromkeys(task for p in payloads
                               for task in [p["config"]["task"], *(p["config"].get("mix_tasks") or [])]))
    config = copy.deepcopy(first)
    config.update(algo="ensemble", task=tasks[0], mix_tasks=tasks[1:], task_kwargs=shared)
    config["ensemble"] = {"rule": rule, "members": [
        {"checkpoint": str(path), "algo": p["algo"], "step": p["step"],
         "task_kwargs": p["config"].get("task_kwargs", {})}
        for path, p in zip(members, payloads, strict=True)]}
    out = Path(out)
    state = {"rule": rule, "members": [{"path": os.path.relpath(Path(path).resolve(), out.resolve().parent),
                                        "sha256": _sha256(Path(path))} for path in members]}
    step = max(p["step"] for p in payloads)
    return save_checkpoint(out, "ensemble", config, state, step, {"inference_only": True})


def ensemble_command(args) -> int:
    """`mjdrive ensemble` (argument parsing lives in mjdrive/cli.py)."""
    path = save_ensemble(args.members, args.rule, args.out)
    payload = load_checkpoint(path, "ensemble")
    print(f"wrote {path}: {len(args.members)} members, rule {args.rule!r}, task kwargs "
          f"{payload['config']['task_kwargs']}")
    return 0
