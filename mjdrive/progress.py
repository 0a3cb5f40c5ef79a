"""Progress of long commands: a tqdm bar with a total and an ETA on a terminal, plain lines elsewhere.

On a terminal the bar redraws itself in place; when stderr is a file or a pipe (a log, CI), every update
that is due writes one whole line instead of carriage returns. A heartbeat thread redraws the bar (or writes
a line) when nothing has updated it for a while, so a command never goes silent during one long step.
"""

from __future__ import annotations

import sys
import threading
import time
from typing import IO, Any

from tqdm import tqdm

HEARTBEAT = 0.5  # [s] how often the heartbeat thread looks at the bar
TERMINAL_REFRESH = 1.0  # [s] longest pause between redraws on a terminal
PLAIN_INTERVAL = 1.5  # [s] shortest pause between two plain lines (and the longest silence)
PLAIN_FORMAT = "{desc}: {n_fmt}/{total_fmt} ({percentage:.0f}%) [{elapsed}<{remaining}, {rate_fmt}{postfix}]"
PLAIN_FORMAT_NO_TOTAL = "{desc}: {n_fmt} [{elapsed}, {rate_fmt}{postfix}]"


def is_terminal(stream: IO[str]) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


class Progress(tqdm):
    """A tqdm bar on stderr that writes plain lines when stderr is not a terminal (`plain=None`: decide
    from the stream) and redraws at least every `TERMINAL_REFRESH` s (terminal) or `PLAIN_INTERVAL` s (lines).
    Use as tqdm: `with Progress(total=n, desc="...", unit="step") as bar: ... bar.update()`."""

    def __init__(self, iterable: Any = None, *, plain: bool | None = None, file: IO[str] | None = None, **kwargs):
        global _STARTING
        if _STARTING is not None and not isinstance(self, Starting):  # the command's real progress begins
            _STARTING.close()
            _STARTING = None
        file = sys.stderr if file is None else file
        self.plain = not is_terminal(file) if plain is None else plain
        if self.plain:
            total = kwargs.get("total", len(iterable) if hasattr(iterable, "__len__") else None)
            kwargs.setdefault("bar_format", PLAIN_FORMAT if total else PLAIN_FORMAT_NO_TOTAL)
            kwargs.setdefault("mininterval", PLAIN_INTERVAL)
            kwargs["leave"] = False  # close() writes the last line itself, once
        else:
            kwargs.setdefault("dynamic_ncols", True)
        kwargs.setdefault("miniters", 1)
        self._stop = threading.Event()
        self._shown = False  # drawn once (a bar with a `delay` is first drawn by the heartbeat once it passed)
        super().__init__(iterable, file=file, **kwargs)
        self._heartbeat = None
        if not self.disable:
            self._heartbeat = threading.Thread(target=self._beat, daemon=True, name="progress-heartbeat")
            self._heartbeat.start()

    def _beat(self) -> None:
        interval = PLAIN_INTERVAL if self.plain else TERMINAL_REFRESH
        while not self._stop.wait(HEARTBEAT):
            if time.time() - self.start_t < self.delay:
                continue
            if not self._shown or time.time() - self.last_print_t >= interval:
                self.refresh()

    def __iter__(self):
        """Iterate through `update()`: tqdm's own loop keeps the count in a local and assumes nothing else
        prints, so a heartbeat redraw between its updates made it count steps twice (229/228)."""
        if self.disable:
            yield from self.iterable
            return
        try:
            for obj in self.iterable:
                yield obj
                self.update()
        finally:
            self.close()

    def refresh(self, nolock: bool = False, lock_args: Any = None) -> None:
        super().refresh(nolock=nolock, lock_args=lock_args)
        self._shown = True
        self.last_print_t, self.last_print_n = time.time(), self.n

    def display(self, msg: str | None = None, pos: int | None = None) -> None:
        if not self.plain:
            super().display(msg, pos)
            return
        if msg == "":  # tqdm clearing a bar that does not stay: nothing to clear in a log
            return
        self.fp.write((msg if msg is not None else self.__str__()) + "\n")
        self.fp.flush()

    def close(self) -> None:
        self._stop.set()
        if self._heartbeat is not None and self._heartbeat is not threading.current_thread():
            self._heartbeat.join()
        if self.plain and not self.disable and self.n != self.last_print_n:
            self.refresh()  # the final count, once
        super().close()


_STARTING: Progress | None = None  # the open `Starting` status, closed by the next Progress


class Starting(Progress):
    """'COMMAND: loading ... [elapsed]' while a command loads (torch, a checkpoint, its envs), shown only when
    that takes more than `delay` s (so a quick one-line error stays one line) and gone as soon as the
    command's own progress bar starts or the command ends. `stdout_in_logs`: when the stream is not a terminal
    (a log or pipe), write the lines to stdout instead (for a wait that may end in a user's mistake: on a
    terminal the status line is erased before the error; in a log stderr keeps the error to one line, and the
    wait is still heard, never silent for more than `delay` + PLAIN_INTERVAL)."""

    def __init__(self, desc: str, delay: float = 1.0, stdout_in_logs: bool = False, **kwargs):
        global _STARTING
        if stdout_in_logs and not is_terminal(kwargs.get("file") or sys.stderr):
            kwargs["file"] = sys.stdout
        super().__init__(desc=desc, bar_format="{desc} [{elapsed}]", delay=delay, leave=False, **kwargs)
        _STARTING = self

    def close(self) -> None:
        global _STARTING
        if _STARTING is self:
            _STARTING = None
        super().close()


def note(message: str, file: IO[str] | None = None) -> None:
    """One status line on stderr (what a command is about to do), flushed at once."""
    stream = sys.stderr if file is None else file
    stream.write(message + "\n")
    stream.flush()
