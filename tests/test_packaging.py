"""The server's distribution: one version (sdfserver.__version__, which pyproject.toml reads, the
installed metadata carries and `sdfserver --version` prints), a license, classifiers, and no
invented project URLs."""

from __future__ import annotations

import importlib.metadata
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import sdfserver

ROOT = Path(__file__).resolve().parents[1]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_the_version_is_written_once_and_read_everywhere():
    project = PROJECT["project"]
    assert "version" not in project and "version" in project["dynamic"]
    assert PROJECT["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "sdfserver.__version__"}
    assert re.fullmatch(r"\d+\.\d+\.\d+", sdfserver.__version__)
    assert importlib.metadata.version("sdfserver") == sdfserver.__version__
    written = [p for p in (ROOT / "sdfserver").rglob("*.py") if f'"{sdfserver.__version__}"' in p.read_text()]
    assert written == [ROOT / "sdfserver" / "__init__.py"]


def test_sdfserver_version_prints_it():
    for flag in ("--version", "-V"):
        proc = subprocess.run([sys.executable, "-m", "sdfserver", flag], capture_output=True, text=True, timeout=60,
                              cwd=ROOT)
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout == f"sdfserver {sdfserver.__version__}\n"


def test_license_classifiers_and_urls():
    project = PROJECT["project"]
    assert project["license"] == "MIT" and project["license-files"] == ["LICENSE"]
    assert (ROOT / "LICENSE").read_text().startswith("MIT License\n")
    assert importlib.metadata.metadata("sdfserver")["License-Expression"] == "MIT"
    classifiers = project["classifiers"]
    assert any(c.startswith("Programming Language :: Python :: 3") for c in classifiers)
    assert not any(c.startswith("License ::") for c in classifiers)  # the expression says it
    for url in project.get("urls", {}).values():  # only real addresses, never a placeholder
        assert url.startswith("https://") and not re.search(r"example|your|todo|xxx", url, re.I), url
