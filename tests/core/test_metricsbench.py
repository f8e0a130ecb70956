"""`sdfserver bench metrics --quick` runs end to end on the CPU device: a row per metric, sign and
size in each section, every field exactly scipy's, and the report in Markdown and JSON."""

import json
import signal
import subprocess
import sys
from pathlib import Path

from sdfserver.bench.cli import main as bench_main

ROOT = Path(__file__).resolve().parents[2]
FIELDS = {("manhattan", False), ("manhattan", True), ("euclidean", False), ("euclidean", True)}


def test_metrics_bench_quick(tmp_path, capsys):
    out = tmp_path / "metrics"
    assert bench_main(["metrics", "--quick", "--out", str(out), "--no-cupy"]) == 0
    report = json.loads((out / "metrics.json").read_text())
    assert report["device"] and report["argv"][:4] == ["sdfserver", "bench", "metrics", "--quick"]
    assert "interrupted" not in report

    full = {(r["metric"], r["signed"], r["world_size"]): r for r in report["full"]}
    assert set(full) == {(m, s, n) for m, s in FIELDS for n in (32, 64)}
    assert all(r["n"] == 2 and 0 < r["min_ms"] <= r["median_ms"] and r["wall_median_ms"] > 0 for r in full.values())

    accuracy = {(r["metric"], r["signed"], r["world_size"], r["after"]): r for r in report["accuracy"]}
    assert set(accuracy) == {(*key, "full") for key in full} | {(m, s, 64, "brushes") for m, s in FIELDS}
    assert all(r["exact_share"] == 1.0 and r["max_abs_error"] == 0 for r in accuracy.values())

    brush = {(r["metric"], r["signed"], r["place"]): r for r in report["brush"]}
    assert set(brush) == {(m, s, p) for m, s in FIELDS for p in ("random", "centre")}
    assert all(r["world_size"] == 64 and r["n"] == 4 and r["median_ms"] > 0 for r in brush.values())

    queries = {(r["metric"], r["signed"], r["kind"]): r for r in report["queries"]}
    assert set(queries) == {(m, s, k) for m, s in FIELDS for k in ("points", "spheres")}
    assert all(row["count"] > 0 and row["median_ms"] > 0 for row in queries.values())

    assert "anchor" not in report and any("--no-cupy" in note for note in report["notes"])
    captured = capsys.readouterr()
    measured = [line for line in captured.err.splitlines() if " ms over " in line]
    assert len(measured) == len(report["full"]) + len(report["brush"]) + len(report["queries"])
    markdown = (out / "metrics.md").read_text()
    assert "### Full regeneration" in markdown and "| euclidean signed | 64³ | brushes | 100.00 | 0 |" in markdown
    assert markdown.strip() in captured.out


def test_a_size_over_the_memory_budget_is_skipped_saying_so(tmp_path, capsys):
    out = tmp_path / "metrics"
    assert bench_main(["metrics", "--quick", "--metrics", "euclidean", "--signed", "false", "--memory-budget-mib", "1",
                       "--no-cupy", "--out", str(out)]) == 0
    report = json.loads((out / "metrics.json").read_text())
    assert [(r["world_size"], "skipped" in r) for r in report["full"]] == [(32, False), (64, True)]
    assert "brush" not in report and any("64^3 did not fit" in note for note in report["notes"])
    assert "skipped" in capsys.readouterr().err


def test_a_stopped_metrics_bench_keeps_what_it_measured(tmp_path):
    out = tmp_path / "metrics"
    bench = subprocess.Popen(
        [sys.executable, "-m", "sdfserver", "bench", "metrics", "--quick", "--sizes", "32,64,64,64", "--reps", "20",
         "--no-cupy", "--out", str(out)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen = []
    for line in bench.stderr:
        seen.append(line)
        if " ms over " in line:  # the first measurement
            break
    bench.send_signal(signal.SIGINT)
    stdout, stderr = bench.communicate(timeout=300)
    assert bench.returncode == 130, "".join(seen) + stderr
    report = json.loads((out / "metrics.json").read_text())
    assert report["interrupted"] is True and 1 <= len(report["full"]) < 16
    assert report["full"][0]["world_size"] == 32 and report["full"][0]["n"] == 20
    assert "interrupted" in stdout and "interrupted" in (out / "metrics.md").read_text()
