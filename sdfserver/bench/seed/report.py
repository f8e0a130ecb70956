"""report.md from results.json: each table beside the dissertation's numbers with the ratio, each
figure's plot or picture with what the dissertation says it shows and what ours shows."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from sdfserver.bench.seed.tables import DISSERTATION, FIGURE_CLAIMS, FIGURES, TABLES, figure_file, pick, table_key

DISSERTATION_DEVICE = "NVIDIA GeForce RTX 3070 Laptop GPU, Vulkan (Fedor 2025, §3.6)"
NOT_AVAILABLE = "not available"


def fmt(value: float | None) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "—"
    return f"{value:.5g}"


def _why(row: dict[str, Any] | None) -> str:
    if row is None:
        return f"{NOT_AVAILABLE}: not measured in this run"
    return f"{NOT_AVAILABLE}: {row.get('not_available') or row.get('error')}"


def _ours(data: dict[str, Any], spec, metric, row: dict[str, Any]) -> float | None:
    if metric.key != "improvement_pct":
        return pick(row, metric.ours)
    # Table 4.3's "% improvement": FPS over the unchunked run of the same world size (Table 4.1).
    unchunked = {r["size"]: r for r in data.get(table_key("4.1"), []) if "fps" in r}.get(row["size"])
    if unchunked is None or not unchunked["fps"]["n"] or "fps" not in row:
        return None
    return 100.0 * (row["fps"]["mean"] - unchunked["fps"]["mean"]) / unchunked["fps"]["mean"]


def comparisons(data: dict[str, Any]) -> dict[str, list[dict[str, Any]]]:
    """Per table, one row per (size, metric) that both we and the dissertation have a place for."""
    out = {}
    for spec in TABLES:
        rows = []
        for row in data.get(table_key(spec.number), []):
            for metric in spec.metrics:
                theirs = DISSERTATION[spec.number][metric.key].get(row["size"])
                if theirs is None:
                    continue
                measured = "not_available" not in row and "error" not in row
                ours = _ours(data, spec, metric, row) if measured else None
                entry = {"size": row["size"], "metric": metric.label, "ours": ours, "dissertation": theirs,
                         "ratio": ours / theirs if ours is not None and theirs else None}
                if not measured:
                    entry["note"] = _why(row)
                elif ours is None:
                    entry["note"] = f"{NOT_AVAILABLE}: no Table 4.1 run at {row['size']}^3 to compare with"
                rows.append(entry)
        out[spec.number] = rows
    return out


def _table_md(spec, rows: list[dict[str, Any]]) -> list[str]:
    lines = [f"## Table {spec.number}: {spec.title}", "", f"Ours: {spec.setup}.", "",
             "| size | metric | ours | dissertation | ratio (ours ÷ dissertation) |",
             "| --- | --- | ---: | ---: | ---: |"]
    for r in rows:
        ours = fmt(r["ours"]) if r["ours"] is not None else r["note"]
        lines.append(f"| {r['size']}³ | {r['metric']} | {ours} | {fmt(r['dissertation'])} | {fmt(r['ratio'])} |")
    if not rows:
        lines.append(f"| — | — | {NOT_AVAILABLE}: not measured in this run | — | — |")
    return lines + [""]


def _render_rows_md(rows: list[dict[str, Any]], keys: tuple[str, ...]) -> list[str]:
    head = " | ".join(keys)
    lines = [f"| {head} | FPS | FPS during recompute | field device ms | edits |",
             "| " + " | ".join("---" for _ in keys) + " | ---: | ---: | ---: | ---: |"]
    for r in rows:
        cells = " | ".join(str(r.get(k)) for k in keys)
        if "fps" not in r:
            lines.append(f"| {cells} | {_why(r)} | | | |")
            continue
        lines.append(f"| {cells} | {fmt(r['fps']['mean'])} | {fmt(r['fps_recompute']['mean'])} | "
                     f"{fmt(r['field_device_ms']['mean'])} | {r['edits']} |")
    return lines


def _trend(rows: list[dict[str, Any]], x: str, y: str, group: str) -> str:
    """For each group, the first and last value of ``y`` as ``x`` grows."""
    parts = []
    for g in dict.fromkeys(r.get(group) for r in rows):
        pts = sorted((r[x], pick(r, y)) for r in rows if r.get(group) == g and pick(r, y) is not None)
        if len(pts) >= 2:
            parts.append(f"{group} {g}: {fmt(pts[0][1])} at {x} {pts[0][0]} → {fmt(pts[-1][1])} at {x} {pts[-1][0]}")
    return "; ".join(parts) or "too few runs to tell"


def _shape(number: str, data: dict[str, Any]) -> str:
    if number in ("4.3", "4.6"):
        rows = [r for r in data.get(f"figure_{number.replace('.', '_')}", []) if "fps" in r]
        return (f"FPS as the world grows, per chunk size: {_trend(rows, 'size', 'fps.mean', 'chunk')}. "
                f"Field device ms: {_trend(rows, 'size', 'field_device_ms.mean', 'chunk')}.")
    if number in ("4.7", "4.8"):
        rows = [r for r in data.get("focus_sweep", []) if "fps" in r]
        y = "fps.mean" if number == "4.7" else "field_device_ms.mean"
        return f"{'FPS' if number == '4.7' else 'Field device ms'} as the focus grows: {_trend(rows, 'focus', y, 'lod')}."
    rows = [r for r in data.get(f"figure_{number.replace('.', '_')}", []) if "exact_share" in r]
    return "Share of voxels with the exact distance: " + (
        "; ".join(f"{r['name']} {100 * r['exact_share']:.2f}% (max error {r['max_error']}, "
                  f"{r['underestimates']} underestimates)" for r in rows) or "not measured in this run") + "."


def _figure_md(number: str, data: dict[str, Any], out_dir: Path) -> list[str]:
    png = figure_file(number)
    lines = [f"## Figure {number}", "",
             f"The dissertation (a {'picture' if number in ('4.5', '4.9') else 'plot'} with no printed "
             f"numbers, so shape is compared, not numbers): {FIGURE_CLAIMS[number]}", ""]
    if (out_dir / png).exists():
        lines.append(f"![Figure {number}]({png})")
    else:
        lines.append(f"({png} not made here: plots need matplotlib — `sdfserver bench seed --plot-only DIR` "
                     "re-makes them from results.json; pictures need the measuring run)")
    lines += ["", f"Ours: {_shape(number, data)}", ""]
    if number in ("4.3", "4.6"):
        lines += _render_rows_md(data.get(f"figure_{number.replace('.', '_')}", []), ("size", "chunk", "borders"))
    elif number == "4.7":
        lines += _render_rows_md(data.get("focus_sweep", []), ("size", "chunk", "focus", "lod", "borders"))
    elif number in ("4.5", "4.9"):
        lines += ["| field | exact voxels % | max error | mean error | underestimates |",
                  "| --- | ---: | ---: | ---: | ---: |"]
        for r in data.get(f"figure_{number.replace('.', '_')}", []):
            if "exact_share" in r:
                lines.append(f"| {r['name']} | {100 * r['exact_share']:.3f} | {r['max_error']} | "
                             f"{fmt(r['mean_error'])} | {r['underestimates']} |")
            else:
                lines.append(f"| {r.get('label')} | {_why(r)} | | | |")
    return lines + [""]


def write_report(data: dict[str, Any], out_dir: Path) -> Path:
    """Writes report.md; stores the table comparisons in ``data['comparisons']``."""
    out_dir = Path(out_dir)
    meta = data.get("meta", {})
    data["comparisons"] = comparisons(data)
    lines = ["# The dissertation's chapter 4, reproduced", "",
             f"- Device: {meta.get('device', '(not opened)')}",
             f"- Date: {meta.get('date')}",
             f"- Commit: {meta.get('commit')}",
             f"- Command: `{meta.get('command')}`",
             f"- Run: {'quick (tiny sizes, short runs)' if meta.get('quick') else 'full'}, seed {meta.get('seed')}; "
             f"chunk borders for Figures 4.3, 4.6–4.8: {meta.get('borders')}",
             f"- The dissertation's numbers: {DISSERTATION_DEVICE}. Ratio = ours ÷ dissertation: above 1 is "
             "better for FPS, below 1 is better for times.",
             "- Brute force stops at 128³ (the dissertation's application crashed above it, §4.1.1).",
             "- Every number here is in results.json beside this file.", ""]
    if data.get("interrupted"):
        lines += ["**Interrupted**: the tables hold what was measured before the stop.", ""]
    for spec in TABLES:
        lines += _table_md(spec, data["comparisons"][spec.number])
    for number in FIGURES:
        lines += _figure_md(number, data, out_dir)
    path = out_dir / "report.md"
    path.write_text("\n".join(lines))
    return path


__all__ = ["comparisons", "fmt", "write_report"]
