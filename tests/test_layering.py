"""The package's shape: what an install adds to site-packages."""

from __future__ import annotations

from pathlib import Path

import setuptools
from setuptools.config.pyprojecttoml import read_configuration

ROOT = Path(__file__).resolve().parents[1]


def test_the_only_top_level_package_is_mjdrive():
    options = read_configuration(ROOT / "pyproject.toml")["tool"]["setuptools"]
    packages = options["packages"]
    assert {name.split(".")[0] for name in packages} == {"mjdrive"}
    assert options["package-dir"] == {"mjdrive.agents": "agents"}
    # the list names every package in the source tree: mjdrive/'s and the agents/ folder's (as mjdrive.agents)
    found = setuptools.find_packages(str(ROOT), include=["mjdrive", "mjdrive.*"])
    found += ["mjdrive.agents." + name for name in setuptools.find_packages(str(ROOT / "agents"))]
    assert sorted(packages) == sorted(found + ["mjdrive.agents"])


def test_agents_import_as_mjdrive_agents():
    import mjdrive.agents

    assert Path(mjdrive.agents.__file__).resolve().parent == ROOT / "agents"
