"""`mjdrive drive`: drive a task by hand in MuJoCo's viewer, with the traffic running, the episode's metrics
on screen, and every episode logged to MCAP like `mjdrive run`'s (replayable bit for bit).

Keys (the viewer reports presses, not releases, so commands persist):
  Up      more throttle (or, while braking, less brake)
  Down    less throttle, then more brake
  Left / Right   steer (the wheel returns to centre by itself, STEER_RETURN)
  Enter   end this episode and start the next
Close the window to stop, or send SIGINT (Ctrl-C) or SIGTERM: the episode under way ends as interrupted, its
log is finished and the summary written. A window destroyed from outside (X errors) stops it the same way
(`StopRequests`); an X connection that dies ends the process as Xlib does (the episode's `.mcap.part` stays,
readable, and never blocks the next run in that folder). The view follows the ego from behind (the
`ego/chase` camera; Esc frees it). A mouse perturbation (Ctrl + drag) pushes the car without being logged:
that episode will not replay.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import signal
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

KEY_ENTER, KEY_RIGHT, KEY_LEFT, KEY_DOWN, KEY_UP = 257, 262, 263, 264, 265  # GLFW key codes
PEDAL_STEP = 0.2  # throttle or brake change per key press [0-1]
STEER_STEP = 0.2  # steer change per key press [-1, 1]
STEER_RETURN = 1.5  # [s] time constant of the wheel's return to centre
CAMERA = "ego/chase"
HELP = "Up/Down throttle, brake   Left/Right steer   Enter next episode   close window: quit"


@dataclass
class KeyboardDriver:
    """Throttle, steer and brake from key presses (called on the viewer's thread; read on the driving one)."""

    throttle: float = 0.0
    steer: float = 0.0
    brake: float = 0.0
    next_episode: bool = False

    def __post_init__(self):
        self._lock = threading.Lock()

    def on_key(self, key: int) -> None:
        with self._lock:
            if key == KEY_UP:
                if self.brake > 0:
                    self.brake = max(0.0, self.brake - PEDAL_STEP)
                else:
                    self.throttle = min(1.0, self.throttle + PEDAL_STEP)
            elif key == KEY_DOWN:
                if self.throttle > 0:
                    self.throttle = max(0.0, self.throttle - PEDAL_STEP)
                else:
                    self.brake = min(1.0, self.brake + PEDAL_STEP)
            elif key == KEY_LEFT:
                self.steer = min(1.0, self.steer + STEER_STEP)
            elif key == KEY_RIGHT:
                self.steer = max(-1.0, self.steer - STEER_STEP)
            elif key == KEY_ENTER:
                self.next_episode = True

    def action(self, dt: float) -> np.ndarray:
        """(throttle, steer, brake) for the next control step of `dt` [s]; the wheel then relaxes."""
        with self._lock:
            action = np.array([self.throttle, self.steer, self.brake])
            self.steer *= float(np.exp(-dt / STEER_RETURN))
            return action

    def take_next_episode(self) -> bool:
        with self._lock:
            wanted, self.next_episode = self.next_episode, False
            return wanted

    def reset(self) -> None:
        with self._lock:
            self.throttle = self.steer = self.brake = 0.0


class _XErrorEvent(ctypes.Structure):
    """Xlib's XErrorEvent (the fields up to the codes)."""

    _fields_ = [("type", ctypes.c_int), ("display", ctypes.c_void_p), ("resourceid", ctypes.c_ulong),
                ("serial", ctypes.c_ulong), ("error_code", ctypes.c_ubyte), ("request_code", ctypes.c_ubyte),
                ("minor_code", ctypes.c_ubyte)]


_X_ERROR_HANDLER = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.POINTER(_XErrorEvent))
_X_HANDLERS_SET: list = []  # every handler given to Xlib, kept alive as long as the process (Xlib may call it late)


