"""The calibration's report: per camera figures, advice, text, ``report.json`` and pictures.

Per camera (:func:`summarise`): RMS and largest reprojection error of the corners the final
adjustment used (px), corners and views (target poses) used, boards rejected, the image area
covered (% of the image inside the convex hull of its corners), the standard uncertainty of
its position (mm) and orientation (degrees) and of its focal length (%), and, for a camera
seen too little, what to do ("cam07: the target seen in 3 poses, 40 % of the image covered:
show it to cam07 in more poses").

A camera is *seen too little* when it saw the target in fewer than :data:`MIN_POSES` poses or
in fewer than half as many as the median camera, when its corners cover less than half the
median camera's area or less than :data:`MIN_COVER_PCT` % of its image, or when its focal
length is not determined (standard uncertainty above :data:`UNDETERMINED_F_PCT` %).

Pictures (:func:`write_pictures`, matplotlib's Agg backend): ``corners_<camera>.png`` per
camera (every corner seen, coloured by its residual, rejected boards grey, the covered area
outlined) and ``corners_all.png``, the same for all cameras in one grid.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from inspector.calibration.solve import Calibration

__all__ = ["summarise", "text", "write_pictures", "timing_line", "STAGES", "MIN_POSES", "MIN_COVER_PCT"]

#: A camera is seen too little below this many target poses ...
MIN_POSES = 6
#: ... or below this much of its image covered (%).
MIN_COVER_PCT = 10.0

#: A camera whose focal length's standard uncertainty exceeds this (%) is not calibrated: said so.
UNDETERMINED_F_PCT = 5.0
#: Residual (px) at the top of the pictures' colour scale.
COLOUR_MAX_PX = 0.5

#: The stages of :attr:`~inspector.calibration.solve.Calibration.timings` in the order the command
#: runs them, and their words.
STAGES = (("detect_s", "detection"), ("initialise_s", "initialisation"), ("adjust_s", "adjustment"),
          ("covariance_s", "uncertainty"), ("write_s", "writing"))


def timing_line(timings: dict[str, float]) -> str:
    """``"done in 18.4 s (31.0 s of CPU): detection 6.1 s, initialisation 0.9 s, ..., machine
    load 1.2"``: the command's own benchmark line (seconds of wall time per stage; the CPU
    seconds of all the command's threads and the 1-minute load average beside them, since a
    machine loaded by other work stretches the wall time, not the CPU time)."""
    parts = [f"{word} {timings[key]:.1f} s" for key, word in STAGES if key in timings]
    load = f", machine load {os.getloadavg()[0]:.1f}" if hasattr(os, "getloadavg") else ""
    total = timings.get("command_s", timings.get("total_s", 0.0))
    cpu = f" ({timings['cpu_s']:.1f} s of CPU)" if "cpu_s" in timings else ""
    return f"done in {total:.1f} s{cpu}: {', '.join(parts)}{load}"


def _coverage(uv: np.ndarray, width: int, height: int) -> float:
    """% of the image inside the convex hull of the points ``uv``."""
    import cv2

    if len(uv) < 3:
        return 0.0
    hull = cv2.convexHull(np.asarray(uv, np.float32).reshape(-1, 1, 2))
    return float(100.0 * cv2.contourArea(hull) / (width * height))


def _r(x: float, nd: int = 4) -> float | None:
    return round(float(x), nd) if np.isfinite(x) else None


def summarise(cal: Calibration) -> dict[str, Any]:
    """The report as a JSON-ready dict: ``cameras`` (one entry each), ``advice``, ``rejected``..."""
    cams: list[dict[str, Any]] = []
    n = len(cal.names)
    per: list[dict[str, Any]] = []
    for j in range(n):
        kept = [k for k, v in enumerate(cal.views) if v.camera == j and cal.kept[k]]
        rej = [k for k, v in enumerate(cal.views) if v.camera == j and not cal.kept[k] and len(cal.residuals[k])]
        r = np.concatenate([cal.residuals[k] for k in kept]) if kept else np.zeros((0, 2))
        e = np.linalg.norm(r, axis=1)
        uv = np.concatenate([cal.views[k].uv for k in kept]) if kept else np.zeros((0, 2))
        w, h = cal.sizes[j]
        per.append({"rms": float(np.sqrt(np.mean(e * e))) if len(e) else float("nan"),
                    "max": float(e.max()) if len(e) else float("nan"), "corners": int(len(e)),
                    "views": len({cal.views[k].capture for k in kept}), "boards": len(kept), "rejected": len(rej),
                    "coverage": _coverage(uv, w, h)})
    med_views = float(np.median([p["views"] for p in per]))
    med_cover = float(np.median([p["coverage"] for p in per]))
    advice: list[str] = []
    for j, name in enumerate(cal.names):
        p = per[j]
        K = cal.K[j]
        few = p["views"] < MIN_POSES or p["views"] < 0.5 * med_views
        small = p["coverage"] < MIN_COVER_PCT or p["coverage"] < 0.5 * med_cover
        tip = None
        fstd = 100.0 * float(np.hypot(cal.intrinsic_std[j, 0] / K[0, 0], cal.intrinsic_std[j, 1] / K[1, 1]) / np.sqrt(2))
        undetermined = not np.isfinite(fstd) or fstd > UNDETERMINED_F_PCT
        if few or small or undetermined:
            what = "in more poses" if few or undetermined else "in more poses, nearer the edges of its image"
            tip = (f"{name}: the target seen in {p['views']} pose{'s' * (p['views'] != 1)}, {p['coverage']:.0f} % of the "
                   f"image covered: show it to {name} {what}")
            if undetermined:
                tip += f" (its focal length is not determined: +-{fstd:.3g} %)"
            advice.append(tip)
        cams.append({
            "name": name, "width": int(cal.sizes[j][0]), "height": int(cal.sizes[j][1]),
            "rms_px": _r(p["rms"]), "max_px": _r(p["max"]), "corners": p["corners"], "views": p["views"],
            "boards": p["boards"], "rejected_boards": p["rejected"], "coverage_pct": _r(p["coverage"], 1),
            "centre_std_mm": _r(cal.centre_std_mm[j]), "angle_std_deg": _r(cal.angle_std_deg[j], 5),
            "f_std_pct": _r(fstd), "fx": _r(K[0, 0], 3), "fy": _r(K[1, 1], 3), "cx": _r(K[0, 2], 3), "cy": _r(K[1, 2], 3),
            "dist": [_r(d, 6) for d in cal.dist[j]], "advice": tip,
        })
    kept_all = [k for k in range(len(cal.views)) if cal.kept[k]]
    return {
        "target": {**cal.target.to_json(), "source": cal.target.source},
        "captures": len(cal.captures),
        "poses": len(cal.poses),
        "cameras": cams,
        "corners": int(sum(len(cal.views[k].ids) for k in kept_all)),
        "rms_px": _r(cal.rms_px),
        "sigma_px": _r(cal.sigma_px),
        "iterations": int(cal.iterations),
        "rejected": cal.rejected,
        "reject_threshold_px": _r(cal.reject_threshold_px),
        "max_angle_deg": float(cal.max_angle_deg),
        "advice": advice,
        "notes": list(cal.notes),
    }


def text(summary: dict[str, Any]) -> str:
    """The report as text (what the command prints)."""
    lines = [f"Calibrated {len(summary['cameras'])} cameras from {summary['poses']} target poses "
             f"({summary['corners']} corners): RMS {summary['rms_px']:.3f} px"]
    head = (f"{'camera':<10} {'RMS px':>7} {'max px':>7} {'corners':>8} {'views':>6} {'cover %':>8} "
            f"{'centre mm':>10} {'angle deg':>10} {'f %':>7}")
    lines += ["", head]

    def f(v: Any, fmt: str) -> str:
        return "-" if v is None else format(v, fmt)

    for c in summary["cameras"]:
        lines.append(f"{c['name']:<10} {f(c['rms_px'], '7.3f')} {f(c['max_px'], '7.3f')} {c['corners']:>8d} {c['views']:>6d} "
                     f"{f(c['coverage_pct'], '8.1f')} {f(c['centre_std_mm'], '10.3f')} {f(c['angle_std_deg'], '10.4f')} "
                     f"{f(c['f_std_pct'], '7.3f')}")
    lines.append("(centre, angle, f: standard uncertainty, 1 sigma, relative to the other cameras)")
    rej = summary["rejected"]
    steep = [r for r in rej if r.get("reason") == "steep"]
    worse = [r for r in rej if r.get("reason") != "steep"]
    if steep:
        lines += ["", f"Rejected {len(steep)} board view{'s' * (len(steep) != 1)} seen at more than "
                      f"{summary.get('max_angle_deg', 70):g} degrees from face-on (their corners are biased)."]
    if worse:
        lines += ["" if not steep else "", f"Rejected {len(worse)} board view{'s' * (len(worse) != 1)} whose residual RMS "
                  f"exceeds {summary['reject_threshold_px']:.3f} px (3 x the median: biased or badly detected):"]
        shown = sorted(worse, key=lambda r: -r["rms_px"])
        for r in shown[:12]:
            lines.append(f"  {r['camera']} in {r['capture']}, board {r['board']} ({r['angle_deg']:.0f} deg): {r['corners']} "
                         f"corners, RMS {r['rms_px']:.3f} px")
        if len(shown) > 12:
            lines.append(f"  ... and {len(shown) - 12} more (report.json)")
    for note in summary["notes"]:
        lines.append(f"note: {note}")
    if summary["advice"]:
        lines += ["", "Seen too little:"] + [f"  {a}" for a in summary["advice"]]
    if "rig" in summary:
        lines += ["", f"Wrote {summary['rig']}; report and pictures in {summary.get('report_dir', '')}"]
    t = summary.get("timings_s")
    if t:
        lines.append(timing_line(t).replace("done in", "Time:", 1))
    return "\n".join(lines)


def _draw(ax: Any, cal: Calibration, j: int, summary_cam: dict[str, Any], small: bool) -> Any:
    import cv2
    from matplotlib.patches import Polygon

    w, h = cal.sizes[j]
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_aspect("equal")
    ax.set_facecolor("#f4f4f4")
    kept = [k for k, v in enumerate(cal.views) if v.camera == j and cal.kept[k]]
    rej = [k for k, v in enumerate(cal.views) if v.camera == j and not cal.kept[k]]
    s = 2 if small else 6
    if rej:
        uv = np.concatenate([cal.views[k].uv for k in rej])
        ax.scatter(uv[:, 0], uv[:, 1], s=s, c="0.6", marker="x", linewidths=0.5, label="rejected")
    sc = None
    if kept:
        uv = np.concatenate([cal.views[k].uv for k in kept])
        e = np.linalg.norm(np.concatenate([cal.residuals[k] for k in kept]), axis=1)
        sc = ax.scatter(uv[:, 0], uv[:, 1], s=s, c=e, cmap="viridis", vmin=0.0, vmax=COLOUR_MAX_PX, linewidths=0)
        if len(uv) >= 3:
            hull = cv2.convexHull(uv.astype(np.float32).reshape(-1, 1, 2)).reshape(-1, 2)
            ax.add_patch(Polygon(hull, closed=True, fill=False, edgecolor="tab:red", linewidth=0.8))
    c = summary_cam
    rms = "-" if c["rms_px"] is None else f"{c['rms_px']:.3f}"
    if small:
        title = f"{c['name']}  {c['views']} poses  {c['coverage_pct']:.0f} %  {rms} px"
    else:
        title = f"{c['name']}: {c['views']} poses, {c['coverage_pct']:.0f} % covered, RMS {rms} px"
    ax.set_title(title, fontsize=6.5 if small else 9)
    if small:
        ax.set_xticks([])
        ax.set_yticks([])
    return sc


def write_pictures(cal: Calibration, summary: dict[str, Any], folder: Path) -> list[Path]:
    """``corners_<camera>.png`` per camera and ``corners_all.png`` (all in a grid) in ``folder``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = Path(folder)
    out: list[Path] = []
    for j, name in enumerate(cal.names):
        fig, ax = plt.subplots(figsize=(4.6, 4.2), dpi=90, layout="constrained")
        sc = _draw(ax, cal, j, summary["cameras"][j], small=False)
        if sc is not None:
            fig.colorbar(sc, ax=ax, fraction=0.046, pad=0.03, label="residual (px)")
        p = folder / f"corners_{name}.png"
        fig.savefig(p)
        plt.close(fig)
        out.append(p)
    n = len(cal.names)
    cols = int(np.ceil(np.sqrt(n)))
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(2.1 * cols + 0.9, 2.1 * rows + 0.5), dpi=100, squeeze=False,
                             layout="constrained")
    sc = None
    for j in range(rows * cols):
        ax = axes[j // cols][j % cols]
        if j >= n:
            ax.axis("off")
            continue
        sc = _draw(ax, cal, j, summary["cameras"][j], small=True) or sc
    fig.suptitle(f"Corners seen by each camera, coloured by residual (px); grey x: rejected; red: area covered. "
                 f"RMS {summary['rms_px']:.3f} px", fontsize=8)
    if sc is not None:
        fig.colorbar(sc, ax=axes, shrink=0.6, label="residual (px)")
    p = folder / "corners_all.png"
    fig.savefig(p)
    plt.close(fig)
    out.append(p)
    return out
