"""`sdfserver bench seed --quick`, run as a user runs it, and the report it leaves: every table of
chapter 4 beside the dissertation's numbers with a ratio, every figure, valid PNGs, and a
results.json holding the same numbers as report.md. Also: the web demo's schedule is the CLI's."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from sdfserver.bench.schedule import Schedule
from sdfserver.bench.seed.tables import DISSERTATION, FIGURES, TABLES, figure_file

from server_process import checkout_env

ROOT = Path(__file__).resolve().parents[2]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
ROW = re.compile(r"^\| (\d+)³ \| ([^|]+?) \| ([^|]+?) \| ([^|]+?) \| ([^|]+?) \|$")


def _bench(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    env = checkout_env()
    return subprocess.run([sys.executable, "-m", "sdfserver", "bench", "seed", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("seed") / "out"
    done = _bench("--quick", "--out", str(out))
    assert done.returncode == 0, done.stderr[-3000:]
    return out, done


def _report_rows(text: str) -> dict[str, list[tuple]]:
    """Per table number, the rows (size, metric, ours, dissertation, ratio) of its comparison table."""
    tables, current = {}, None
    for line in text.splitlines():
        heading = re.match(r"^## Table (4\.\d):", line)
        if heading:
            current = tables.setdefault(heading.group(1), [])
        elif line.startswith("## "):
            current = None
        elif current is not None and (m := ROW.match(line)):
            current.append(m.groups())
    return tables


@pytest.mark.slow
def test_quick_run_reports_every_table_and_figure(quick_run):
    out, done = quick_run
    assert "[bench] [1/" in done.stderr and "#" in done.stderr  # the progress bar
    report = (out / "report.md").read_text()
    results = json.loads((out / "results.json").read_text())
    for field in ("Device:", "Date:", "Commit:", "Command: `sdfserver bench seed --quick"):
        assert field in report
    rows = _report_rows(report)
    assert sorted(rows) == [spec.number for spec in TABLES]
    for spec in TABLES:
        assert rows[spec.number], f"Table {spec.number} has no rows"
        expected = {(e["size"], e["metric"]): e for e in results["comparisons"][spec.number]}
        assert len(expected) == len(rows[spec.number])
        for size, metric, ours, theirs, ratio in rows[spec.number]:
            entry = expected[int(size), metric]
            key = next(m.key for m in spec.metrics if m.label == metric)
            assert float(theirs) == pytest.approx(DISSERTATION[spec.number][key][int(size)], rel=1e-4)
            assert float(theirs) == pytest.approx(entry["dissertation"], rel=1e-4)
            if ours.startswith("not available"):
                # Only Table 4.3's improvement, where this quick run has no unchunked run of that size.
                assert metric.startswith("% improvement") and entry["ours"] is None
                continue
            assert float(ours) == pytest.approx(entry["ours"], rel=1e-4)
            assert float(ratio) == pytest.approx(entry["ours"] / entry["dissertation"], rel=1e-3)
    for number in FIGURES:
        assert f"## Figure {number}" in report
        png = out / figure_file(number)
        assert f"![Figure {number}]({png.name})" in report
        assert png.read_bytes()[:8] == PNG_MAGIC and png.stat().st_size < 300_000
    for section in ("figure_4_3", "figure_4_6", "focus_sweep"):
        measured = [r for r in results[section] if "fps" in r]
        assert measured and all(r["fps_recompute"]["n"] == r["edits"] for r in measured)
    assert [r["name"] for r in results["figure_4_5"]] == ["exact", "padded (brute)", "jfa", "conservative"]
    assert results["figure_4_5"][0]["exact_share"] == 1.0


@pytest.mark.slow
def test_plot_only_remakes_the_plots_and_report_from_the_json(quick_run, tmp_path):
    out, _ = quick_run
    copy = tmp_path / "copy"
    copy.mkdir()
    shutil.copy(out / "results.json", copy / "results.json")
    done = _bench("--plot-only", str(copy), timeout=120)
    assert done.returncode == 0, done.stderr[-3000:]
    for number in ("4.3", "4.6", "4.7", "4.8"):
        assert (copy / figure_file(number)).read_bytes()[:8] == PNG_MAGIC
    assert _report_rows((copy / "report.md").read_text()) == _report_rows((out / "report.md").read_text())


@pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed")
def test_the_web_demo_makes_the_cli_schedule():
    script = ("import { schedule } from './sdfserver/web/static/schedule.js';"
              "console.log(JSON.stringify([schedule(7, [64, 32, 48], 40), schedule(2025, [256, 256, 256], 40)]));")
    done = subprocess.run(["node", "--input-type=module", "-e", script], cwd=ROOT, capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0, done.stderr
    js = json.loads(done.stdout)
    assert js == [Schedule((64, 32, 48), 7).first(40), Schedule((256, 256, 256), 2025).first(40)]
