"""The ``inspector`` command line.

Exit status of ``inspector run`` (CONTRACT): 0 every part passed; 1 at least one part
failed its tolerances; 2 the command or the recipe is invalid (nothing inspected); 3 at
least one capture could not be inspected. Errors are one line on stderr, never a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from inspector.errors import InspectorError, RecipeError

__all__ = ["main"]

EXIT_OK, EXIT_FAIL, EXIT_INVALID, EXIT_ERROR = 0, 1, 2, 3


def _recipes_dir() -> Path:
    return Path(__file__).resolve().parent.parent / "recipes"


def _err(msg: str) -> None:
    print(f"inspector: error: {msg}", file=sys.stderr)


# -- run -------------------------------------------------------------------------------
def _load(recipe_path: str, reference: str | None) -> tuple[Any, Any, Any]:
    """Plugin manager, validated recipe and loaded reference (RecipeError on any problem)."""
    from inspector.session import Session

    s = Session.open(recipe_path, ".", reference=reference)  # the same loading as every run
    return s.pm, s.recipe, s.reference


def _watch_params(args: argparse.Namespace) -> dict[str, Any] | None:
    """The hot-folder driver's parameters from ``--watch``, ``--count``, ``--idle-exit``."""
    if args.watch is None:
        for flag, value in (("--count", args.count), ("--idle-exit", args.idle_exit)):
            if value is not None:
                raise RecipeError(f"{flag}: only with --watch")
        return None
    if args.count is not None and args.count < 1:
        raise RecipeError(f"--count: expected a number >= 1, got {args.count}")
    if args.idle_exit is not None and not args.idle_exit > 0:
        raise RecipeError(f"--idle-exit: expected seconds > 0, got {args.idle_exit}")
    return {"folder": args.watch, "count": args.count or 0, "idle_exit_s": args.idle_exit or 0.0}


def _run(recipe_path: str, captures: Sequence[str] | None, out: str, reference: str | None, quiet: bool,
         watch: dict[str, Any] | None = None) -> int:
    """``inspector run``: a :class:`~inspector.session.Session` whose events are printed."""
    from inspector.outputs import one_line
    from inspector.session import Inspected, RunStarted, Session, Source, Warned

    session = Session.open(recipe_path, out, reference=reference)

    def show(event: object) -> None:
        # Only the verdicts are kept (the summary counts them): a live driver or a long batch
        # must not hold every result's points in memory (5 MB a capture).
        if isinstance(event, RunStarted) and event.inbox is not None and not quiet:
            print(f"watching {event.inbox} for capture folders (Ctrl-C to stop); results in {event.outdir}", flush=True)
        elif isinstance(event, Inspected):
            result = event.outcome.result
            if not quiet:
                of = f"/{event.total}" if event.total else ""
                print(f"[{event.index}{of}] {one_line(result)}", flush=True)
            elif result.verdict == "error":  # no progress lines, but no silent error
                _err(f"{result.capture}: {result.error}")
        elif isinstance(event, Warned):
            print(f"inspector: warning: {event.capture}: {event.text}", file=sys.stderr, flush=True)

    session.subscribe(show)
    try:
        summary = session.run(Source(captures=tuple(captures or ()), watch=watch))
    finally:
        session.close()
    if summary.inbox is not None and summary.ended == "interrupted" and not quiet:
        print("watch stopped", flush=True)
    if not summary.inspected and summary.inbox is not None:
        if not quiet:
            print(f"no capture arrived in {summary.inbox}")
        return EXIT_OK
    if not summary.inspected:
        raise RecipeError("no capture to inspect")
    if not quiet:
        n = summary.counts
        print(f"{summary.inspected} inspected: {n['pass']} pass, {n['fail']} fail, {n['error']} error. Results in {summary.outdir.resolve()}")
    return summary.exit_status


# -- simulate --------------------------------------------------------------------------
def _parse_bump(text: str) -> dict[str, Any]:
    parts = [p.strip() for p in text.split(",")]
    try:
        if len(parts) not in (4, 5):
            raise ValueError
        x, y, z, r = (float(v) for v in parts[:4])
    except ValueError:
        raise RecipeError(f"--bump {text!r}: expected X,Y,Z,RADIUS[,add|remove]") from None
    kind = parts[4] if len(parts) == 5 else "remove"
    if kind not in ("add", "remove"):
        raise RecipeError(f"--bump {text!r}: kind must be add or remove")
    return {"at": [x, y, z], "radius_mm": r, "kind": kind}


