"""``inspector experiment``: the paper's experiments (cases 1-3) as one command, with plots.

Each run simulates one capture of the rig (:mod:`inspector_drivers.sim.simulate`), inspects
it, and measures the distance of the raw reconstruction's points and of the BCPS points to
the *true* surface (:mod:`inspector.truth`). Runs are spread over a Dask distributed cluster:
a :class:`~distributed.LocalCluster` by default, or an existing one (``--scheduler``).

Cases (Pérez Soler et al., Mathematics 2023, 11(21), 4419, section 4):

1. ``scale``: ``cube30`` and ``sphere30`` scaled around the fixed reference (Figures 7, 8);
2. ``defects``: random bumps of radius up to 3 mm added (``+``) or removed (``-``), with
   Gaussian and impulse image noise (Figures 9, 10);
3. ``objects``: ``gauge``, ``turbine_blade``, ``cube_sphere`` (nominal, excess and missing
   material by scale 1.03 / 0.97 and by added / removed bumps) and the ``spring``
   (Figures 3, 5, 11-17; simulated here, real objects in the paper).

Outputs in ``--out``: one CSV per case (one row per run and BCPS method), one PNG per case
and part (Figures 7-10 style), ``summary.md`` (Table 1 style, improvement ratios beside the
paper's) and ``experiment.json`` (the configuration).

One task per (case, part, value, orientation). A task builds its own plugin manager, recipe
and reference, runs the pipeline up to the alignment once, then each BCPS method on that
same context, and returns small dicts (never images). A failing task becomes rows with
``status = error``: nothing else is lost. Rows are appended to the CSVs as they arrive.

Importing this module is cheap: Dask, tqdm and matplotlib are imported when used. The cases and
task specs are :mod:`inspector_tools.experiment_cases`, their execution
:mod:`inspector_tools.experiment_execution`, the plots and summary
:mod:`inspector_tools.experiment_report`; this module is the command (and re-exports their
public names).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from inspector import hookimpl
from inspector.errors import RecipeError
from inspector.registry import CommandRegistry, CommandSpec

# The command's three parts: the cases and task specs, their execution on Dask, the report.
from inspector_tools.experiment_cases import (
    CASES,
    CSV_COLUMNS,
    METHODS,
    OBJECT_VARIANTS,
    PAPER_TABLE1,
    PRESETS,
    check_pipeline,
    make_specs,
    pipeline,
    resolve_cases,
)
from inspector_tools.experiment_execution import CsvSink, execute, run_task, start_client, write_csvs
from inspector_tools.experiment_report import ratio_ranges, write_plots, write_summary

__all__ = [
    "CASES",
    "PRESETS",
    "PAPER_TABLE1",
    "CSV_COLUMNS",
    "add_parser",
    "run",
    "make_specs",
    "run_task",
    "execute",
    "start_client",
    "write_plots",
    "write_summary",
    "ratio_ranges",
]

# --------------------------------------------------------------------------- CLI


def add_parser(subparsers: Any) -> None:
    """Add the ``experiment`` sub-command to ``subparsers`` (from ``add_subparsers``)."""
    e = subparsers.add_parser(
        "experiment",
        help="reproduce the paper's experiments (cases 1-3) with plots and a Table-1 summary (Dask)",
        description="Simulate, inspect and measure against the truth: case 1 scale (cube, sphere), case 2 impulse defects "
        "with image noise, case 3 objects with excess/missing material. Writes CSVs, PNG plots and summary.md.",
    )
    e.add_argument("cases", nargs="*", metavar="CASE", help="1|scale, 2|defects, 3|objects, or all (default all)")
    e.add_argument("--out", required=True, metavar="DIR", help="output folder (CSV, PNG, summary.md)")
    e.add_argument("--quick", action="store_true", help="quick preset: 512x512 px at 0.2 mm/px, fewer values and orientations")
    e.add_argument("--orientations", type=int, metavar="N", help="random orientations per value (default: 5 full, 1-2 quick)")
    e.add_argument("--scheduler", metavar="ADDRESS", help="connect to this Dask scheduler (e.g. tcp://host:8786) instead of starting a local cluster")
    e.add_argument("--workers", type=int, default=2, metavar="N", help="local cluster worker processes, one thread each (default 2)")
    e.add_argument("--parts", nargs="+", metavar="PART", help="only these parts of the chosen cases")
    e.add_argument("--values", nargs="+", metavar="V", help="override the swept values (scales, defect sizes in mm, or variants "
                   + "|".join(OBJECT_VARIANTS) + ")")
    e.add_argument("--methods", nargs="+", default=["ray", "surface"], choices=list(METHODS), help="BCPS methods (default: ray surface)")
    e.add_argument("--recipe", metavar="TOML", help="take the stages and tolerance from this recipe (its bcps stage is replaced by each method)")
    e.add_argument("--seed", type=int, default=0, help="seed of orientation 0 (orientation i uses seed + i; default 0)")
    e.add_argument("--band", choices=["minmax", "std"], default="minmax", help="shaded band over orientations in the plots (default minmax)")
    e.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def run(args: argparse.Namespace) -> int:
    """Run ``inspector experiment``. Exit 0 if every run succeeded, 3 if some failed (rows kept)."""
    try:
        import distributed  # noqa: F401
        import matplotlib  # noqa: F401
    except ImportError as e:
        raise RecipeError(f"experiment needs {e.name} (pip install 'dask[distributed]' matplotlib tqdm)") from None
    if args.orientations is not None and args.orientations < 1:
        raise RecipeError("experiment --orientations: expected a number >= 1")
    if args.workers < 1:
        raise RecipeError("experiment --workers: expected a number >= 1")
    preset = "quick" if args.quick else "full"
    cases = resolve_cases(args.cases)
    stages, tolerance = pipeline(args.recipe, preset)
    methods = list(dict.fromkeys(args.methods))
    specs = make_specs(cases, preset=preset, orientations=args.orientations, values=args.values, parts=args.parts,
                       methods=methods, seed=args.seed, stages=stages, tolerance=tolerance)
    check_pipeline(stages, tolerance, methods)
    cases = [c for c in cases if any(s["case"] == c.name for s in specs)]

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    config = {
        "cases": [c.name for c in cases], "preset": preset, "rig": PRESETS[preset]["rig"], "methods": methods,
        "orientations": args.orientations, "values": args.values, "parts": args.parts, "seed": args.seed,
        "scheduler": args.scheduler, "workers": None if args.scheduler else args.workers, "stages": stages,
        "tolerance": tolerance, "tasks": len(specs), "case_sim": {c.name: c.sim for c in cases},
    }
    t0 = time.perf_counter()
    sink = CsvSink(out, cases)
    rows: list[dict[str, Any]] = []
    client = cluster = None
    where = args.scheduler or f"a local cluster of {args.workers} worker process(es)"
    print(f"experiment: {len(specs)} runs ({', '.join(c.stem for c in cases)}; preset {preset}) on {where}", flush=True)
    try:
        client, cluster = start_client(args.scheduler, args.workers)
        rows = execute(specs, client, on_rows=sink.add, progress=not args.no_progress)
    finally:
        sink.close()
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
        config["elapsed_s"] = time.perf_counter() - t0
        if rows:
            write_csvs(rows, out, cases)
            write_plots(rows, out, cases, band=args.band)
            write_summary(rows, out, cases, config)
        (out / "experiment.json").write_text(json.dumps(config, indent=2, default=str), encoding="utf-8")
    bad = sum(r["status"] != "ok" for r in rows)
    print(f"experiment: {len(rows) - bad}/{len(rows)} inspections OK ({len(specs)} runs x {len(methods)} method(s)) in "
          f"{config['elapsed_s']:.0f} s; results in {out.resolve()} (summary.md, CSV, PNG)", flush=True)
    if bad or len(rows) < len(specs) * len(methods):
        print(f"inspector: error: {bad} inspection(s) failed; see the 'error' column of the CSVs and summary.md", file=sys.stderr)
        return 3
    return 0


# --------------------------------------------------------------------------- plugin
@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    """``inspector experiment``: a built-in plugin (entry point ``experiment``), like any command."""
    registry.add(CommandSpec("experiment", add_parser, run, "the paper's experiments (cases 1-3) on Dask"))
