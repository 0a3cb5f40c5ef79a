"""Every bad input of results/robustness.md gives the documented error: a ValueError (ConfigError for task
keywords) naming what is wrong, or on the command line one line and exit status 2; a checkpoint's pickle
payload never runs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tools import robustness

ROOT = Path(__file__).resolve().parents[1]


def test_every_bad_input_gives_a_clear_error():
    results = robustness.run_all()  # raises if a checkpoint's payload ran
    assert len(results) >= 60
    failures = [f"{case.entry} {case.shown}: {outcome.kind}: {outcome.message}"
                for case, outcome in results if not outcome.expected(case)]
    assert sum(case.status is not None for case, _ in results) >= 9  # the handled cases ran too
    assert not failures, "\n".join(failures)


def test_the_committed_table_lists_every_case():
    table = (ROOT / "results" / "robustness.md").read_text()
    missing = [case.shown for case in robustness.cases() if f"`{case.shown}`" not in table]
    assert not missing, f"results/robustness.md is stale (python tools/robustness.py --out ...): {missing}"
    assert "**accepted**" not in table and "**crash**" not in table


def test_a_user_mistake_prints_one_line_in_a_real_process(tmp_path):
    """The command line as a user runs it: one line on stderr, exit status 2, no traceback."""
    for argv in (["replay", str(tmp_path / "missing.mcap")], ["logs", str(tmp_path)],
                 ["run", "--task", "waypoints/straight", "--task-kwarg", "time_limit=-5"]):
        done = subprocess.run([sys.executable, "-m", "mjdrive.cli", *argv], capture_output=True, text=True,
                              cwd=tmp_path, timeout=120)
        assert done.returncode == 2, (argv, done.stderr)
        assert len(done.stderr.strip().splitlines()) == 1 and "Traceback" not in done.stderr, done.stderr
        assert done.stderr.startswith(f"mjdrive {argv[0]}: error: ")


def test_a_study_tool_reports_a_user_mistake_in_one_line_in_a_real_process(tmp_path):
    """`python -m tools.NAME` as a user runs it (from the repository): a missing checkpoint and a bad count each
    give one line on stderr naming the tool, exit status 2, no traceback."""
    for argv in (["roundabout_table3", "--episodes", "1", "--agent", "A", str(tmp_path / "missing.pt")],
                 ["urban_table2", "--episodes", "0"]):
        done = subprocess.run([sys.executable, "-m", f"tools.{argv[0]}", *argv[1:]], capture_output=True, text=True,
                              cwd=ROOT, timeout=120)
        assert done.returncode == 2, (argv, done.stderr)
        assert len(done.stderr.strip().splitlines()) == 1 and "Traceback" not in done.stderr, done.stderr
        assert done.stderr.startswith(f"{argv[0]}.py: error: "), done.stderr


def test_a_figure_tool_without_matplotlib_names_the_extra_in_one_line(tmp_path):
    """`python -m tools.urban_figures` where matplotlib is not installed (blocked here): one line naming the
    `plot` extra, exit status 2, no traceback; a missing package that is no extra's still raises."""
    block = "import runpy, sys; sys.modules['matplotlib'] = None; sys.argv = ['urban_figures.py', *sys.argv[1:]]; "
    done = subprocess.run([sys.executable, "-c", block + "runpy.run_module('tools.urban_figures', run_name='__main__')",
                           "--time-limit", "1", "--out", str(tmp_path)], capture_output=True, text=True, cwd=ROOT,
                          timeout=120)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip() == ("urban_figures.py: error: this needs matplotlib, which is not installed: pip "
                                   "install 'mjdrive[plot]' (or pip install -e '.[plot]' in a clone)"), done.stderr
    assert not list(tmp_path.iterdir())
    from mjdrive.cli import run_reporting_errors

    def missing_other():
        raise ModuleNotFoundError("No module named 'not_an_extra'", name="not_an_extra")

    with pytest.raises(ModuleNotFoundError):
        run_reporting_errors("tool", missing_other)
