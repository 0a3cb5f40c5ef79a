"""Each camera renderer owns its GL context: envs made, closed and dropped in any order leave the survivors'
images bit-identical to an undisturbed run of the same env and seed, with EGL and with OSMesa (the backend is
chosen when mujoco is imported, so each runs in its own process)."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

# Ops of a schedule: "+A:kind" makes env A, "-A" closes it, "~A" drops it unclosed (its renderers are freed
# by the garbage collector), "t" steps every live env once. Each env's images are kept from its reset on.
SCHEDULES = [
    "+A:roundabout +B:waypoints t t -A t +C:gym t -B t +D:roundabout t t ~C t -D",
    "+A:waypoints +B:gym +C:roundabout t -C t -B t +D:waypoints t -A t ~D",
    "+A:gym +B:roundabout t ~A t +C:waypoints t +D:gym -B t t -C t -D",
]

SCRIPT = textwrap.dedent("""
    import gc, hashlib, json, sys
    import numpy as np
    from mjdrive import suite
    from mjdrive.envs.gym_env import make_env

    ACTION = np.array([0.6, 0.08, 0.0])  # throttle, steer, brake: the car moves, so every frame differs

    class DmEnv:
        def __init__(self, domain, task, seed):
            self.env = suite.load(domain, task, task_kwargs={"random": seed, "observation": "camera"})
        def first(self):
            return self.env.reset().observation["image"]
        def next(self):
            return self.env.step(ACTION).observation["image"]
        def close(self):
            self.env.close()

    class GymEnv:
        def __init__(self):
            self.env = make_env("waypoints", "four_routes", observation="camera")
        def first(self):
            return self.env.reset(seed=5)[0]["image"]
        def next(self):
            return self.env.step(ACTION.astype(np.float32))[0]["image"]
        def close(self):
            self.env.close()

    KINDS = {"roundabout": lambda: DmEnv("roundabout", "d120", 0),
             "waypoints": lambda: DmEnv("waypoints", "straight", 1), "gym": GymEnv}

    def digest(image):
        return hashlib.sha1(np.ascontiguousarray(image).tobytes()).hexdigest()

    def undisturbed(kind, steps):
        env = KINDS[kind]()
        images = [digest(env.first())] + [digest(env.next()) for _ in range(steps)]
        env.close()
        return images

    def play(schedule):
        live, kinds, images, done = {}, {}, {}, []
        for op in schedule.split():
            if op == "t":
                for name, env in live.items():
                    images[name].append(digest(env.next()))
            elif op[0] == "+":
                name, kind = op[1:].split(":")
                live[name], kinds[name] = KINDS[kind](), kind
                images[name] = [digest(live[name].first())]
            elif op[0] == "-":
                live.pop(op[1:]).close()
                done.append(op[1:])
            else:  # "~": dropped without close
                del live[op[1:]]
                gc.collect()
                done.append(op[1:])
        return [{"name": n, "kind": kinds[n], "images": images[n]} for n in done]

    references = {kind: undisturbed(kind, 8) for kind in KINDS}
    runs = [play(schedule) for schedule in json.loads(sys.argv[1])]
    print(json.dumps({"references": references, "runs": runs}))
""")


@pytest.mark.parametrize("backend", ["egl", "osmesa"])
def test_closing_envs_in_any_order_leaves_the_others_images_untouched(backend, tmp_path):
    script = tmp_path / "isolation.py"
    script.write_text(SCRIPT)
    env = {**os.environ, "MUJOCO_GL": backend, "PYTHONPATH": str(ROOT)}
    env.pop("PYOPENGL_PLATFORM", None)
    result = subprocess.run([sys.executable, str(script), json.dumps(SCHEDULES)], env=env, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-3000:]
    out = json.loads(result.stdout.strip().splitlines()[-1])
    references = out["references"]
    for kind, images in references.items():  # a frozen image could not pass for a moving car's
        assert all(a != b for a, b in zip(images, images[1:], strict=False)), kind
    checked = 0
    for schedule, run in zip(SCHEDULES, out["runs"], strict=True):
        assert len(run) == 4, schedule
        for env_run in run:
            images, reference = env_run["images"], references[env_run["kind"]]
            assert 2 <= len(images) <= len(reference), (schedule, env_run["name"])
            assert images == reference[:len(images)], (backend, schedule, env_run["name"])
            checked += len(images)
    assert checked >= 40


def test_a_closed_renderer_refuses_to_render_and_others_keep_working():
    from mjdrive import suite
    from mjdrive.sensors import CameraRenderer

    env = suite.load("waypoints", "straight", task_kwargs={"random": 0, "observation": "camera"})
    env.reset()
    model, data = env.physics.raw_model, env.physics.raw_data
    a = CameraRenderer(model, "ego/front", 48, 64)
    b = CameraRenderer(model, "ego/front", 48, 64)
    before = b.render(data).copy()
    a.close()
    a.close()  # idempotent
    with pytest.raises(RuntimeError, match="this CameraRenderer is closed"):
        a.render(data)
    np.testing.assert_array_equal(b.render(data), before)
    assert not np.array_equal(before, np.flipud(before))  # an upside-down frame would not match
    b.close()
    with pytest.raises(ValueError, match=r"no camera 'ego/rear' in the model; cameras: .*ego/front"):
        CameraRenderer(model, "ego/rear", 48, 64)
    with pytest.raises(ValueError, match="image size 0x64 px must be positive"):
        CameraRenderer(model, "ego/front", 0, 64)
    env.close()
    assert env.task.cameras == {}
    assert env.step([0.5, 0.0, 0.0]).observation["image"].shape == (128, 128, 3)  # a closed env renders anew
    env.close()
