"""docs/benchmarks.md names only what exists, every raw result in docs/results/ backs a figure
there, and tools/ holds only what reproduces a documented figure (named in the benchmark or
rendering document, or used by a tool that is)."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = (ROOT / "docs" / "benchmarks.md").read_text()


def test_every_tool_and_result_named_exists():
    named = set(re.findall(r"\b(tools/[\w.-]+\.(?:py|sh))", DOC))
    named |= {f"docs/{p}" for p in re.findall(r"\]\((results/[^)#]+)\)", DOC)}
    assert named
    assert not sorted(p for p in named if not (ROOT / p).exists())


def test_every_result_backs_a_figure():
    linked = {p.split("/")[1] for p in re.findall(r"\]\((results/[^)#]+)\)", DOC)}
    assert not sorted(p.name for p in (ROOT / "docs" / "results").iterdir() if p.name not in linked)


def test_tools_hold_only_what_reproduces_a_documented_figure():
    docs = DOC + (ROOT / "docs" / "rendering.md").read_text()
    tools = {p.name: p.read_text() for p in (ROOT / "tools").iterdir() if p.suffix in (".py", ".sh")}
    kept = {name for name in tools if name in docs}
    kept |= {helper for helper in tools for name in kept if helper != name and Path(helper).stem in tools[name]}
    assert not sorted(set(tools) - kept)
