"""Camera policies distilled from a privileged teacher ("Learning by Cheating", Chen et al. 2019, with DAgger,
Ross et al. 2011).

A SAC teacher trained on the roundabout's `features` observation (ego state, destination, the nearest road
users) labels every step with its greedy action, while the student, a SAC actor on the camera observation
(`student` config, e.g. sac_roundabout_camera_state), learns to regress those actions from what it sees.
Iteration 0 lets the teacher drive; later iterations let the student drive (so it is taught in the states its
own mistakes lead to), and every iteration retrains on all samples so far. The result is an ordinary "sac"
policy checkpoint: `mjdrive eval` and tools/roundabout_table3.py read it like any other.

    python -m mjdrive.agents.distill --teacher results/checkpoints/sac_features_roundabout.pt \\
        --student sac_roundabout_camera_state --out runs/distill_camera
"""

from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from mjdrive.agents.checkpoints import save_checkpoint
from mjdrive.agents.config import apply_overrides, load_config
from mjdrive.agents.evaluate import load_agent
from mjdrive.agents.observations import ObsBatch
from mjdrive.agents.sac import SACAgent
from mjdrive.agents.seeding import set_seed
from mjdrive.envs import make_env
from mjdrive.suite import split_task

DEFAULTS = {
    "iterations": 4,  # DAgger iterations (the first driven by the teacher)
    "steps_per_iteration": 10_000,  # [env steps] collected per iteration
    "epochs": 5,  # passes over all samples so far, per iteration
    "batch_size": 64,
    "lr": 3e-4,
    "random_shift": 4,  # [px] DrQ augmentation of the student's frames
}
LOG_FIELDS = ("iteration", "driver", "samples", "episodes", "success", "collision", "off_route", "loss", "wall_s")


