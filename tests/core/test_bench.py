"""`sdfserver bench --quick` runs end to end and its accuracy table is computed, not assumed."""

import json

from sdfserver.bench import main


def test_bench_quick_smoke(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["--quick", "--algorithms", "exact,jfa,jfa_fim", "--sections", "chunks,worlds,update",
                 "--reps", "2", "--json", str(out)]) == 0
    results = json.loads(out.read_text())
    assert {r["chunk_size"] for r in results["chunks"]} == {8, 16}
    by_alg = {(r["algorithm"], r["world_size"]): r for r in results["accuracy"]}
    assert by_alg[("exact", 64)]["exact_share"] == 1.0
    assert by_alg[("jfa_fim", 64)]["exact_share"] == 1.0
    assert by_alg[("jfa", 64)]["underestimates"] == 0
    assert all(r["mean_ms"] > 0 for r in results["worlds"])
    assert "Single chunk" in capsys.readouterr().out