def _add_param_options(parser: argparse.ArgumentParser, cls: type, skip: set[str]) -> None:
    """One ``--option`` per parameter of ``cls`` (types and docs from the dataclass)."""
    from inspector.params import describe_params

    for d in describe_params(cls):
        if d["name"] in skip:
            continue
        flag = "--" + d["name"].replace("_", "-")
        if d["type"] == "bool":
            parser.add_argument(flag, action="store_true", default=None, help=d["doc"])
        elif d["type"].startswith("list of"):
            parser.add_argument(flag, type=float, nargs="+", default=None, help=d["doc"])
        else:
            conv = {"int": int, "float": float}.get(d["type"], str)
            if d["type"] == "8 | 16":
                conv = int
            parser.add_argument(flag, type=conv, default=None, help=f"{d['doc']} (default {d['default']!r})")


def _simulate(args: argparse.Namespace) -> int:
    from inspector.params import build_params, describe_params
    from inspector_drivers.replay.folder import save_capture
    from inspector_drivers.sim.simulate import SimParams, sim_rig, simulate

    table = {d["name"]: getattr(args, d["name"]) for d in describe_params(SimParams) if getattr(args, d["name"], None) is not None}
    if args.bump:
        table["bumps"] = [_parse_bump(b) for b in args.bump]
    if "dist" in table:
        table["dist"] = list(table["dist"])
    p = build_params(SimParams, table, "simulate")
    out = Path(args.out)
    rig = sim_rig(p)
    for i in range(p.count):
        folder = save_capture(cap := simulate(p, i, rig), out / cap.name, overwrite=True)
        print(f"[{i + 1}/{p.count}] wrote {folder}", flush=True)
    return EXIT_OK


# -- demo ------------------------------------------------------------------------------
def _demo(args: argparse.Namespace) -> int:
    """Simulate a good and a notched cube, inspect both with recipes/demo.toml."""
    from inspector.outputs import read_ply
    from inspector.params import build_params
    from inspector_drivers.replay.folder import save_capture
    from inspector_drivers.sim.simulate import SimParams, sim_rig, simulate

    out = Path(args.out)
    cap_dir = out / "captures"
    print(f"Simulating the 16-camera rig (1024x1024, 0.1 mm/px) into {cap_dir} ...", flush=True)
    cases = [
        ("cube-good", {"part": "cube30", "seed": 11}),
        ("cube-notched", {"part": "cube30", "seed": 12, "bumps": [{"at": [15.0, 15.0, 0.0], "radius_mm": 1.5, "kind": "remove"}]}),
    ]
    rig = None
    for name, table in cases:
        p = build_params(SimParams, table, "demo")
        rig = rig or sim_rig(p)
        save_capture(simulate(p, 0, rig, name=name), cap_dir / name, overwrite=True)
        print(f"  {name}: {'1.5 mm notch removed on an edge' if 'bumps' in table else 'as the reference'}")
    recipe = str(_recipes_dir() / "demo.toml")
    print(f"Inspecting with {recipe} ...", flush=True)
    status = _run(recipe, [str(cap_dir)], str(out / "results"), None, quiet=False)
    for name, _ in cases:
        res = json.loads((out / "results" / name / "result.json").read_text())
        print(f"\n{name}: verdict {res['verdict'].upper()}")
        if res["verdict"] == "error":
            print(f"  {res['error']}")
            continue
        s = res["stats"]
        d = s["deviation_mm"]
        print(f"  {s['n_points']} BCPS points; deviation mean {d['mean']:+.4f} mm, min {d['min']:+.4f}, max {d['max']:+.4f}; "
              f"{100 * s['within_tolerance']:.2f} % within ±{s['tolerance_mm']['upper']} mm")
        if "truth" in s and "bcps" in s["truth"]:
            t = s["truth"]["bcps"]
            print(f"  accuracy vs. truth: BCPS mean {t['mean_mm']:.4f} mm ({t['mean_px']:.3f} px), p99 {t['p99_mm']:.4f} mm; "
                  f"raw reconstruction mean {s['truth']['reconstruction']['mean_mm']:.4f} mm")
        for dfc in res["defects"]:
            pos = ", ".join(f"{x:.1f}" for x in dfc["position"])
            print(f"  defect: {dfc['kind']} material at ({pos}) mm, {dfc['n_points']} points, worst {dfc['worst_mm']:+.3f} mm")
        pts = read_ply(out / "results" / name / "bcps_points.ply")
        from inspector.report import render_report

        png = render_report(out / "results" / name)
        print(f"  outputs: {out / 'results' / name} (result.json, bcps_points.ply [{len(pts['x'])} pts], reconstruction.ply, {png.name})")
    expected = {"cube-good": "pass", "cube-notched": "fail"}
    got = {name: json.loads((out / "results" / name / "result.json").read_text())["verdict"] for name in expected}
    if got != expected:
        _err(f"demo verdicts {got}, expected {expected}")
        return EXIT_ERROR
    print(f"\nhistory: {out / 'results' / 'history.sqlite'} (inspector history {out / 'results'})")
    print("\nDemo OK: the good cube passes, the notched cube fails with its defect located.")
    return EXIT_OK if status in (EXIT_OK, EXIT_FAIL) else status


