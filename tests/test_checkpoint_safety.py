"""Checkpoints never run code: every policy, checkpoint and ensemble file is read with
`torch.load(weights_only=True)`, and each bad file (a pickle that would run code, text, empty, truncated, a
directory, a missing path, an ensemble whose member is missing or changed) is a one-line CheckpointError from
the loader and `mjdrive: error: ...` with exit status 2 from `mjdrive eval` and `mjdrive ensemble`."""

import hashlib
import json
import os
import pickle
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")

from mjdrive.agents.checkpoints import CheckpointError, load_checkpoint, save_checkpoint  # noqa: E402
from mjdrive.agents.evaluate import load_agent  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
COMMITTED = sorted((ROOT / "results" / "checkpoints").glob("*.pt"))
ENSEMBLE_CONFIG = {"algo": "ensemble", "task": "waypoints/straight", "actions": "pedal", "task_kwargs": {}}


class _RunsCode:
    """Unpickles into a call of exec(code): the payload of a malicious checkpoint."""

    def __init__(self, code: str):
        self.code = code

    def __reduce__(self):
        return exec, (self.code,)


def _touch(marker: Path) -> _RunsCode:
    return _RunsCode(f"open({str(marker)!r}, 'w').close()")


def _write_evil(path: Path, marker: Path, kind: str) -> Path:
    """A file that creates `marker` when unpickled: torch's zip format or a bare pickle (protocol 2 or 4)."""
    payload = {"format": "mjdrive.agents.checkpoint", "version": 1, "state": _touch(marker)}
    if kind == "torch":
        torch.save(payload, path)
    else:
        path.write_bytes(pickle.dumps(payload, protocol=int(kind[-1])))
    return path


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _ensemble(path: Path, members: list[dict] | object) -> Path:
    return save_checkpoint(path, "ensemble", ENSEMBLE_CONFIG, {"rule": "mean", "members": members}, step=0,
                           extra={"inference_only": True})


def _bad_files(tmp_path: Path, marker: Path) -> dict[str, tuple[Path, str]]:
    """name: (bad file, the start of the error it must give)."""
    real = COMMITTED[0]
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(real.read_bytes()[:4000])
    text = tmp_path / "notes.pt"
    text.write_text("these are my notes, not a checkpoint\n")
    empty = tmp_path / "empty.pt"
    empty.write_bytes(b"")
    (tmp_path / "folder.pt").mkdir()
    evil = {kind: _write_evil(tmp_path / f"evil_{kind}.pt", marker, kind) for kind in ("torch", "pickle2", "pickle4")}
    member = tmp_path / "member.pt"
    member.write_bytes(real.read_bytes())
    ens = tmp_path / "ens"
    ens.mkdir()
    return {
        "evil_torch": (evil["torch"], "is refused: it would call or build the Python object exec;"),
        "evil_pickle2": (evil["pickle2"], "is refused: it would call or build the Python object exec;"),
        "evil_pickle4": (evil["pickle4"], "is refused: it is a pickle the safe unpickler cannot read"),
        "text": (text, "is not a torch file (it starts with b'thes', neither a zip archive nor a pickle)"),
        "empty": (empty, "is empty (0 bytes)"),
        "truncated": (truncated, "is corrupt or not a torch file (RuntimeError: PytorchStreamReader failed"),
        "missing": (tmp_path / "missing.pt", "does not exist"),
        "directory": (tmp_path / "folder.pt", "is a directory, not a checkpoint file"),
        "member_missing": (_ensemble(ens / "gone.pt", [{"path": "../nowhere.pt", "sha256": "0" * 64}]),
                           "its member ../nowhere.pt is missing"),
        "member_changed": (_ensemble(ens / "changed.pt", [{"path": "../member.pt", "sha256": "0" * 64}]),
                           "has changed since the ensemble was made"),
        "member_evil": (_ensemble(ens / "evil.pt", [{"path": "../evil_torch.pt",
                                                     "sha256": _sha256(evil["torch"])}]),
                        "is refused: it would call or build the Python object exec;"),
        "members_malformed": (_ensemble(ens / "malformed.pt", "../member.pt"),
                              "an ensemble's 'members' must be a list"),
    }


@pytest.fixture
def marker(tmp_path) -> Path:
    return tmp_path / "PAYLOAD_RAN"


def test_the_malicious_files_do_run_code_when_unpickled_unsafely(tmp_path):
    """The control: a plain pickle.load of the test's evil files runs their payload (so the other tests'
    'the marker does not exist' could fail)."""
    for kind in ("torch", "pickle2", "pickle4"):
        marker = tmp_path / f"ran_{kind}"
        path = _write_evil(tmp_path / f"{kind}.pt", marker, kind)
        if kind == "torch":
            torch.load(path, weights_only=False)
        else:
            pickle.loads(path.read_bytes())
        assert marker.exists(), kind


def test_every_committed_checkpoint_loads_with_weights_only():
    assert len(COMMITTED) >= 10
    for path in COMMITTED:
        payload = load_checkpoint(path)
        assert payload["algo"] in ("sac", "dqn", "ppo", "trpo", "ppo_discrete", "ensemble", "hybrid"), path
        torch.load(path, map_location="cpu", weights_only=True)  # no allow-list needed at all


