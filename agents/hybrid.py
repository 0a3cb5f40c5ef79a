"""Study 002's hybrid agent (§4.2, Fig. 5): a scenario selector hands each decision to the agent trained on the
scenario the ego is in, and "Follow Path" (drive) outside every scenario; the operative level (LQR + MPC) under
the decisions is the env's (`decisions=True`).

A hybrid checkpoint is one file (algo "hybrid") that holds its members' acting networks, each named by its
scenario with its learner, config, training steps, source file and the SHA-256 of its weights (checked when
the file loads: a member whose weights changed is an error, not another policy). `mjdrive eval`, the Table 2
tool and `load_agent` read it like any policy.pt:

    mjdrive hybrid --member roundabout=A.pt --member crossroad=B.pt ... --out results/checkpoints/hybrid_trpo.pt

A scenario without a member decides "drive" there (the operative level still yields where the rules of the
road say so); the description says so.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mjdrive.agents.algorithms import agent_from_payload
from mjdrive.agents.checkpoints import CheckpointError, load_checkpoint, save_checkpoint
from mjdrive.agents.observations import observation_mismatch
from mjdrive.agents.train import INFERENCE_KEYS
from mjdrive.tasks.decisions import ACTIONS
from mjdrive.tasks.urban import SCENARIOS

MEMBER_ALGOS = ("trpo", "ppo_discrete")
DECIDING = tuple(name for name in SCENARIOS if name in ACTIONS)  # the scenarios an agent decides in
SAME = {"keep": "drive"}  # a member's action name -> the route's of the same effect


def weights_sha256(state: dict) -> str:
    """SHA-256 of a network state: every tensor's name, dtype, shape and bytes, in name order."""
    digest = hashlib.sha256()

    def add(prefix: str, value: Any) -> None:
        if isinstance(value, dict):
            for key in sorted(value, key=str):
                add(f"{prefix}/{key}", value[key])
        elif isinstance(value, torch.Tensor):
            digest.update(f"{prefix}:{value.dtype}:{tuple(value.shape)}".encode())
            digest.update(value.detach().cpu().contiguous().numpy().tobytes())
        else:
            digest.update(f"{prefix}={value!r}".encode())

    add("", state)
    return digest.hexdigest()


class HybridAgent:
    """Acts like one agent on the urban decision tasks: per observation row, the member of the active scenario
    (the observation's `scenario` one-hot) decides, mapped by name onto the env's actions; "drive" elsewhere.
    `last` holds the latest rows' (scenario, agent, action name) for `info` and the logs."""

    def __init__(self, members: dict[str, Any], member_actions: dict[str, tuple[str, ...]],
                 actions: tuple[str, ...]):
        self.members, self.actions = members, actions
        index = {name: i for i, name in enumerate(actions)}
        # by name; a name the task lacks (a lane change on a task whose route has no two-lane road) is "drive"
        self._map = {scenario: np.array([index.get(SAME.get(name, name), index["drive"]) for name in names])
                     for scenario, names in member_actions.items()}
        self._drive = index["drive"]
        self.last: list[tuple[str, str, str]] = []

    def act(self, obs: dict[str, np.ndarray], deterministic: bool = True) -> np.ndarray:
        """Env actions (N,) for batched observations."""
        active = np.asarray(obs["scenario"]).argmax(axis=-1)
        out = np.full(len(active), self._drive, dtype=np.int64)
        agents = ["follow path"] * len(active)
        for code in np.unique(active):
            scenario = SCENARIOS[code]
            if scenario not in self.members:
                continue
            rows = np.flatnonzero(active == code)
            chosen = self.members[scenario].act({key: value[rows] for key, value in obs.items()}, deterministic)
            out[rows] = self._map[scenario][np.asarray(chosen, dtype=np.int64)]
            for row in rows:
                agents[row] = scenario
        self.last = [(SCENARIOS[code], agent, self.actions[a]) for code, agent, a in zip(active, agents, out,
                                                                                        strict=True)]
        return out


def describe(hybrid: dict) -> str:
    """One line for reports from a hybrid checkpoint's `config["hybrid"]`."""
    members = hybrid["members"]
    parts = [f"{scenario}: `{m['source']}` ({m['algo']}, {m['step']:,} steps)" if m else f"{scenario}: drive"
             for scenario, m in ((s, members.get(s)) for s in DECIDING)]
    return "the hybrid agent (scenario selector over " + "; ".join(parts) + ")"