# -- plugins / recipe check -------------------------------------------------------------
def _plugins(args: argparse.Namespace) -> int:
    from inspector.manager import create_plugin_manager
    from inspector.params import describe_params

    pm = create_plugin_manager()
    doc: dict[str, Any] = {"plugins": pm.plugin_names(), "stages": {}, "drivers": {}}
    for kind, reg in (("stages", pm.stages), ("drivers", pm.drivers)):
        for name in reg.names():
            spec = reg[name]
            doc[kind][name] = {"doc": spec.doc, "params": describe_params(spec.params)}
            if kind == "stages":
                doc[kind][name]["requires"] = list(spec.requires)
    if args.json:
        print(json.dumps(doc, indent=2, default=repr))
        return EXIT_OK
    print("plugins: " + ", ".join(doc["plugins"]))
    for kind in ("stages", "drivers"):
        print(f"\n{kind.upper()}")
        for name, d in doc[kind].items():
            req = f"  (after: {', '.join(d['requires'])})" if d.get("requires") else ""
            print(f"  {name}: {d['doc']}{req}")
            for prm in d["params"]:
                print(f"      {prm['name']} ({prm['type']}, default {prm['default']!r}): {prm['doc']}")
    if args.parts:
        from inspector.parts import BUILTIN_PARTS

        print("\nBUILT-IN PARTS (reference = \"builtin:NAME\")")
        for name, desc in BUILTIN_PARTS.items():
            print(f"  {name}: {desc}")
    return EXIT_OK


def _recipe_check(args: argparse.Namespace) -> int:
    _, recipe, ref = _load(args.recipe, args.reference)
    steps = " -> ".join(f"{s.name} ({s.spec.name})" for s in recipe.steps)
    print(f"{args.recipe}: OK: recipe {recipe.name!r}, driver {recipe.driver.spec.name}, stages {steps}; reference {recipe.reference or 'none'}")
    return EXIT_OK


# -- entry point -----------------------------------------------------------------------
class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2 (CONTRACT)
        self.print_usage(sys.stderr)
        _err(message)
        raise SystemExit(EXIT_INVALID)