class StopRequests:
    """Why `drive` should stop before its episodes are done: SIGINT, SIGTERM, or an X error of the viewer.

    Xlib's default error handler ends the process on the spot when the viewer's window is destroyed from
    outside (e.g. `xdotool windowclose`: BadDrawable), leaving the episode's log unfinished; while
    `installed()`, an X error asks the drive to stop instead (the viewer's thread carries on until closed)."""

    def __init__(self):
        self.reason: str | None = None  # what asked to stop, for messages
        self._x_handler = _X_ERROR_HANDLER(self._on_x_error)

    @property
    def requested(self) -> bool:
        return self.reason is not None

    def request(self, reason: str) -> None:
        if self.reason is None:
            self.reason = reason

    def _on_signal(self, signum: int, frame) -> None:
        self.request(signal.Signals(signum).name)

    def _on_x_error(self, display, event) -> int:
        self.request(f"the viewer's window failed (X error {event.contents.error_code}, request "
                     f"{event.contents.request_code}): closed from outside?")
        return 0  # handled: Xlib carries on

    @contextlib.contextmanager
    def installed(self) -> Iterator[StopRequests]:
        """SIGINT and SIGTERM handlers (main thread only; the previous ones are restored on exit) and an Xlib
        error handler (where libX11 is found; it stays, as the viewer's thread may meet X errors until the
        process ends) that call `request`."""
        previous = {}
        if threading.current_thread() is threading.main_thread():
            previous = {sig: signal.signal(sig, self._on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
        name = ctypes.util.find_library("X11")
        if name is not None:
            _X_HANDLERS_SET.append(self._x_handler)
            ctypes.CDLL(name).XSetErrorHandler(self._x_handler)
        try:
            yield self
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def screen_texts(task_name: str, episode: int, steps: int, dt: float, speed: float, action: np.ndarray,
                 reward: float, episode_return: float, info: dict[str, Any], last_outcome: str | None) -> list:
    """The viewer's overlay: metrics top left, keys bottom left."""
    import mujoco

    rows = [("task", task_name), ("episode", str(episode)), ("time", f"{steps * dt:.1f} s (step {steps})"),
            ("speed", f"{3.6 * speed:.1f} km/h"),
            ("throttle / steer / brake", f"{action[0]:.2f} / {action[1]:+.2f} / {action[2]:.2f}"),
            ("reward / return", f"{reward:+.2f} / {episode_return:+.1f}")]
    if info.get("route_completion") is not None:
        rows.append(("route completion", f"{100 * float(info['route_completion']):.0f} %"))
    if info.get("remaining_distance") is not None:
        rows.append(("to destination", f"{float(info['remaining_distance']):.0f} m"))
    if last_outcome:
        rows.append(("last episode", last_outcome))
    return [(mujoco.mjtFontScale.mjFONTSCALE_150, mujoco.mjtGridPos.mjGRID_TOPLEFT,
             "\n".join(name for name, _ in rows), "\n".join(value for _, value in rows)),
            (mujoco.mjtFontScale.mjFONTSCALE_100, mujoco.mjtGridPos.mjGRID_BOTTOMLEFT, "keys", HELP)]


def open_viewer(model, data, key_callback):
    """MuJoCo's passive viewer on `model`/`data` following the ego, and the thread that draws it (joined
    on close, so its window is gone before the process exits)."""
    import mujoco
    import mujoco.viewer

    before = set(threading.enumerate())
    viewer = mujoco.viewer.launch_passive(model, data, key_callback=key_callback, show_left_ui=False,
                                          show_right_ui=False)
    threads = [t for t in threading.enumerate() if t not in before]
    viewer.cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
    viewer.cam.fixedcamid = model.camera(CAMERA).id
    return viewer, threads


def close_viewer(viewer, threads, timeout: float = 5.0) -> None:
    viewer.close()
    for thread in threads:
        thread.join(timeout)


def drive(env, *, episodes: int, seed: int, task_name: str, realtime: float = 1.0,
          on_episode=None, stop: StopRequests | None = None) -> list[dict]:
    """Drive `env` (a gymnasium driving env, recorded or not) by keyboard in MuJoCo's passive viewer for
    `episodes` episodes (0: until the window closes), seeds seed, seed+1, ...; `realtime` >1 runs faster
    than the wall clock. `on_episode(row)` gets each finished episode's summary row; returns the rows.
    `stop` (installed by the caller): a request ends the episode under way as interrupted, and the drive."""
    from mjdrive.record.summary import episode_row, roundabout_arms

    stop = stop or StopRequests()
    base = env.unwrapped
    dt = base.dm_env.control_timestep()  # [s]
    arms = roundabout_arms(base.domain, base.task_name, base.task_kwargs)
    driver = KeyboardDriver()
    rows: list[dict] = []
    viewer, threads = None, []
    model = None
    last_outcome = None
    episode = 0
    try:
        while (episodes == 0 or episode < episodes) and not stop.requested:
            _, info = env.reset(seed=seed + episode)
            driver.reset()
            physics = base.dm_env.physics
            if viewer is None or model is not physics.model.ptr:  # a task may rebuild its model on reset
                if viewer is not None:
                    close_viewer(viewer, threads)
                model = physics.model.ptr
                viewer, threads = open_viewer(model, physics.data.ptr, driver.on_key)
            total, steps, reward = 0.0, 0, 0.0
            terminated = truncated = interrupted = False
            next_tick = time.perf_counter()
            while viewer.is_running() and not stop.requested:
                action = driver.action(dt)
                _, reward, terminated, truncated, info = env.step(action)
                total += reward
                steps += 1
                viewer.set_texts(screen_texts(task_name, episode, steps, dt, float(getattr(base.task, "speed", 0.0)),
                                              action, reward, total, info, last_outcome))
                viewer.sync()
                next_tick += dt / realtime
                time.sleep(max(0.0, next_tick - time.perf_counter()))
                if terminated or truncated:
                    break
                if driver.take_next_episode():
                    interrupted = True
                    break
            else:
                interrupted = True  # the window was closed mid-episode, or a stop was requested
            log = Path(info["record_path"]).name if "record_path" in info else None
            if interrupted and hasattr(env, "recorder"):  # finish the log now, marked interrupted
                path = env.recorder.end(interrupted=True, task=base.task)
                log = path.name if path is not None else log
            row = episode_row(info, episode=episode, seed=seed + episode, reward=total, steps=steps,
                              terminated=terminated, truncated=truncated, interrupted=interrupted, arms=arms,
                              log=log, control_dt=dt)
            last_outcome = row["end"] if row["end"] != "interrupted" else None
            rows.append(row)
            if on_episode is not None:
                on_episode(row)
            episode += 1
            if not viewer.is_running():
                break
    finally:
        if viewer is not None:
            close_viewer(viewer, threads)
    return rows
