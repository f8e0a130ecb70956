"""`sdfserver bench seed --out DIR [--quick] [--device SPEC]`: every table and figure of the
dissertation's chapter 4, measured and set beside the published numbers.

Writes DIR/results.json (every number, rewritten after each measurement), DIR/report.md, the
pictures of Figures 4.5 and 4.9, and, where matplotlib is installed, the plots of Figures 4.3,
4.6, 4.7 and 4.8. A line on stderr per measurement with a progress bar; Ctrl-C or SIGTERM ends
the run with the report and JSON of what was measured (exit status 130). `--plot-only DIR`
re-makes the plots and report.md from DIR/results.json (the measuring machine need not have
matplotlib). The full run takes a few minutes on a GPU; --quick is the CPU smoke run.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from datetime import datetime, timezone
from pathlib import Path

from sdfserver.algorithms import ALGORITHMS
from sdfserver.bench.run import Results, progress, source_commit, stoppable
from sdfserver.bench.schedule import DEFAULT_SEED
from sdfserver.bench.seed import measure as measuring
from sdfserver.bench.seed.report import write_report

SECTIONS = ("table_4_1", "table_4_2", "table_4_3", "table_4_4", "table_4_5", "table_4_6",
            "figure_4_3", "figure_4_5", "figure_4_6", "focus_sweep", "figure_4_9")


def finish(data: dict, out_dir: Path, plots: bool) -> None:
    """Plots (if matplotlib is here and wanted) and report.md from the results so far."""
    if plots:
        try:
            from sdfserver.bench.seed.figures import plot_all
        except ImportError as exc:  # the package itself imports; matplotlib is checked below
            raise SystemExit(f"sdfserver.bench.seed.figures: {exc}") from exc
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            progress("matplotlib is not installed: no plots; `sdfserver bench seed --plot-only DIR` makes them")
        else:
            for path in plot_all(data, out_dir):
                progress(f"wrote {path}")
    progress(f"wrote {write_report(data, out_dir)}")


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="sdfserver bench seed", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", help="output folder (made if missing)")
    p.add_argument("--quick", action="store_true", help="tiny sizes and short runs: a smoke run for CPU devices")
    p.add_argument("--device", default=None, help="OpenCL device: index or name substring (default: prefer a GPU)")
    p.add_argument("--seed", type=int, default=DEFAULT_SEED, help="seed of the edit schedule and the scenes")
    p.add_argument("--borders", choices=("padded", "exact"), default="padded",
                   help="chunk borders for Figures 4.3, 4.6–4.8: 'padded' is the dissertation's (§4.2.1)")
    p.add_argument("--only", default=None, help=f"comma list of sections to measure: {', '.join(SECTIONS)}")
    p.add_argument("--no-plots", action="store_true", help="skip the matplotlib plots (fewer files)")
    p.add_argument("--plot-only", metavar="DIR", help="re-make the plots and report.md from DIR/results.json")
    args = p.parse_args(argv)
    if not args.plot_only and not args.out:
        p.error("--out DIR is required (or --plot-only DIR)")
    args.only = None if args.only is None else {v for v in args.only.split(",") if v}
    if args.only is not None and (not args.only or args.only - set(SECTIONS)):
        p.error(f"unknown sections {sorted(args.only - set(SECTIONS))}; choose from {', '.join(SECTIONS)}")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    if args.plot_only:
        out_dir = Path(args.plot_only)
        data = json.loads((out_dir / "results.json").read_text())
        finish(data, out_dir, plots=True)
        (out_dir / "results.json").write_text(json.dumps(data, indent=1))
        return 0
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    command = "sdfserver bench seed " + " ".join(sys.argv[1:] if argv is None else argv)
    results = Results({"meta": {"date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                                "host": platform.node(), "commit": source_commit() or "unknown (not a git checkout)", "command": command,
                                "quick": args.quick, "seed": args.seed, "borders": args.borders,
                                "device": "(not opened)", "algorithms": sorted(ALGORITHMS)}},
                      str(out_dir / "results.json"))
    with stoppable(results, "report.md and results.json hold what was measured") as outcome:
        from sdfserver.gpu import GpuContext  # after the signal handler: opening a device takes a while

        progress("opening the OpenCL device")
        gpu = GpuContext.create(args.device)
        results.data["meta"]["device"] = gpu.device_name
        progress(f"device: {gpu.device_name}")
        measuring.measure(gpu, measuring.QUICK if args.quick else measuring.FULL, args.seed, args.borders,
                          results, out_dir, args.only)
        progress("measured; writing the report")
    finish(results.data, out_dir, plots=not args.no_plots)
    results.save()
    return outcome.status


__all__ = ["SECTIONS", "main"]
