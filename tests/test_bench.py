"""The benchmarks' timing: what a timed round may and may not include."""

from __future__ import annotations

import subprocess
import sys

from mjdrive.bench import _timed_rate, calls_per_second

FIRST_STEP_SEES = """
import sys
from mjdrive.bench import {name}
seen = []
{call}
print(seen[0])
"""


def first_step_sees_scipy_signal(name: str, call: str) -> str:
    """In a fresh process (nothing imported yet): whether scipy.signal was imported when the benchmark's first call
    of the step ran."""
    code = FIRST_STEP_SEES.format(name=name, call=call)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_timed_steps_find_scipy_signal_already_imported():
    """An env imports scipy.signal at its first episode end (~0.5 s, the comfort metrics); the benchmark imports it
    before it times anything, so that no timed round pays that one-off."""
    step = "lambda: seen.append('scipy.signal' in sys.modules)"
    assert first_step_sees_scipy_signal(calls_per_second.__name__, f"calls_per_second({step}, 0.01)") == "True"
    assert first_step_sees_scipy_signal(_timed_rate.__name__, f"_timed_rate({step}, 0.01, lambda: 0.0)") == "True"
