"""`mjdrive drive` under Xvfb: start it, press keys, take a screenshot, and check that the car moved as
told and that its log replays bit for bit."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mjdrive.envs.replay import replay
from mjdrive.record.reader import read_episode

if shutil.which("Xvfb") is None or shutil.which("xdotool") is None:
    pytest.skip("needs Xvfb and xdotool (Debian: apt-get install xvfb xdotool; `make test` installs them)",
                allow_module_level=True)


@pytest.fixture()
def display():
    number = next(n for n in range(90, 200) if not Path(f"/tmp/.X{n}-lock").exists())
    server = subprocess.Popen(["Xvfb", f":{number}", "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    socket = Path(f"/tmp/.X11-unix/X{number}")
    deadline = time.monotonic() + 10
    while not socket.exists():
        assert server.poll() is None and time.monotonic() < deadline, "Xvfb did not start"
        time.sleep(0.1)
    yield f":{number}"
    server.terminate()
    server.wait(10)


def xdotool(display: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["xdotool", *args], env={**os.environ, "DISPLAY": display}, capture_output=True,
                          text=True, timeout=40)


def test_drive_by_keyboard_moves_the_car_and_logs_a_replayable_episode(display, tmp_path):
    from PIL import ImageGrab

    out = tmp_path / "drive"
    command = subprocess.Popen(
        [sys.executable, "-m", "mjdrive.cli", "drive", "--task", "waypoints/straight", "--episodes", "1",
         "--task-kwarg", "time_limit=6", "--out", str(out)],
        env={**os.environ, "DISPLAY": display}, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        found = xdotool(display, "search", "--sync", "--name", "MuJoCo")
        assert found.returncode == 0, found.stderr
        # keys go to the focused window: focus the viewer and let it settle (on a busy machine the first keys
        # could otherwise arrive before it takes input)
        xdotool(display, "windowfocus", "--sync", found.stdout.split()[0])
        time.sleep(0.5)
        xdotool(display, "key", "Up", "Up", "Up", "Up")  # throttle 0.8
        time.sleep(1.5)
        screenshot = ImageGrab.grab(xdisplay=display)
        if os.environ.get("MJDRIVE_SCREENSHOT"):  # how docs/images/drive.png is made
            screenshot.save(os.environ["MJDRIVE_SCREENSHOT"])
        xdotool(display, "key", "Left")  # steer 0.2, returning to centre by itself
        time.sleep(0.3)
        xdotool(display, "key", "Right")
        stdout, stderr = command.communicate(timeout=60)
    finally:
        if command.poll() is None:
            command.kill()
    assert command.returncode == 0, stderr
    pixels = np.asarray(screenshot.convert("RGB"), dtype=float)
    assert pixels.std() > 20  # a rendered scene with the metrics box, not a blank screen
    summary = json.loads((out / "summary.json").read_text())
    assert summary["command"] == "drive" and summary["policy"] == "keyboard"
    row = summary["rows"][0]
    assert row["distance_m"] > 3.0 and row["steps"] > 10, row  # it drove (a late key may end it in a marking)
    episode = read_episode(out / row["log"])
    actions = episode.actions()
    assert actions[:, 0].max() == pytest.approx(0.8) and actions[:, 1].max() > 0.1  # the keys reached the car
    assert replay(out / row["log"]).match


@pytest.mark.parametrize("stop", ["SIGINT", "SIGTERM", "windowclose"])
def test_drive_stops_cleanly_on_a_signal_or_its_window_destroyed(stop, display, tmp_path):
    """Ctrl-C (SIGINT), SIGTERM or the viewer's window destroyed from outside (`xdotool windowclose`: an X
    BadDrawable error, which Xlib's default handler turns into an exit) each end the drive within seconds: the
    episode under way is logged as interrupted and replays, and summary.json is written."""
    import signal

    out = tmp_path / "drive"
    command = subprocess.Popen(
        [sys.executable, "-m", "mjdrive.cli", "drive", "--task", "waypoints/straight", "--out", str(out)],
        env={**os.environ, "DISPLAY": display}, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        found = xdotool(display, "search", "--sync", "--name", "MuJoCo")
        assert found.returncode == 0, found.stderr
        time.sleep(3.0)  # steps driven (on a loaded machine the first ones may be late: none is required)
        if stop == "windowclose":
            xdotool(display, "windowclose", found.stdout.split()[0])
        else:
            command.send_signal(getattr(signal, stop))
        start = time.monotonic()
        stdout, stderr = command.communicate(timeout=30)
        took = time.monotonic() - start
    finally:
        if command.poll() is None:
            command.kill()
            command.communicate()
    assert command.returncode == 0, stderr
    assert took < 15, took
    assert "mjdrive drive: stopped: " + ("SIGINT" if stop == "SIGINT" else "SIGTERM" if stop == "SIGTERM" else
                                         "the viewer's window failed (X error 9") in stderr, stderr
    assert "Traceback" not in stderr and "X Error" not in stderr
    summary = json.loads((out / "summary.json").read_text())
    assert [row["end"] for row in summary["rows"]] == ["interrupted"]
    assert not list(out.glob("*.part"))
    episode = read_episode(out / summary["rows"][0]["log"])
    assert episode.intact and episode.summary["interrupted"]
    assert episode.summary["steps"] == len(episode.messages.get("/action", [])) == summary["rows"][0]["steps"]
    assert replay(out / summary["rows"][0]["log"]).match
