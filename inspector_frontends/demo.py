"""``inspector demo``: simulate a good and a notched cube on the 16-camera rig and inspect both
with the shipped ``demo.toml`` (what ``make demo`` runs). A built-in command plugin (entry point
``demo``), registered like any third party's; it drives the simulator and ``inspector run``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from inspector import hookimpl
from inspector.params import build_params
from inspector.registry import CommandRegistry, CommandSpec
from inspector.report import render_report
from inspector.resources import recipe_path
from inspector_drivers.sim.simulate import SimParams, sim_rig, simulate
from inspector_frontends.cli import EXIT_ERROR, EXIT_FAIL, EXIT_OK, err, run_recipe

__all__ = ["add_demo_parser", "demo_command"]


def add_demo_parser(sub: argparse._SubParsersAction[Any]) -> None:
    d = sub.add_parser("demo", help="simulate a good and a defective cube and inspect them")
    d.add_argument("--out", default="out/demo", help="where captures and results go (default out/demo)")


def demo_command(args: argparse.Namespace) -> int:
    """Simulate a good and a notched cube, inspect both with the shipped ``demo.toml``."""
    from inspector.capture_folder import save_capture
    from inspector.outputs import read_ply

    out = Path(args.out)
    cap_dir = out / "captures"
    print(f"Simulating the 16-camera rig (1024x1024, 0.1 mm/px) into {cap_dir} ...", flush=True)
    cases: list[tuple[str, dict[str, Any]]] = [
        ("cube-good", {"part": "cube30", "seed": 11}),
        ("cube-notched", {"part": "cube30", "seed": 12,
                          "bumps": [{"at": [15.0, 15.0, 0.0], "radius_mm": 1.5, "kind": "remove"}]}),
    ]
    rig = None
    for name, table in cases:
        p = build_params(SimParams, table, "demo")
        rig = rig or sim_rig(p)
        save_capture(simulate(p, 0, rig, name=name), cap_dir / name, overwrite=True)
        print(f"  {name}: {'1.5 mm notch removed on an edge' if 'bumps' in table else 'as the reference'}")
    recipe = str(recipe_path("demo.toml"))
    print(f"Inspecting with {recipe} ...", flush=True)
    status = run_recipe(recipe, [str(cap_dir)], str(out / "results"), None, quiet=False,
                        pm=getattr(args, "plugin_manager", None))
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
        png = render_report(out / "results" / name)
        print(f"  outputs: {out / 'results' / name} (result.json, bcps_points.ply [{len(pts['x'])} pts], "
              f"reconstruction.ply, {png.name})")
    expected = {"cube-good": "pass", "cube-notched": "fail"}
    got = {name: json.loads((out / "results" / name / "result.json").read_text())["verdict"] for name in expected}
    if got != expected:
        err(f"demo verdicts {got}, expected {expected}")
        return EXIT_ERROR
    print(f"\nhistory: {out / 'results' / 'history.sqlite'} (inspector history {out / 'results'})")
    print("\nDemo OK: the good cube passes, the notched cube fails with its defect located.")
    return EXIT_OK if status in (EXIT_OK, EXIT_FAIL) else status


@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    """``inspector demo``: a built-in plugin (entry point ``demo``), like any command."""
    registry.add(CommandSpec("demo", add_demo_parser, demo_command, "simulate a good and a notched cube and inspect both"))
