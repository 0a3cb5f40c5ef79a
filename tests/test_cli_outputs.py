"""What a user sees at the keyboard: progress with totals (plain lines in logs), one run per folder, the
summary schema of run, eval and logs."""

from __future__ import annotations

import io
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mjdrive.progress import PLAIN_INTERVAL, Progress

ROOT = Path(__file__).resolve().parents[1]


def mjdrive(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """`mjdrive ARGS` with stdout and stderr captured (so neither is a terminal)."""
    return subprocess.run([sys.executable, "-m", "mjdrive.cli", *args], capture_output=True, text=True,
                          cwd=cwd or ROOT, timeout=120)


def test_progress_writes_plain_lines_with_a_total_and_keeps_talking_during_a_long_step():
    stream = io.StringIO()
    with Progress(total=3, desc="work", unit="step", file=stream) as bar:
        bar.update()
        time.sleep(2 * PLAIN_INTERVAL + 0.6)  # one long step: the heartbeat must still write lines
        bar.update(2)
    text = stream.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    assert all(line.startswith("work: ") for line in lines)
    assert "work: 3/3 (100%)" in lines[-1]
    assert sum("1/3" in line for line in lines) >= 2, lines  # the heartbeat spoke during the long step


def test_progress_on_a_terminal_redraws_in_place():
    stream = io.StringIO()
    with Progress(total=2, desc="work", file=stream, plain=False) as bar:
        bar.update(2)
    assert "\r" in stream.getvalue()


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    out = tmp_path_factory.mktemp("cli") / "run"
    result = mjdrive("run", "--task", "waypoints/straight", "--episodes", "2", "--no-video",
                     "--task-kwarg", "time_limit=3", "--out", str(out))
    assert result.returncode == 0, result.stderr
    return out, result


def test_run_shows_steps_out_of_the_episode_length_without_carriage_returns(run_folder):
    _, result = run_folder
    assert "\r" not in result.stderr
    assert "episode 1/2 (seed 0): " in result.stderr
    assert "/30 (" in result.stderr, result.stderr  # 3 s at 10 Hz: the bar's total is the episode length
