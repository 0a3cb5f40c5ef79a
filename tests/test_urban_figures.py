"""tools.urban_figures: a short autopilot episode of urban/concatenated drawn as PNG (Fig. 9/10)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from tools import urban_figures  # noqa: E402

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
TIME_LIMIT = 3.0  # [s] a short episode: 30 control steps at 10 Hz


def test_cli_writes_both_figures(tmp_path, capsys):
    assert urban_figures.main(["--seed", "3", "--time-limit", str(TIME_LIMIT), "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "seed 3: time_limit after 3.0 s (30 steps)" in out
    assert "jerk_max_mps3" in out and "accel_p95_mps2" in out
    for name in ("autopilot_seed3.png", "autopilot_seed3_peak.png"):
        data = (tmp_path / name).read_bytes()
        assert data[:8] == PNG_MAGIC and len(data) > 30_000  # [bytes] five panels with curves, not a blank


def test_plotted_series_span_the_episode(tmp_path):
    episode = urban_figures.drive(3, time_limit=TIME_LIMIT)
    n = episode.info["steps"] + 1  # samples: the start and after every control step
    assert episode.end == "time_limit" and n == 31
    assert len(episode.time) == len(episode.steering) == len(episode.scenario) == n
    assert episode.commands.shape == (n - 1, 3)
    assert episode.profile.window == 5 and np.isfinite(episode.jerk).all()
    metrics = episode.profile.metrics().as_dict()  # the task's own comfort metrics, from the same samples
    assert all(metrics[k] == pytest.approx(episode.info[k]) for k in metrics)

    fig = urban_figures.draw(episode, tmp_path / "f.png")
    assert (tmp_path / "f.png").stat().st_size > 30_000
    lengths = {line.get_label(): len(line.get_xdata()) for ax in fig.axes for line in ax.get_lines()}
    for label in ("speed", "steering angle", "a_lon", "a_lat", "jerk_lon", "jerk_lat", "|jerk|"):
        assert lengths[label] == n, label
    assert lengths["throttle"] == lengths["brake"] == n - 1  # commands held between samples
    spans = urban_figures.scenario_spans(episode.time, episode.scenario)
    assert spans[0][0] == 0.0 and spans[-1][1] == pytest.approx(episode.time[-1] + 0.1)