def test_the_loader_refuses_each_bad_file_with_one_line(tmp_path, marker):
    for name, (path, expected) in _bad_files(tmp_path, marker).items():
        with pytest.raises(CheckpointError) as caught:
            load_agent(path)
        message = str(caught.value)
        assert expected in message and "\n" not in message and len(message) < 400, (name, message)
        assert isinstance(caught.value, ValueError)
    assert not marker.exists()


def test_save_checkpoint_writes_only_tensors_and_plain_data(tmp_path):
    import numpy as np

    path = save_checkpoint(tmp_path / "c.pt", "sac", {"task": "waypoints/straight", "out": tmp_path},
                           {"w": torch.ones(2), "n": np.float32(0.5), "a": np.arange(3)}, step=np.int64(7))
    assert torch.serialization.get_unsafe_globals_in_checkpoint(path) == []
    payload = load_checkpoint(path)
    assert payload["config"]["out"] == str(tmp_path) and payload["step"] == 7
    assert type(payload["state"]["n"]) is float and torch.equal(payload["state"]["a"], torch.arange(3))
    with pytest.raises(TypeError, match=r"checkpoint\['state'\]\['f'\] is a builtins.function"):
        save_checkpoint(tmp_path / "d.pt", "sac", {"task": "waypoints/straight"}, {"f": lambda: None}, step=0)
    assert not (tmp_path / "d.pt").exists()


def _assert_cli_error(returncode: int, stderr: str, expected: str) -> None:
    lines = stderr.strip().splitlines()
    assert returncode == 2, stderr
    assert len(lines) == 1 and re.match(r"mjdrive( \w+)?: error: ", lines[0]), stderr
    assert re.search(expected, lines[0]), (expected, stderr)
    assert "Traceback" not in stderr


def _env() -> dict[str, str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("MJDRIVE_DEBUG", None)  # it would show tracebacks
    return env


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = _env()
    return subprocess.run([sys.executable, "-m", "mjdrive.cli", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=120)


def test_the_cli_refuses_a_malicious_checkpoint_without_running_it(tmp_path, marker):
    evil = _write_evil(tmp_path / "evil.pt", marker, "torch")
    result = _cli("eval", "--checkpoint", "evil.pt", "--episodes", "1", cwd=tmp_path)
    _assert_cli_error(result.returncode, result.stderr, "checkpoint evil.pt is refused: it would call or build the "
                      "Python object exec")
    result = _cli("ensemble", "--out", "e.pt", str(_write_evil(tmp_path / "p.pt", marker, "pickle2")), str(evil),
                  cwd=tmp_path)
    _assert_cli_error(result.returncode, result.stderr, r"p\.pt is refused: it would call or build the Python object")
    assert not marker.exists() and not (tmp_path / "e.pt").exists()


# the command line checks that a path exists and is a file before the loader sees it (its own wording)
CLI_EXPECTED = {"missing": "no such file|does not exist", "directory": "is a folder, not a file|is a directory"}

# `mjdrive eval` and `mjdrive ensemble` on every bad file in one process (a subprocess per case would take a
# minute): cli.main as `python -m mjdrive.cli` runs it, with stdout and stderr captured per case.
DRIVER = textwrap.dedent("""
    import contextlib, io, json, sys, traceback
    from mjdrive.cli import main
    results = []
    for argv in json.loads(sys.argv[1]):
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(argv)
            except SystemExit as exit:  # argparse's own errors: what the process would exit with
                code = exit.code
            except BaseException:
                code, err = -1, io.StringIO(err.getvalue() + traceback.format_exc())
        results.append({"argv": argv, "code": code, "stderr": err.getvalue()})
    print(json.dumps(results))
""")


def test_eval_and_ensemble_commands_give_one_line_for_each_bad_file(tmp_path, marker):
    cases = _bad_files(tmp_path, marker)
    good = str(COMMITTED[0])
    commands = []
    for name, (path, expected) in cases.items():
        expected = CLI_EXPECTED.get(name, re.escape(expected))
        commands.append((["eval", "--checkpoint", str(path), "--episodes", "1", "--no-record"], expected))
        if not name.startswith("member"):  # an ensemble's own members are checkpoints, never ensembles
            commands.append((["ensemble", "--out", str(tmp_path / "out.pt"), good, str(path)], expected))
    driver = tmp_path / "driver.py"
    driver.write_text(DRIVER)
    result = subprocess.run([sys.executable, str(driver), json.dumps([argv for argv, _ in commands])], cwd=tmp_path,
                            env=_env(), capture_output=True, text=True, timeout=300)
    assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr[-3000:]
    outcomes = json.loads(result.stdout.strip().splitlines()[-1])
    assert len(outcomes) == len(commands) >= 20
    for outcome, (argv, expected) in zip(outcomes, commands, strict=True):
        assert outcome["argv"] == argv
        _assert_cli_error(outcome["code"], outcome["stderr"], expected)
    assert not marker.exists() and not (tmp_path / "out.pt").exists()
