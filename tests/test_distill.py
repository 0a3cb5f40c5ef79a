"""Distilling the privileged features teacher into a camera student (agents/distill.py)."""

import csv

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from mjdrive.agents.config import apply_overrides, load_config  # noqa: E402
from mjdrive.agents.distill import distill  # noqa: E402
from mjdrive.agents.evaluate import evaluate, load_agent  # noqa: E402

TEACHER = "results/checkpoints/sac_features_roundabout.pt"  # committed: SAC on the features observation
SMALL = ["task=roundabout/d120", "task_kwargs.image_size=32",
         "algorithm.cnn={channels: [8, 8, 16], kernel: 5, stride: 2, pool: none}", "algorithm.hidden=[64, 64]"]


def _student() -> dict:
    return apply_overrides(load_config("sac_roundabout_camera_state"), SMALL)


def _rows(out):
    with open(out / "distill.csv") as f:
        return list(csv.DictReader(f))


def test_distilled_student_is_a_camera_sac_policy_that_fits_the_teacher(tmp_path):
    short = distill(TEACHER, _student(), tmp_path / "a", progress=False, iterations=2, steps_per_iteration=120,
                    epochs=1)
    rows = _rows(tmp_path / "a")
    assert [r["driver"] for r in rows] == ["teacher", "student"] and int(rows[-1]["samples"]) == 240
    assert int(rows[0]["episodes"]) >= 1 and 0.0 <= float(rows[0]["success"]) <= 1.0
    agent, payload = load_agent(short)
    assert payload["algo"] == "sac" and payload["extra"]["distilled_from"] == TEACHER
    assert agent.layout.image_key == "image"  # the student sees the camera, not the road users
    result = evaluate(short, episodes=2, task="roundabout/d120")
    assert all(r["steps"] > 0 for r in result["rows"])
    on_road = [r["success"] and not r["off_road"] for r in result["rows"]]
    assert result["summary"]["success_on_road_pct"] == 100 * np.mean(on_road) <= result["summary"]["success_pct"]
    # more epochs on the same samples fit the teacher's actions better
    long = distill(TEACHER, _student(), tmp_path / "b", progress=False, iterations=1, steps_per_iteration=120,
                   epochs=12, batch_size=16)
    first = distill(TEACHER, _student(), tmp_path / "c", progress=False, iterations=1, steps_per_iteration=120,
                    epochs=1, batch_size=16)
    assert long and first
    assert float(_rows(tmp_path / "b")[0]["loss"]) < 0.5 * float(_rows(tmp_path / "c")[0]["loss"])
    assert np.isfinite(float(rows[-1]["loss"]))


def test_teacher_must_see_the_features(tmp_path):
    camera_teacher = distill(TEACHER, _student(), tmp_path / "s", progress=False, iterations=1,
                             steps_per_iteration=20, epochs=1)
    with pytest.raises(ValueError, match="teacher must see the features"):
        distill(camera_teacher, _student(), tmp_path / "t", progress=False, iterations=1, steps_per_iteration=10)
    with pytest.raises(ValueError, match="unknown distillation settings"):
        distill(TEACHER, _student(), tmp_path / "u", progress=False, epoch=3)
