"""The README's two commands are what CI runs, and what the docs name exists."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def readme_commands() -> list[str]:
    return [line.strip() for line in (ROOT / "README.md").read_text().splitlines()
            if line.startswith("    python3 -m venv")]


def test_ci_runs_exactly_the_readme_test_command():
    commands = readme_commands()
    assert len(commands) == 2, commands
    serve, test = commands
    assert serve.endswith("sdfserver serve") and "pytest" in test
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert test in [line.strip() for line in ci], "README's test command must appear verbatim in .ci/run"


def test_docs_named_in_the_readme_exist():
    text = (ROOT / "README.md").read_text()
    for path in set(re.findall(r"`((?:docs|deploy|clients|tools)/[\w./-]+)`", text)):
        assert (ROOT / path).exists(), path
