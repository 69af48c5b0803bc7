"""``inspector calibrate --refine``'s command: its inputs checked, the rig refined and written, its report.

The refinement itself is :mod:`inspector.calibration.refine`'s (see its docstring).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from inspector.calibration.command import check_new_file, write_rig
from inspector.calibration.refine import (
    ROBUST_PX,
    Refinement,
    _check_folder,
    inspect_with_rig,
    load_inputs,
    refine_rig,
)
from inspector.errors import RecipeError
from inspector.kernels import silhouette_fit as sf
from inspector.model import Rig

__all__ = ["run_refine"]


def _report(ref: Refinement, rig: Rig, used: list[str], left_out: list[str], seconds: float) -> dict[str, Any]:
    def num(v: float) -> float | None:
        return round(float(v), 4) if np.isfinite(v) else None

    cams = {}
    for i, c in enumerate(rig.cameras):
        e: dict[str, Any] = {"before_px": num(ref.before_px[i]), "after_px": num(ref.after_px[i]),
                             "turn_px": num(ref.turn_px[i]),
                             "turn_mrad": [round(float(v) * 1e3, 5) for v in ref.turn[i]],
                             "shift_mm": [round(float(v), 4) for v in ref.shift_mm[i]], "rays": int(ref.rays[i])}
        if ref.intrinsics is not None:
            e["intrinsics_px"] = dict(zip(sf.INTRINSICS, (round(float(v), 3) for v in ref.intrinsics[i])))
        cams[c.name] = e
    return {
        "captures": used, "left_out": left_out, "intrinsics": ref.intrinsics is not None,
        "iterations": ref.iterations, "converged": ref.converged, "seconds": round(seconds, 1),
        "robust_px": ROBUST_PX, "gauge_cameras": list(ref.gauge_cameras),
        "offset_mm": {n: round(float(v), 5) for n, v in zip(used, ref.offset_mm)},
        "median_before_px": num(float(np.nanmedian(ref.before_px))),
        "median_after_px": num(float(np.nanmedian(ref.after_px))),
        "cameras": cams,
    }


def _text(report: dict[str, Any], out: Path) -> str:
    lines = [f"refined from {len(report['captures'])} captures in {report['iterations']} iterations"
             f"{'' if report['converged'] else ' (not converged)'}, {report['seconds']} s "
             f"({report['seconds_inspect']} s inspecting, {report['seconds_refine']} s refining); "
             f"median |residual| {report['median_before_px']} -> {report['median_after_px']} px"]
    if report["left_out"]:
        lines.append(f"left out (inspection failed): {', '.join(report['left_out'])}")
    lines.append(f"{'camera':<10} {'before px':>10} {'after px':>10} {'turn px':>9} {'shift mm':>9}")
    for name, c in report["cameras"].items():
        sh = float(np.linalg.norm(c["shift_mm"]))

        def fmt(v: float | None) -> str:
            return "-" if v is None else f"{v:.3f}"
        lines.append(f"{name:<10} {fmt(c['before_px']):>10} {fmt(c['after_px']):>10} {fmt(c['turn_px']):>9} "
                     f"{sh:>9.4f}")
    off = [n for n in report["cameras"] if n not in report["gauge_cameras"]]
    if off:
        lines.append(f"frame held by the other cameras (these moved apart from them): {', '.join(off)}")
    lines.append(f"wrote {out}")
    return "\n".join(lines)


def run_refine(args: argparse.Namespace) -> int:
    """``inspector calibrate --refine RIG --captures DIR --reference MESH --out RIG2``."""
    if not args.out:
        raise RecipeError("--refine: give --out RIG2.json (the refined rig to write)")
    if not args.reference:
        raise RecipeError("--refine: give --reference MESH (the parts' reference mesh, or builtin:NAME)")
    if args.rig or args.correct:
        raise RecipeError("--refine: --rig and --correct belong to --verify (the rig to refine is --refine RIG)")
    out = check_new_file(args.out, args.force, "refined rig")
    if Path(args.refine).resolve() == out.resolve():
        raise RecipeError(f"{out}: is the input rig; write the refined rig to another file")
    rig, folders, recipe, ref, pm = load_inputs(args.captures, args.reference, args.recipe, args.refine, "--refine")
    quiet = bool(getattr(args, "json", False))

    def say(line: str) -> None:
        if not quiet:
            print(line, flush=True)

    t0 = time.perf_counter()
    for f in folders:  # every folder is checked before the first inspection
        _check_folder(f, rig)
    done = inspect_with_rig(folders, rig, recipe, ref, pm, progress=say)
    good = [d for d in done if d.view is not None]
    if not good:
        raise RecipeError(f"--captures {args.captures}: no capture could be inspected "
                          f"({done[0].error if done else 'none'})")
    t1 = time.perf_counter()
    result = refine_rig(rig, [d.view for d in good if d.view is not None], ref.distance,
                        intrinsics=bool(args.intrinsics), progress=say)
    seconds = time.perf_counter() - t0
    report = _report(result, rig, [d.name for d in good], [d.name for d in done if d.view is None], seconds)
    report["seconds_inspect"] = round(t1 - t0, 1)
    report["seconds_refine"] = round(time.perf_counter() - t1, 1)
    report.update({"input_rig": str(args.refine), "reference": str(args.reference),
                   "recipe": str(recipe.path) if recipe.path is not None else recipe.name})
    write_rig(result.rig, out, {"refinement": report})
    if quiet:
        print(json.dumps({**report, "out": str(out)}, indent=1))
    else:
        print(_text(report, out))
    return 0