def build_parser() -> argparse.ArgumentParser:
    from inspector import __version__

    ap = _Parser(prog="inspector", description="3D quality inspection from the silhouettes of a multi-camera rig (BCPS).")
    ap.add_argument("--version", action="version", version=f"inspector {__version__}")
    sub = ap.add_subparsers(dest="command", required=True, parser_class=_Parser)

    r = sub.add_parser("run", help="inspect captures with a recipe (batch, one process)")
    r.add_argument("recipe", help="recipe TOML file")
    src = r.add_mutually_exclusive_group()
    src.add_argument("--capture", nargs="+", metavar="DIR", help="capture folders, or folders of capture folders (default: the recipe's driver)")
    src.add_argument("--watch", metavar="INBOX", help="hot folder: inspect capture folders as they land in INBOX, then move them to INBOX/done/")
    r.add_argument("--count", type=int, metavar="N", help="with --watch: stop after N captures")
    r.add_argument("--idle-exit", type=float, metavar="S", help="with --watch: stop after S seconds without a new capture")
    r.add_argument("--out", required=True, metavar="OUTDIR", help="result folder (one sub-folder per capture)")
    r.add_argument("--reference", metavar="MESH", help="reference mesh (STL/PLY/OBJ in mm, or builtin:NAME); replaces the recipe's")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress lines (capture errors are still printed, on stderr)")

    d = sub.add_parser("demo", help="simulate a good and a defective cube and inspect them")
    d.add_argument("--out", default="out/demo", help="where captures and results go (default out/demo)")

    s = sub.add_parser("simulate", help="write simulated capture folders")
    s.add_argument("--out", required=True, help="folder that receives one capture folder per capture")
    s.add_argument("--bump", action="append", metavar="X,Y,Z,R[,KIND]", help="a bump in the part's frame (kind add|remove, default remove); repeatable")
    from inspector_drivers.sim.simulate import SimParams

    _add_param_options(s, SimParams, skip={"bumps"})

    from inspector import experiment

    experiment.add_parser(sub)
    from inspector_drivers.replay import importers

    importers.add_parser(sub)
    from inspector import report

    report.add_parser(sub)
    from inspector import bench

    bench.add_parser(sub)
    from inspector_plugins import history

    history.add_parser(sub)
    from inspector_drivers import capture_cmd

    capture_cmd.add_parser(sub)
    from inspector import roles

    roles.add_parser(sub)
    # The GUI's parser only: Qt is imported when `inspector gui` runs, never for other commands.
    from inspector.gui import app as gui_app

    gui_app.add_parser(sub)

    pl = sub.add_parser("plugins", help="list stages and drivers with their parameters")
    pl.add_argument("--json", action="store_true", help="machine-readable output")
    pl.add_argument("--parts", action="store_true", help="also list the built-in parts")

    rc = sub.add_parser("recipe", help="recipe tools")
    rsub = rc.add_subparsers(dest="recipe_command", required=True, parser_class=_Parser)
    chk = rsub.add_parser("check", help="validate a recipe without running it")
    chk.add_argument("recipe")
    chk.add_argument("--reference", metavar="MESH")
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.command == "run":
            return _run(args.recipe, args.capture, args.out, args.reference, args.quiet,
                        watch=_watch_params(args))
        if args.command == "demo":
            return _demo(args)
        if args.command == "simulate":
            return _simulate(args)
        if args.command == "plugins":
            return _plugins(args)
        if args.command == "capture":
            from inspector_drivers import capture_cmd

            return capture_cmd.run(args)
        if args.command == "bench":
            from inspector import bench

            return bench.run(args)
        if args.command == "history":
            from inspector_plugins import history

            return history.run(args)
        if args.command == "report":
            from inspector import report

            return report.run(args)
        if args.command == "import":
            from inspector_drivers.replay import importers

            return importers.run(args)
        if args.command == "experiment":
            from inspector import experiment

            return experiment.run(args)
        if args.command == "recipe":
            return _recipe_check(args)
        if args.command == "roles":
            from inspector import roles

            return roles.run(args)
        if args.command == "gui":
            from inspector.gui import app as gui_app

            return gui_app.run(args)
    except RecipeError as e:
        _err(str(e))
        return EXIT_INVALID
    except InspectorError as e:
        _err(str(e))
        return EXIT_ERROR
    except BrokenPipeError:  # output piped to a pager or head that closed early
        return EXIT_OK
    except KeyboardInterrupt:
        _err("interrupted; results written so far are kept")
        return 130
    except OSError as e:
        _err(f"{e.filename or ''}: {e.strerror or e}".strip(": "))
        return EXIT_ERROR
    except Exception as e:  # noqa: BLE001 - a bug: one line for the user, the traceback kept for us
        _err(f"internal error {type(e).__name__}: {' '.join(str(e).split())} (traceback in {_save_traceback()})")
        return EXIT_ERROR
    return EXIT_INVALID


def _save_traceback() -> str:
    """Write the current exception's traceback to a new private file; its path."""
    from inspector.tracebacks import save_traceback

    return save_traceback()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
