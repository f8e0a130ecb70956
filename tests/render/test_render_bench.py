import json

import pytest

from sdfserver.render import bench
from sdfserver.bench.schedule import Schedule


def test_brushes_follow_the_seed():
    a, b, c = (Schedule((32, 32, 32), seed).first(3) for seed in (5, 5, 6))
    assert a == b != c
    for brush in a:
        assert all(0 <= v < 32 for v in brush["center"]) and 1 <= brush["radius"] <= 2


def test_chunk_never_exceeds_the_world_and_whole_means_one_chunk():
    assert bench.chunk_for(8, 16) == 8 and bench.chunk_for(64, 16) == 16 and bench.chunk_for(64, None) == 64
    config = bench.world_config(64, "jfa_fim", chunk_size=16, focus=2, lod_algorithm="jfa")
    assert config.focus.size == (2, 2, 2) and config.focus.center == (2, 2, 2)
    with pytest.raises(bench.NotAvailable):
        bench.world_config(16, "no-such-algorithm")


def test_render_benchmark_reports_every_run(gpu):
    lines = []
    report = bench.run_render_benchmark(gpu, world_sizes=[16, 32], algorithms=["exact", "jfa"],
                                        edit_interval_ms=50, duration_s=0.6, seed=3,
                                        width=32, height=24, progress=lines.append)
    assert [(r["algorithm"], r["world_size"]) for r in report["runs"]] == [
        ("exact", 16), ("exact", 32), ("jfa", 16), ("jfa", 32)]
    for run in report["runs"]:
        assert run["frames"] > 5 and run["edits"] >= 2
        assert run["fps"]["n"] == run["frames"] and run["fps"]["mean"] > 0 and run["fps"]["ci95"] >= 0
        assert run["field_device_ms"]["n"] == run["edits"] and run["field_device_ms"]["mean"] > 0
        assert run["render_device_ms"]["mean"] > 0
        # §3.5.1: FPS during recompute, apart from overall: one frame per edit carried its recompute.
        assert run["fps_recompute"]["n"] == run["edits"] and run["fps_recompute"]["mean"] > 0
        assert run["fps_recompute"]["mean"] < run["fps"]["mean"]
    assert lines and "FPS" in lines[0]
    json.dumps(report)  # plain JSON
    assert "exact" in bench.format_table(report)


def test_main_writes_json(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert bench.main(["--sizes", "16", "--algorithms", "exact", "--duration", "0.3",
                       "--width", "16", "--height", "16", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["runs"][0]["world_size"] == 16
    assert "FPS mean" in capsys.readouterr().out


def test_main_takes_small_worlds_chunk_sizes_and_focus(tmp_path, capsys):
    """`--sizes 8` once crashed on the fixed 16^3 chunk."""
    out = tmp_path / "bench.json"
    assert bench.main(["--sizes", "8,32", "--algorithms", "jfa_fim", "--chunk-size", "8", "--focus", "none,2",
                       "--duration", "0.3", "--width", "16", "--height", "16", "--json", str(out)]) == 0
    runs = json.loads(out.read_text())["runs"]
    assert [(r["world_size"], r["chunk_size"], r["focus"]) for r in runs] == [
        (8, 8, None), (8, 8, 2), (32, 8, None), (32, 8, 2)]
    assert runs[3]["lod_algorithm"] == "jfa"
    assert "FPS during recompute" in capsys.readouterr().out
    assert bench.main(["--sizes", "16", "--algorithms", "brute", "--chunk-size", "whole", "--duration", "0.2",
                       "--width", "16", "--height", "16", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["runs"][0]["chunk_size"] == 16