def hybrid_agent(payload: dict, path: str | Path) -> HybridAgent:
    """The acting hybrid of the hybrid checkpoint at `path` (its loaded `payload`), weights checked."""
    members, member_actions = {}, {}
    entries = payload["state"].get("members")
    if not isinstance(entries, dict) or not set(entries) <= set(DECIDING):
        raise CheckpointError(f"{path}: a hybrid's 'members' must map scenarios ({', '.join(DECIDING)}) to agents")
    for scenario, member in entries.items():
        if not isinstance(member, dict) or not {"algo", "config", "state", "step", "sha256"} <= set(member):
            raise CheckpointError(f"{path}: its member {scenario!r} lacks algo, config, state, step or sha256")
        if weights_sha256(member["state"]) != member["sha256"]:
            raise CheckpointError(f"{path}: the weights of its member {scenario!r} do not match their SHA-256 "
                                  "(the file was changed or damaged)")
        members[scenario] = agent_from_payload(member, f"{path} member {scenario!r}")
        member_actions[scenario] = ACTIONS[scenario]
    return HybridAgent(members, member_actions, ACTIONS[payload["config"]["task"].split("/", 1)[1]])


def save_hybrid(members: dict[str, str | Path], out: str | Path, task: str = "urban/concatenated") -> Path:
    """Write a hybrid checkpoint for `task` of the agents `members` (scenario -> checkpoint or policy.pt), each
    trained on `urban/<scenario>` with decisions; they must read the observation `task` gives."""
    from mjdrive.envs import make_env

    unknown = sorted(set(members) - set(DECIDING))
    if unknown:
        raise ValueError(f"no scenario {unknown[0]!r}; a hybrid's members decide in {', '.join(DECIDING)}")
    if not task.startswith("urban/") or task.split("/", 1)[1] not in ACTIONS:
        raise ValueError(f"a hybrid drives an urban task ({', '.join('urban/' + t for t in ACTIONS)}), not {task!r}")
    entries, kwargs = {}, None
    for scenario, path in members.items():
        payload = load_checkpoint(path)
        config = payload["config"]
        if payload["algo"] not in MEMBER_ALGOS:
            raise CheckpointError(f"{path} holds a {payload['algo']!r} agent; a hybrid's members are "
                                  f"{' or '.join(MEMBER_ALGOS)} agents")
        if config["task"] != f"urban/{scenario}" or not config.get("task_kwargs", {}).get("decisions"):
            raise CheckpointError(f"{path} was trained on {config['task']} with {config.get('task_kwargs')}; the "
                                  f"{scenario} member must be trained on urban/{scenario} with decisions=true")
        state = {key: payload["state"][key] for key in INFERENCE_KEYS[payload["algo"]]}
        entries[scenario] = {"algo": payload["algo"], "config": config, "state": state, "step": payload["step"],
                             "source": str(path), "sha256": weights_sha256(state)}
        observed = {k: v for k, v in config["task_kwargs"].items() if k in ("adversaries", "observation")}
        if kwargs is not None and observed != kwargs:
            raise CheckpointError(f"{path} sees another observation ({observed}) than the other members ({kwargs})")
        kwargs = observed
    kwargs = {**(kwargs or {}), "decisions": True}
    domain, name = task.split("/", 1)
    env = make_env(domain, name, **kwargs)
    try:
        for scenario, entry in entries.items():
            member_env = make_env("urban", scenario, **entry["config"]["task_kwargs"])
            problems = observation_mismatch(member_env.observation_space, env.observation_space)
            member_env.close()
            if problems:
                raise CheckpointError(f"the {scenario} member cannot read the observation of {task}: {problems}")
    finally:
        env.close()
    config = {"algo": "hybrid", "task": task, "task_kwargs": kwargs, "actions": "continuous",
              "hybrid": {"members": {s: {k: e[k] for k in ("algo", "step", "source", "sha256")}
                                     for s, e in entries.items()}}}
    step = max((e["step"] for e in entries.values()), default=0)
    return save_checkpoint(out, "hybrid", config, {"members": entries}, step, {"inference_only": True})


def hybrid_command(args) -> int:
    """`mjdrive hybrid` (argument parsing lives in mjdrive/cli.py)."""
    members = {}
    for item in args.member:
        scenario, sep, path = item.partition("=")
        if not sep or not path:
            raise ValueError(f"--member {item!r}: write SCENARIO=CHECKPOINT (scenarios: {', '.join(DECIDING)})")
        if scenario in members:
            raise ValueError(f"--member {scenario} given twice")
        members[scenario] = path
    path = save_hybrid(members, args.out, args.task)
    print(f"wrote {path}: {describe(load_checkpoint(path, 'hybrid')['config']['hybrid'])}")
    return 0
