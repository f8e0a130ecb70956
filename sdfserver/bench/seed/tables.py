"""The dissertation's published numbers (Fedor 2025, chapter 4; RTX 3070 laptop GPU, Vulkan) and
what each table and figure of chapter 4 measures here.

Numbers are copied from the dissertation's text, keyed by table and world or chunk size. Figures
4.3 and 4.6–4.8 are plots without printed numbers, and 4.5 and 4.9 are pictures: for those the
report compares shape (what the text says the plot shows), not numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

# World or chunk side -> value, in the dissertation's units (FPS, ms, FIM passes, percent).
DISSERTATION: dict[str, dict[str, dict[int, float]]] = {
    # Table 4.1: brute force, no chunks, an edit every 200 ms (Avg. FPS).
    "4.1": {"fps": {8: 142.33702, 16: 142.335887, 32: 91.44403, 64: 2.30128, 128: 0.04184}},
    # Table 4.2: brute force, one world of one chunk: compute shader time.
    "4.2": {"mean_ms": {8: 0.13085426, 16: 0.72909933, 32: 8.415086, 64: 431.46756, 128: 25854.305},
            "std_ms": {8: 0.07906039, 16: 0.72129595, 32: 0.6034345, 64: 23.69193, 128: 43.82031},
            "ci_lo_ms": {8: 0.12865908, 16: 0.7251273, 32: 8.400318, 64: 428.5129, 128: 25830.484},
            "ci_hi_ms": {8: 0.13304944, 16: 0.7330714, 32: 8.429853, 64: 434.4222, 128: 25878.125}},
    # Table 4.3: brute force in 16^3 chunks with padding, an edit every 200 ms.
    "4.3": {"fps": {32: 141.02969, 64: 140.32344, 128: 88.75602, 256: 22.13375, 512: 3.37203},
            "field_ms": {32: 0.8090571, 64: 0.7992149, 128: 0.7797105, 256: 0.7632012, 512: 0.7504562},
            # "Inf%" at 256^3 and 512^3 (no unchunked run to compare with) is left out.
            "improvement_pct": {32: 54.2251, 64: 5997.63, 128: 212032.0}},
    # Table 4.4: FIM, one chunk: total time of all passes, and passes to converge.
    "4.4": {"mean_ms": {8: 0.0408411, 16: 0.05089584, 32: 0.1566725, 64: 1.089782, 128: 17.556416},
            "std_ms": {8: 0.012230597, 16: 0.009375835, 32: 0.07214462, 64: 0.5198319, 128: 16.088636},
            "iterations": {8: 1.0313779, 16: 1.1514729, 32: 1.4801816, 64: 2.3467271, 128: 6.194286}},
    # Table 4.5: JFA, one chunk: total time of all passes.
    "4.5": {"mean_ms": {8: 0.031079482, 16: 0.37563447, 32: 0.07390518, 64: 0.38933817, 128: 8.052377},
            "std_ms": {8: 0.0060166107, 16: 0.0011396826, 32: 0.014052732, 64: 0.1003621, 128: 3.9264889}},
    # Table 4.6: JFA then FIM, one chunk.
    "4.6": {"mean_ms": {8: 0.04326828, 16: 0.042948034, 32: 0.142226286, 64: 0.8856182, 128: 16.556087},
            "std_ms": {8: 0.014001529, 16: 0.0082087135, 32: 0.004889435, 64: 0.48032447, 128: 13.672007},
            "iterations": {8: 0.21335079, 16: 0.41733277, 32: 0.9516885, 64: 1.2535588, 128: 4.1610336}},
}

# What the dissertation's text says each plot or picture shows (the report compares shape).
FIGURE_CLAIMS = {
    "4.3": "FIM at several world and chunk sizes: performance declines at large world sizes with "
           "several chunks to update (time spent waiting on fences between per-chunk dispatches).",
    "4.5": "Rendering an exact and an approximate (JFA) distance field: JFA's render shows minor "
           "artifacts where distances do not align with the true surface.",
    "4.6": "JFA at several world and chunk sizes: far quicker than FIM; chunks as big as 64^3 are feasible.",
    "4.7": "Level of detail (JFA outside the focus, FIM inside): increasing the focus size lowers FPS "
           "significantly.",
    "4.8": "Level of detail: increasing the focus size raises the distance field's computation time "
           "significantly.",
    "4.9": "Focus 1x1, 2x2 and the whole world: visual fidelity rises with the focus size as more chunks "
           "get an exact field.",
}


@dataclass(frozen=True)
class Metric:
    key: str  # in DISSERTATION[table]
    label: str
    ours: str  # where our number is in a measured row: "fps.mean", "mean_ms", ...


@dataclass(frozen=True)
class TableSpec:
    number: str
    title: str
    kind: str  # "render" (the §3.5 scenario) or "chunk" (one world of one chunk, full regeneration)
    algorithm: str
    sizes: tuple[int, ...]
    metrics: tuple[Metric, ...]
    setup: str


TABLES = (
    TableSpec("4.1", "Brute force, no chunks, an edit every 200 ms", "render", "brute", (8, 16, 32, 64, 128),
              (Metric("fps", "Avg. FPS", "fps.mean"),),
              "one chunk per world (chunk = world side), brute force, seeded edits every 200 ms"),
    TableSpec("4.2", "Brute force, compute time of one chunk", "chunk", "brute", (8, 16, 32, 64, 128),
              (Metric("mean_ms", "Avg. time (ms)", "mean_ms"), Metric("std_ms", "Std. deviation (ms)", "std_ms"),
               Metric("ci_lo_ms", "95% CI low (ms)", "ci95_ms.0"), Metric("ci_hi_ms", "95% CI high (ms)", "ci95_ms.1")),
              "one world of one chunk, full regeneration after random brush edits"),
    TableSpec("4.3", "Brute force in 16³ chunks with padding, an edit every 200 ms", "render", "brute",
              (32, 64, 128, 256, 512),
              (Metric("fps", "Avg. FPS", "fps.mean"), Metric("field_ms", "Avg. execution time (ms)", "field_device_ms.mean"),
               Metric("improvement_pct", "% improvement over Table 4.1", "improvement_pct")),
              "16³ chunks, borders='padded' (each chunk alone, outside counted solid), seeded edits every 200 ms"),
    TableSpec("4.4", "FIM, compute time of one chunk", "chunk", "fim", (8, 16, 32, 64, 128),
              (Metric("mean_ms", "Total avg. time (ms)", "mean_ms"), Metric("std_ms", "Std. deviation (ms)", "std_ms"),
               Metric("iterations", "Avg. iterations", "iterations_mean")),
              "one world of one chunk, full regeneration after random brush edits"),
    TableSpec("4.5", "JFA, compute time of one chunk", "chunk", "jfa", (8, 16, 32, 64, 128),
              (Metric("mean_ms", "Total avg. time (ms)", "mean_ms"), Metric("std_ms", "Std. deviation (ms)", "std_ms")),
              "one world of one chunk, full regeneration after random brush edits"),
    TableSpec("4.6", "JFA then FIM, compute time of one chunk", "chunk", "jfa_fim", (8, 16, 32, 64, 128),
              (Metric("mean_ms", "Total avg. time (ms)", "mean_ms"), Metric("std_ms", "Std. deviation (ms)", "std_ms"),
               Metric("iterations", "Avg. iterations", "iterations_mean")),
              "one world of one chunk, full regeneration after random brush edits"),
)

FIGURES = ("4.3", "4.5", "4.6", "4.7", "4.8", "4.9")


def figure_file(number: str) -> str:
    return f"figure_{number.replace('.', '_')}.png"


def table_key(number: str) -> str:
    return f"table_{number.replace('.', '_')}"


def pick(row: dict, path: str):
    """``row``'s value at a dotted path ("fps.mean", "ci95_ms.0"), or None."""
    value = row
    for part in path.split("."):
        if isinstance(value, list):
            value = value[int(part)] if int(part) < len(value) else None
        elif isinstance(value, dict):
            value = value.get(part)
        else:
            return None
    return value if isinstance(value, (int, float)) and not isinstance(value, bool) else None


__all__ = ["DISSERTATION", "FIGURES", "FIGURE_CLAIMS", "Metric", "TABLES", "TableSpec", "figure_file", "pick",
           "table_key"]
