"""The plots of Figures 4.3, 4.6, 4.7 and 4.8, from results.json alone (matplotlib, Agg).

matplotlib is imported here only, and only when plotting: the measuring machine may lack it, and
``sdfserver bench seed --plot-only DIR`` re-plots anywhere it is installed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sdfserver.bench.seed.tables import figure_file, pick

DPI = 90


def _figure(width_in: float = 9.0, height_in: float = 3.4):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure  # no pyplot: no global figure state, no GUI backend

    return Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")


def _lines(ax, rows: list[dict[str, Any]], x: str, y: str, group: str, label: str) -> None:
    for g in dict.fromkeys(r.get(group) for r in rows):
        pts = sorted((r[x], pick(r, y)) for r in rows if r.get(group) == g and pick(r, y) is not None)
        if pts:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=f"{label} {g}")
    ax.grid(True, alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7)


def _grid_plot(rows: list[dict[str, Any]], title: str, path: Path) -> None:
    fig = _figure()
    fps, field = fig.subplots(1, 2)
    _lines(fps, rows, "size", "fps.mean", "chunk", "chunk")
    _lines(fps, rows, "size", "fps_recompute.mean", "chunk", "during recompute, chunk")
    fps.set(xscale="log", yscale="log", xlabel="world side (voxels)", ylabel="FPS", title="frame rate")
    _lines(field, rows, "size", "field_device_ms.mean", "chunk", "chunk")
    field.set(xscale="log", yscale="log", xlabel="world side (voxels)", ylabel="ms per edit (device)",
              title="distance field time")
    fig.suptitle(title, fontsize=10)
    fig.savefig(path)


def _focus_plot(rows: list[dict[str, Any]], y: str, ylabel: str, title: str, path: Path) -> None:
    fig = _figure(6.0, 3.4)
    ax = fig.subplots()
    _lines(ax, rows, "focus", y, "lod", "outside:")
    if y == "fps.mean":
        _lines(ax, rows, "focus", "fps_recompute.mean", "lod", "during recompute, outside:")
    ax.set(xlabel="focus size (chunks a side)", ylabel=ylabel, title=title, yscale="log")
    fig.savefig(path)


def plot_all(data: dict[str, Any], out_dir: Path) -> list[Path]:
    """Writes figure_4_3/4_6/4_7/4_8.png for the figures with measured runs; returns their paths."""
    out_dir = Path(out_dir)
    written = []

    def measured(key: str) -> list[dict[str, Any]]:
        return [r for r in data.get(key, []) if "fps" in r]

    for number, algorithm in (("4.3", "FIM"), ("4.6", "JFA")):
        rows = measured(f"figure_{number.replace('.', '_')}")
        if rows:
            path = out_dir / figure_file(number)
            _grid_plot(rows, f"Figure {number}: {algorithm} at several world and chunk sizes", path)
            written.append(path)
    rows = measured("focus_sweep")
    if rows:
        for number, y, ylabel, title in (
                ("4.7", "fps.mean", "FPS", "Figure 4.7: focus size and FPS"),
                ("4.8", "field_device_ms.mean", "ms per edit (device)", "Figure 4.8: focus size and field time")):
            path = out_dir / figure_file(number)
            _focus_plot(rows, y, ylabel, title, path)
            written.append(path)
    return written


__all__ = ["plot_all"]
