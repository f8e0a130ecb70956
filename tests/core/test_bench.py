"""`sdfserver bench --quick` runs end to end and its accuracy table is measured against scipy; every
measurement shows on stderr as it is taken, a stopped run keeps what it measured, and an unknown
section is refused by name."""

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from sdfserver.bench.cli import main

ROOT = Path(__file__).resolve().parents[2]


def test_bench_quick_smoke(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["--quick", "--algorithms", "exact,jfa,jfa_fim", "--sections", "chunks,worlds,update",
                 "--reps", "2", "--json", str(out)]) == 0
    results = json.loads(out.read_text())
    assert {r["chunk_size"] for r in results["chunks"]} == {8, 16}
    by_alg = {(r["algorithm"], r["world_size"]): r for r in results["accuracy"]}
    assert {r["reference"] for r in results["accuracy"]} == {"scipy"}  # independent of the algorithms
    assert by_alg[("exact", 64)]["exact_share"] == 1.0
    assert by_alg[("jfa_fim", 64)]["exact_share"] == 1.0
    assert by_alg[("jfa", 64)]["underestimates"] == 0
    assert all(r["mean_ms"] > 0 for r in results["worlds"])
    captured = capsys.readouterr()
    assert "Single chunk" in captured.out and "interrupted" not in results
    measured = [line for line in captured.err.splitlines() if " ms over " in line]
    assert len(measured) == len(results["chunks"]) + len(results["worlds"]) + len(results["update"])
    assert "[bench] chunks: exact 8^3: mean" in captured.err


@pytest.mark.parametrize("sections", ["chunks,tables", "accuracy", ","])
def test_unknown_sections_are_refused_by_name(sections, capsys):
    with pytest.raises(SystemExit) as stopped:
        main(["--quick", "--sections", sections])
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert "chunks, worlds, update, anchors" in err
    assert all(f"'{name}'" in err for name in sections.split(",") if name and name != "chunks")


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM])
def test_a_stopped_bench_keeps_what_it_measured(tmp_path, stop):
    out = tmp_path / "bench.json"
    bench = subprocess.Popen(
        [sys.executable, "-m", "sdfserver", "bench", "--sections", "chunks", "--algorithms", "exact",
         "--chunk-sizes", "8,128,128,128,128", "--reps", "200", "--json", str(out)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen = []
    for line in bench.stderr:
        seen.append(line)
        if " ms over " in line:  # the first measurement; each 128^3 one after it takes about a second
            break                # on a CPU device, long enough for the signal to land while the run goes on
    bench.send_signal(stop)
    stdout, stderr = bench.communicate(timeout=300)
    assert bench.returncode == 130, "".join(seen) + stderr
    results = json.loads(out.read_text())
    assert results["interrupted"] is True
    measured = [line for line in "".join(seen).splitlines() + stderr.splitlines() if " ms over " in line]
    assert 1 <= len(results["chunks"]) == len(measured) < 5
    assert results["chunks"][0]["chunk_size"] == 8 and results["chunks"][0]["n"] == 200
    assert "interrupted" in stdout and "exact         8³" in stdout


def test_a_stopped_render_bench_keeps_the_runs_that_finished(tmp_path):
    out = tmp_path / "render.json"
    bench = subprocess.Popen(
        [sys.executable, "-m", "sdfserver", "bench", "render", "--sizes", "16,32,32,32", "--algorithms", "exact",
         "--duration", "2", "--width", "16", "--height", "16", "--json", str(out)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    seen = []
    for line in bench.stderr:
        seen.append(line)
        if " FPS over " in line:  # the first run ended
            break
    bench.send_signal(signal.SIGINT)
    stdout, stderr = bench.communicate(timeout=300)
    assert bench.returncode == 130, "".join(seen) + stderr
    report = json.loads(out.read_text())
    assert report["interrupted"] is True and 1 <= len(report["runs"]) < 4
    assert report["runs"][0]["world_size"] == 16 and report["runs"][0]["frames"] > 0
    assert "interrupted" in stdout and "FPS mean" in stdout
