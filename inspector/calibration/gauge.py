"""``inspector calibrate --verify``: a rig's scale checked with a gauge of known size.

::

    inspector calibrate --verify REFERENCE --captures DIR --rig RIG.json
                        [--correct OUT.json] [--recipe R] [--json] [--force]

Each capture of the gauge (any reference mesh made to its nominal size: a sphere, a step
gauge, a part measured on a coordinate measuring machine) is inspected with the rig. A rig
whose cameras stand ``s`` times too far from its origin shows every part ``s`` times too
large: the images of a rig and a part scaled together about the origin are the same, so
what the rig measures of the gauge is its scale.

The scale of each capture is the least-squares size of the reference fitted to the BCPS
points (:func:`~inspector.kernels.prior.fit_size_prior`, the bcps stage's own size model:
isotropic scale about the reference's centre, with a small rotation and shift). The bcps
stage itself keeps a part at nominal size unless the scale explains its points clearly
better than a uniform offset (on a sphere or a cube it never does: both move every point
alike); a gauge *is* of nominal size, so here any such offset is the scale error and the
fit is taken as it is. Reported: the scale error in ppm (mean over the captures, with its
standard uncertainty, the standard deviation over the captures over the square root of
their number), and the BCPS residual (mean absolute deviation of the BCPS points from the
nominal gauge, px).

``--correct OUT.json`` writes the rig with its scale corrected: every camera centre scaled
about the origin by ``1 / s`` (``t' = t / s``; rotations and intrinsics unchanged), so that
the gauge measures its nominal size. Simulated (8 cameras, 512², 0.1 mm/px, the built-in
sphere30, three captures): a rig scaled by 1.001 is measured at 1013-1019 ppm, the exact rig
at 7-24 ppm.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from inspector.calibration.command import check_new_file, write_rig
from inspector.calibration.refine import _check_folder, inspect_with_rig, load_inputs
from inspector.errors import RecipeError
from inspector.kernels.prior import fit_size_prior
from inspector.model import Camera, Rig

if TYPE_CHECKING:
    from inspector.calibration.refine import InspectedCapture
    from inspector.reference import Reference

__all__ = ["run_verify", "gauge_scale", "scaled_rig", "Verification", "verify_captures"]


def scaled_rig(rig: Rig, factor: float) -> Rig:
    """``rig`` with every camera centre scaled by ``factor`` about the origin (``t * factor``)."""
    return Rig(tuple(Camera(c.name, c.width, c.height, c.K, c.dist, c.R, np.asarray(c.t, float) * float(factor))
                     for c in rig.cameras))


def gauge_scale(points: np.ndarray, pose: np.ndarray, ref: Reference) -> float | None:
    """The scale (1: nominal) of the reference best fitting world ``points`` (N, 3) about
    ``pose`` (the stage's size model, without its test of significance); None when the fit
    fails (too few points, a size off by more than 5 %)."""
    V = ref.vertices
    local = ref.to_reference_frame(np.asarray(points, float), np.asarray(pose, float))
    prior = fit_size_prior(local, ref.distance, centre=0.5 * (V.min(axis=0) + V.max(axis=0)), robust_mm=0.1,
                           min_significance=0.0)
    if prior.is_identity and prior.inliers == 1.0:
        return None  # the fit's identity: it failed
    return float(prior.scale)


class Verification(dict):
    """The report of :func:`verify_captures` (a dict: what ``--json`` prints)."""


def verify_captures(done: list[InspectedCapture], ref: Reference, footprint_mm: float) -> Verification:
    """The scale and residual figures of gauge captures inspected with a rig
    (:class:`~inspector.calibration.refine.InspectedCapture`)."""
    rows = []
    for d in done:
        row: dict[str, Any] = {"capture": d.name, "verdict": d.verdict}
        if d.view is None or d.points is None or d.pose is None:
            row["error"] = d.error
        else:
            s = gauge_scale(d.points, d.pose, ref)
            row["scale_ppm"] = None if s is None else round((s - 1.0) * 1e6, 1)
            row["residual_px"] = None if d.bcps_mean_px is None else round(d.bcps_mean_px, 4)
            row["signed_px"] = None if d.bcps_signed_px is None else round(d.bcps_signed_px, 4)
        rows.append(row)
    ppm = np.array([r["scale_ppm"] for r in rows if r.get("scale_ppm") is not None], float)
    res = np.array([r["residual_px"] for r in rows if r.get("residual_px") is not None], float)
    out = Verification(
        captures=rows,
        measured=int(len(ppm)),
        scale_ppm=round(float(ppm.mean()), 1) if len(ppm) else None,
        uncertainty_ppm=round(float(ppm.std(ddof=1) / np.sqrt(len(ppm))), 1) if len(ppm) >= 2 else None,
        residual_px=round(float(res.mean()), 4) if len(res) else None,
        footprint_mm=round(float(footprint_mm), 5),
    )
    return out


def _text(v: Verification) -> str:
    lines = []
    for r in v["captures"]:
        if "error" in r:
            lines.append(f"  {r['capture']}: error: {r['error']} (left out)")
        else:
            ppm = "-" if r["scale_ppm"] is None else f"{r['scale_ppm']:+.1f} ppm"
            res = "-" if r["residual_px"] is None else f"{r['residual_px']:.4f}"
            lines.append(f"  {r['capture']}: scale {ppm}, BCPS residual {res} px ({r['verdict']})")
    u = "" if v["uncertainty_ppm"] is None else f" ± {v['uncertainty_ppm']:.1f}"
    lines.append(f"scale {v['scale_ppm']:+.1f}{u} ppm over {v['measured']} captures (the gauge measures "
                 f"{'larger' if v['scale_ppm'] > 0 else 'smaller'} than nominal: the rig is "
                 f"{'too large' if v['scale_ppm'] > 0 else 'too small'}); BCPS residual "
                 f"{'-' if v['residual_px'] is None else format(v['residual_px'], '.4f')} px")
    if v.get("corrected"):
        lines.append(f"wrote {v['corrected']} (camera centres scaled by {v['correction']:.8f} about the origin)")
    return "\n".join(lines)


def run_verify(args: argparse.Namespace) -> int:
    """``inspector calibrate --verify REFERENCE --captures DIR --rig RIG [--correct OUT]``."""
    if not args.rig:
        raise RecipeError("--verify: give --rig RIG.json (the rig to verify)")
    if args.out:
        raise RecipeError("--verify: writes no --out (use --correct OUT.json for the corrected rig)")
    if args.intrinsics or args.reference:
        raise RecipeError("--verify: --intrinsics and --reference belong to --refine (the gauge is --verify REFERENCE)")
    out = check_new_file(args.correct, args.force, "corrected rig") if args.correct else None
    if out is not None and out.resolve() == Path(args.rig).resolve():
        raise RecipeError(f"{out}: is the rig verified; write the corrected rig to another file")
    rig, folders, recipe, ref, pm = load_inputs(args.captures, args.verify, args.recipe, args.rig, "--rig")
    quiet = bool(getattr(args, "json", False))

    def say(line: str) -> None:
        if not quiet:
            print(line, flush=True)

    for f in folders:
        _check_folder(f, rig)
    t0 = time.perf_counter()
    done = inspect_with_rig(folders, rig, recipe, ref, pm, progress=say, label="verify")
    v = verify_captures(done, ref, rig.footprint_mm())
    if v["scale_ppm"] is None:
        first = next((d.error for d in done if d.error), "no scale could be fitted")
        raise RecipeError(f"--captures {args.captures}: the gauge could not be measured in any capture ({first})")
    v["seconds"] = round(time.perf_counter() - t0, 1)
    if out is not None:
        s = 1.0 + v["scale_ppm"] * 1e-6
        v["correction"] = 1.0 / s
        write_rig(scaled_rig(rig, 1.0 / s), out, {"verification": {
            "gauge": str(args.verify), "input_rig": str(args.rig), "scale_ppm": v["scale_ppm"],
            "uncertainty_ppm": v["uncertainty_ppm"], "captures": [r["capture"] for r in v["captures"]],
            "centres_scaled_by": 1.0 / s}})
        v["corrected"] = str(out)
    if quiet:
        print(json.dumps(dict(v), indent=1))
    else:
        print(_text(v))
    return 0
