import json

import numpy as np

from sdfserver.render import bench


def test_brushes_follow_the_seed():
    a = [bench._random_brush(np.random.default_rng(5), (32, 32, 32)) for _ in range(3)]
    b = [bench._random_brush(np.random.default_rng(5), (32, 32, 32)) for _ in range(3)]
    c = [bench._random_brush(np.random.default_rng(6), (32, 32, 32)) for _ in range(3)]
    assert a == b != c


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
