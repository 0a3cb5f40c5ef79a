"""Where an agent's collisions happen: re-run its collision episodes (deterministic) and describe each contact.

For every collision episode in an `mjdrive eval` JSON (or the given --seeds), the episode is replayed with the
greedy policy and, at the contact, the road user hit is reported: its kind, its centre in the ego frame
(x ahead, y left) [m], its bearing from the ego camera's axis and its heading relative to the ego's [deg], and
both speeds 0.2 s (the step before the contact, which stops the ego against a mocap road user) and 1 s
before [m/s]:

    python -m tools.collision_report results/checkpoints/sac_camera_state_demos_ft_roundabout_122k.pt \\
        --eval runs/eval/ft_fail_d160.json

Writes a markdown table to stdout (and OUT.md with --out); `--frames DIR` also saves what the agent saw in the
last 1.6 s before each contact (DIR/seed_SEED.png, oldest frame left), to tell a road user it could not see
from one it misjudged.
"""

from __future__ import annotations

import json
import sys
from collections import deque
from pathlib import Path

import numpy as np

from mjdrive.agents.evaluate import load_agent
from mjdrive.cli import ArgumentParser, int_at_least, run_reporting_errors
from mjdrive.envs import make_env
from mjdrive.roads.geometry import wrap_angle
from mjdrive.suite import split_task

HISTORY = 5  # [steps] 1 s at 5 Hz
FRAMES = 8  # [steps] of camera images in a --frames strip (1.6 s)


def describe_collision(agent, env, seed: int, frames: Path | None = None) -> dict | None:
    """Replay episode `seed` with `agent`; the contact's description, or None if it does not collide. With
    `frames`, the agent's camera images of the last FRAMES steps are written to frames/seed_SEED.png."""
    obs, _ = env.reset(seed=seed)
    seen = deque(maxlen=FRAMES)  # the newest camera frame of each step's (frames, H, W) observation
    dm = env.unwrapped.dm_env
    task, physics = dm.task, dm.physics
    model = physics.model
    camera = model.camera(getattr(task, "camera", "ego/front")).id
    camera_x = float(model.cam_pos[camera, 0])  # [m] ahead of the ego centre
    poses, speeds, ego = [], [], []  # per step: road users (M, 3) x, y, yaw and (M,) [m/s]; ego (x, y, yaw, speed)
    while True:
        obs, _, terminated, truncated, info = env.step(agent.act({k: v[None] for k, v in obs.items()})[0])
        if "image" in obs:
            seen.append(obs["image"][-1])
        poses.append(task.traffic.poses().copy())
        speeds.append(np.hypot(*task.traffic.velocities().T))
        ego.append((*task.xy, task.yaw, task.speed))
        if terminated or truncated:
            break
    if not info.get("collision"):
        return None
    if frames is not None and seen:
        write_strip(list(seen), frames / f"seed_{seed}.png")
    geom = task.collision_sensor.last_other_geom
    body = model.body(int(model.geom_bodyid[geom])).name
    row = {"seed": seed, "step": len(ego), "hit": model.geom(geom).name, "kind": "static"}
    if body.startswith("traffic_"):
        slot = int(body.removeprefix("traffic_"))
        x, y, yaw, speed = ego[-1]
        dx, dy = poses[-1][slot, :2] - (x, y)
        c, s = np.cos(yaw), np.sin(yaw)
        ahead, left = c * dx + s * dy, -s * dx + c * dy  # [m] in the ego frame
        previous, before = max(len(ego) - 2, 0), max(len(ego) - 1 - HISTORY, 0)  # 0.2 s and 1 s before
        row.update(kind=task.traffic.kinds[slot], ahead_m=round(float(ahead), 2), left_m=round(float(left), 2),
                   bearing_deg=round(float(np.degrees(np.arctan2(left, ahead - camera_x))), 1),
                   relative_yaw_deg=round(float(np.degrees(wrap_angle(poses[-1][slot, 2] - yaw))), 1),
                   ego_speed=round(float(ego[previous][3]), 2), ego_speed_1s=round(float(ego[before][3]), 2),
                   other_speed=round(float(speeds[previous][slot]), 2),
                   other_speed_1s=round(float(speeds[before][slot]), 2))
    return row


def write_strip(images: list[np.ndarray], path: Path, zoom: int = 3) -> None:
    """The images side by side (oldest left, the collision step right), `zoom` times larger, as a PNG."""
    from PIL import Image

    gap = np.full((images[0].shape[0], 2, *images[0].shape[2:]), 255, np.uint8)
    strip = np.concatenate([part for image in images for part in (image, gap)][:-1], axis=1)
    path.parent.mkdir(parents=True, exist_ok=True)
    picture = Image.fromarray(strip)
    picture.resize((picture.width * zoom, picture.height * zoom), Image.NEAREST).save(path)


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("--eval", type=Path, default=None, help="an `mjdrive eval` JSON: its collision episodes")
    parser.add_argument("--seeds", type=int_at_least(0), nargs="*", default=[], help="episode seeds to replay")
    parser.add_argument("--task", default=None, help="DOMAIN/TASK (default: the eval JSON's, else the run's)")
    parser.add_argument("--out", type=Path, default=None, help="also write OUT.md")
    parser.add_argument("--frames", type=Path, default=None,
                        help=f"write the agent's camera frames of the last {FRAMES} steps to FRAMES/seed_SEED.png")
    args = parser.parse_args(argv)

    agent, payload = load_agent(args.checkpoint)
    config = payload["config"]
    seeds, task = list(args.seeds), args.task
    if args.eval:
        result = json.loads(args.eval.read_text())
        seeds += [row["seed"] for row in result["rows"] if row["collision"]]
        task = task or result["task"]
    if not seeds:
        parser.error("no episodes: give --eval with collisions or --seeds")
    domain, name = split_task(task or config["task"])
    env = make_env(domain, name, actions=config.get("actions", "continuous"), **config.get("task_kwargs", {}))
    columns = ["seed", "step", "kind", "ahead_m", "left_m", "bearing_deg", "relative_yaw_deg", "ego_speed",
               "ego_speed_1s", "other_speed", "other_speed_1s", "hit"]
    lines = [f"# Collisions of {args.checkpoint} on {domain}/{name}", "",
             "Road user's centre in the ego frame (x ahead, y left) [m]; bearing from the ego camera's axis "
             "(left +) and heading relative to the ego's [deg]; speeds [m/s] 0.2 s and 1 s before the contact.", "",
             "| " + " | ".join(columns) + " |", "|" + " ---: |" * len(columns)]
    for seed in seeds:
        row = describe_collision(agent, env, seed, args.frames)
        if row is None:
            lines.append(f"| {seed} | no collision on replay |" + " |" * (len(columns) - 2))
            continue
        lines.append("| " + " | ".join(str(row.get(c, "")) for c in columns) + " |")
    env.close()
    report = "\n".join(lines)
    print(report)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.with_suffix(".md").write_text(report + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