def distill(teacher: str | Path, student_config: dict, out: str | Path, seed: int = 0, progress: bool = True,
            **hp) -> Path:
    """Distil `teacher` (a checkpoint on the features observation of a roundabout task) into a camera student
    built from `student_config`; writes out/policy.pt and out/distill.csv (one row per iteration)."""
    from tqdm import tqdm

    hp = {**DEFAULTS, **hp}
    unknown = set(hp) - set(DEFAULTS)
    if unknown:
        raise ValueError(f"unknown distillation settings {sorted(unknown)}; valid: {sorted(DEFAULTS)}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    set_seed(seed)
    torch.set_num_threads(int(student_config.get("torch_threads", 1)))
    teacher_agent, teacher_payload = load_agent(teacher)
    teacher_kwargs = teacher_payload["config"].get("task_kwargs", {})
    if teacher_kwargs.get("observation", "features") != "features":
        raise ValueError(f"the teacher must see the features observation, {teacher} saw "
                         f"{teacher_kwargs.get('observation')!r}")
    teacher_frame = teacher_kwargs.get("destination_frame", "world")
    domain, name = split_task(student_config["task"])
    env = make_env(domain, name, actions=student_config.get("actions", "continuous"),
                   **student_config.get("task_kwargs", {}))
    dm_env = env.unwrapped.dm_env
    if not hasattr(dm_env.task, "features_observation"):
        raise ValueError(f"{student_config['task']} has no features observation to teach from")
    student = SACAgent(student_config, env.observation_space, env.action_space)
    layout, actor = student.layout, student.actor
    optimizer = torch.optim.Adam(actor.parameters(), lr=hp["lr"])  # the encoder included

    capacity = hp["iterations"] * hp["steps_per_iteration"]
    features = np.zeros((capacity, layout.feature_dim), np.float32)
    images = np.zeros((capacity, *layout.image_shape), np.uint8)
    labels = np.zeros((capacity, student.action_dim), np.float32)  # teacher's squashed mean, in [-1, 1]
    size, episode, start = 0, 0, time.perf_counter()
    log_file = open(out / "distill.csv", "w", newline="")  # noqa: SIM115
    log = csv.DictWriter(log_file, LOG_FIELDS)
    log.writeheader()
    generator = torch.Generator().manual_seed(seed)
    bar = tqdm(total=capacity, unit="step", desc="distill", disable=not progress, dynamic_ncols=True)
    try:
        for iteration in range(hp["iterations"]):
            driver = "teacher" if iteration == 0 else "student"
            ends = {"episodes": 0, "success": 0, "collision": 0, "off_route": 0}
            obs, _ = env.reset(seed=seed * 1_000_003 + episode)
            for _ in range(hp["steps_per_iteration"]):
                teacher_obs = dm_env.task.features_observation(dm_env.physics, teacher_frame)
                with torch.no_grad():
                    batch = ObsBatch.from_numpy(teacher_agent.layout, {k: v[None] for k, v in teacher_obs.items()})
                    label = teacher_agent.actor.sample(teacher_agent.actor.encode(batch))[2]
                one = {k: v[None] for k, v in obs.items()}
                features[size], images[size], labels[size] = layout.features(one)[0], layout.image(one)[0], label[0]
                size += 1
                bar.update(1)
                if driver == "teacher":
                    action = teacher_agent.actor.to_env(label)[0].numpy()
                else:  # the greedy action through `sample`: its draw advances torch's global generator, which
                    # the shifts in `_fit` use, as when the published student was distilled
                    with torch.no_grad():
                        greedy = actor.sample(actor.encode(ObsBatch.from_numpy(layout, one)))[2]
                    action = actor.to_env(greedy)[0].numpy()
                obs, _, terminated, truncated, info = env.step(action)
                if terminated or truncated:
                    episode += 1
                    ends["episodes"] += 1
                    for key in ("success", "collision", "off_route"):
                        ends[key] += bool(info.get(key))
                    obs, _ = env.reset(seed=seed * 1_000_003 + episode)
            loss = _fit(actor, optimizer, features[:size], images[:size], labels[:size], hp, generator)
            n = max(ends["episodes"], 1)
            row = {"iteration": iteration, "driver": driver, "samples": size, "episodes": ends["episodes"],
                   "success": round(ends["success"] / n, 3), "collision": round(ends["collision"] / n, 3),
                   "off_route": round(ends["off_route"] / n, 3), "loss": round(loss, 5),
                   "wall_s": round(time.perf_counter() - start, 1)}
            log.writerow(row)
            log_file.flush()
            bar.set_postfix(it=iteration, loss=f"{loss:.4f}", success=row["success"], refresh=False)
            path = save_checkpoint(out / "policy.pt", "sac", student_config, {"actor": actor.state_dict()},
                                   size, {"inference_only": True, "distilled_from": str(teacher),
                                          "iteration": iteration, "episodes": episode,
                                          "wall_s": row["wall_s"], "distill": hp})
    finally:
        bar.close()
        log_file.close()
        env.close()
    return path


def _fit(actor, optimizer, features: np.ndarray, images: np.ndarray, labels: np.ndarray, hp: dict,
         generator: torch.Generator) -> float:
    """`epochs` passes of minibatch regression of the actor's squashed mean onto the labels; the last
    epoch's mean loss."""
    n = len(labels)
    for _ in range(hp["epochs"]):
        order = torch.randperm(n, generator=generator).numpy()
        losses = []
        for k in range(0, n - hp["batch_size"] + 1, hp["batch_size"]):
            idx = np.sort(order[k:k + hp["batch_size"]])
            batch = ObsBatch(torch.from_numpy(features[idx]), torch.from_numpy(images[idx]))
            batch = batch.shifted(hp["random_shift"])
            mean, _ = actor(actor.encode(batch))
            loss = F.mse_loss(torch.tanh(mean), torch.from_numpy(labels[idx]))
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            losses.append(loss.item())
    return float(np.mean(losses)) if losses else float("nan")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--teacher", required=True, help="checkpoint of an agent on the features observation")
    parser.add_argument("--student", default="sac_roundabout_camera_state",
                        help="config (name or file) of the camera student: task, task_kwargs, actions, network")
    parser.add_argument("--out", required=True)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help=f"a distillation setting ({', '.join(DEFAULTS)}) or student config override")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    config = load_config(args.student)
    settings, overrides = {}, []
    for pair in args.set:
        key = pair.split("=", 1)[0]
        if key in DEFAULTS:
            settings.update(apply_overrides({}, [pair]))
        else:
            overrides.append(pair)
    config = apply_overrides(config, overrides)
    start = time.perf_counter()
    path = distill(args.teacher, config, args.out, seed=args.seed, progress=not args.no_progress, **settings)
    print(f"distilled {args.teacher} into a camera student in {time.perf_counter() - start:.0f} s: {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
