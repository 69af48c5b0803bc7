"""End-to-end acceptance of ``inspector calibrate`` (issue 24, "Done when", first bullet):
simulated captures of the calibration cube, the calibrated rig against the true one, and parts
inspected with the calibrated rig as well as with the exact one.

1. **The true rig**: the default 16-camera sphere rig (1024², 0.1 mm/px at the centre, 400 mm),
   each camera given a lens of its own (seed ``--rig-seed``): k1 of magnitude 0.08-0.12 and
   either sign, k2 within +-0.05, p1 and p2 within +-2e-4, the focal length within +-1 % and
   the principal point within +-8 px of nominal (``--uniform``: every camera k1 = 0.1 and
   nothing else, the simulator's rig with ``--dist 0.1``). Written to ``WORK/true_rig.json``.
2. **Target captures** with the real command line: ``inspector simulate --target
   examples/calibration/charuco_cube.toml --rig true_rig.json --poses N --supersample S
   --out WORK/target`` (random poses, so some boards are seen steeply; blur 0.7 px, noise
   sigma 2). Reused when ``WORK/target/stamp.json`` says they were made with the same settings.
3. **Calibration** with the real command line: ``inspector calibrate TARGET --captures
   WORK/target --out WORK/calibrated.json --force --json``; its wall time, its own per-stage
   timings and the boards it rejected (steep or biased) are reported.
4. **The calibrated rig against the truth** (:func:`inspector.kernels.calibration.compare_rigs`):
   the estimated frame aligned to the true one by the 7-dof similarity that minimises the
   reprojection differences of points uniform in a ball of ``--radius-mm`` about the rig
   centre; per camera the RMS of those differences (px), the focal length errors (%) and the
   camera centre's distance after the alignment (mm). Also at ``--radius-mm-wide`` (the
   bracket's reach).
5. **Parts**: ``--count`` good captures each of ``cube30`` and ``bracket`` rendered with the
   TRUE rig (the simulator, seeds ``--part-seed``..), inspected with the shipped
   ``default.toml`` once with the exact rig and once with the calibrated rig (put in the true
   frame by the similarity's rotation and translation only: its own scale is kept, so a scale
   error of the calibration shows in the distances). The BCPS points are measured against the
   true surface (``truth/part.ply``, exact point-to-triangle distances of
   :func:`measure.distances_to_mesh`), mean and p99 in px (0.1 mm).

Bars (issue 24): every camera within 0.05 px RMS over the working volume, focal lengths within
0.1 %, centres within 0.5 mm, and for each part the calibrated rig's BCPS mean within 0.01 px of
the exact rig's (and every good part passes). Exit 0 when all are met, 1 when not, 2 when a
command fails.

Usage::

    .venv/bin/python tests/acceptance/calibration_e2e.py --work /tmp/calibration-e2e [--poses 30] [--supersample 4]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # siblings, when run as a script

from calibration_common import ROOT, Measurer, inspector_exe, relax_watchdog, simulate_parts

TARGET = ROOT / "examples" / "calibration" / "charuco_cube.toml"
BAR_RMS_PX, BAR_F_PCT, BAR_CENTRE_MM, BAR_BCPS_PX = 0.05, 0.1, 0.5, 0.01


def true_rig(seed: int, uniform: bool) -> Any:
    """The rig the captures are rendered with (module docstring, step 1)."""
    from inspector.model import Camera, Rig
    from inspector_drivers.sim.rig import sphere_rig

    base = sphere_rig(16, dist=[0.1])
    if uniform:
        return base
    rng = np.random.default_rng(seed)
    cams = []
    for c in base.cameras:
        K = np.array(c.K, float)
        K[0, 0] *= 1.0 + rng.uniform(-0.01, 0.01)
        K[1, 1] = K[0, 0] * (1.0 + rng.uniform(-1e-3, 1e-3))  # square pixels, almost
        K[0, 2] += rng.uniform(-8.0, 8.0)
        K[1, 2] += rng.uniform(-8.0, 8.0)
        k1 = rng.choice([-1.0, 1.0]) * rng.uniform(0.08, 0.12)
        dist = np.array([k1, rng.uniform(-0.05, 0.05), rng.uniform(-2e-4, 2e-4), rng.uniform(-2e-4, 2e-4), 0.0])
        cams.append(Camera(c.name, c.width, c.height, K, dist, c.R, c.t))
    return Rig(tuple(cams))


def run_cmd(cmd: list[str], label: str) -> tuple[subprocess.CompletedProcess[str], float]:
    print(f"{label}: {' '.join(cmd)}", flush=True)
    t = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if proc.returncode != 0:
        print(proc.stdout[-3000:], proc.stderr[-3000:], file=sys.stderr)
        raise SystemExit(2)
    return proc, wall


def simulate_target(work: Path, rig_path: Path, poses: int, supersample: int, seed: int) -> tuple[Path, float | None]:
    """Target captures (step 2), reused when made with the same settings."""
    out = work / "target"
    stamp = {"rig": rig_path.read_text(), "poses": poses, "supersample": supersample, "seed": seed,
             "target": TARGET.read_text()}
    if (out / "stamp.json").is_file() and json.loads((out / "stamp.json").read_text()) == stamp:
        print(f"target captures: reusing {out}", flush=True)
        return out, None
    cmd = [inspector_exe(), "simulate", "--target", str(TARGET), "--rig", str(rig_path), "--poses", str(poses),
           "--supersample", str(supersample), "--seed", str(seed), "--out", str(out)]
    _, wall = run_cmd(cmd, "target captures")
    (out / "stamp.json").write_text(json.dumps(stamp))
    return out, wall


def in_true_frame(est: Any, sim: tuple[float, np.ndarray, np.ndarray], centre: np.ndarray) -> Any:
    """``est`` moved into the true frame by the rotation and translation of the similarity
    ``X_true = s R X_est + t`` (about ``centre``, the working volume's centre in the true
    frame), its own scale kept.

    Parameters
    ----------
    est : Rig
    sim : (float, (3, 3), (3,))
        ``(s, R, t)`` of :func:`~inspector.kernels.calibration.compare_rigs`.
    centre : (3,) float, mm

    Returns
    -------
    Rig
        Each camera ``x_cam = R_c X_e + t_c`` rewritten for ``X_e = R^T (X_true - centre) + c_e``
        with ``c_e = R^T (centre - t) / s`` (the centre's place in the estimated frame).
    """
    from inspector.model import Camera, Rig

    s, Rs, ts = sim
    c_e = Rs.T @ (centre - ts) / s
    cams = []
    for c in est.cameras:
        R = np.asarray(c.R, float) @ Rs.T
        t = np.asarray(c.t, float) + np.asarray(c.R, float) @ (c_e - Rs.T @ centre)
        cams.append(Camera(c.name, c.width, c.height, c.K, c.dist, R, t))
    return Rig(tuple(cams))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/inspector-calibration-e2e"))
    ap.add_argument("--poses", type=int, default=30, help="poses of the calibration cube")
    ap.add_argument("--supersample", type=int, default=4, help="sub-samples per pixel side of the target's images")
    ap.add_argument("--target-seed", type=int, default=0)
    ap.add_argument("--rig-seed", type=int, default=24)
    ap.add_argument("--uniform", action="store_true", help="every camera the same lens (k1 = 0.1), nominal K")
    ap.add_argument("--parts", nargs="+", default=["cube30", "bracket"])
    ap.add_argument("--count", type=int, default=2, help="captures per part")
    ap.add_argument("--part-seed", type=int, default=300)
    ap.add_argument("--radius-mm", type=float, default=30.0, help="working volume (ball) radius for the bars, mm")
    ap.add_argument("--radius-mm-wide", type=float, default=45.0, help="a wider ball, reported too, mm")
    ap.add_argument("--json", type=Path, help="write every figure here")
    args = ap.parse_args(argv)

    from inspector.calibration.command import write_rig
    from inspector.capture_folder import read_rig
    from inspector.kernels.calibration import compare_rigs

    relax_watchdog()
    work = args.work
    work.mkdir(parents=True, exist_ok=True)
    out: dict[str, Any] = {"settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
                           "load_before": os.getloadavg()}
    truth = true_rig(args.rig_seed, args.uniform)
    rig_path = work / "true_rig.json"
    if not rig_path.is_file() or read_rig(rig_path).to_json() != truth.to_json():
        write_rig(truth, rig_path)
    truth = read_rig(rig_path)  # exactly what the simulator reads
    cap_dir, sim_wall = simulate_target(work, rig_path, args.poses, args.supersample, args.target_seed)
    out["simulate_target_wall_s"] = sim_wall

    # --- calibrate with the command line
    cal_path = work / "calibrated.json"
    load = os.getloadavg()
    proc, cal_wall = run_cmd([inspector_exe(), "calibrate", str(TARGET), "--captures", str(cap_dir), "--out",
                              str(cal_path), "--force", "--json"], "calibrate")
    report = json.loads(proc.stdout)
    stage_lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("calibrate:")]
    print("\n".join(stage_lines), flush=True)
    rejected = report["rejected"]
    out["calibrate"] = {"wall_s": round(cal_wall, 2), "load_1min": round(load[0], 2), "timings_s": report.get("timings_s"),
                        "rms_px": report["rms_px"], "poses": report["poses"], "corners": report["corners"],
                        "rejected_steep": sum(r["reason"] == "steep" for r in rejected),
                        "rejected_residual": sum(r["reason"] != "steep" for r in rejected),
                        "advice": report["advice"], "progress": stage_lines}
    est = read_rig(cal_path)

    # --- against the truth
    cmp = compare_rigs(list(est.cameras), list(truth.cameras), radius_mm=args.radius_mm)
    wide = compare_rigs(list(est.cameras), list(truth.cameras), radius_mm=args.radius_mm_wide)
    names = [c.name for c in truth.cameras]
    f_pct = 100.0 * np.abs(cmp["f_err"]).max(axis=1)
    cams = [{"camera": n, "rms_px": float(cmp["rms_px"][j]), "rms_px_wide": float(wide["rms_px"][j]),
             "max_px": float(cmp["max_px"][j]), "f_err_pct": float(f_pct[j]), "centre_err_mm": float(cmp["centre_err_mm"][j]),
             "pp_err_px": [float(v) for v in cmp["pp_err_px"][j]], "k1_true": float(truth.cameras[j].dist[0]),
             "k1_est": float(est.cameras[j].dist[0])} for j, n in enumerate(names)]
    out["cameras"] = cams
    out["scale_ppm"] = 1e6 * (cmp["scale"] - 1.0)
    geometry_ok = (max(c["rms_px"] for c in cams) <= BAR_RMS_PX and max(c["f_err_pct"] for c in cams) <= BAR_F_PCT
                   and max(c["centre_err_mm"] for c in cams) <= BAR_CENTRE_MM)

    # --- parts with the exact and the calibrated rig
    from inspector.kernels.calibration import nearest_point_to_lines

    centre = nearest_point_to_lines(np.array([c.centre for c in truth.cameras]), np.array([c.R[2] for c in truth.cameras]))
    calibrated = in_true_frame(est, cmp["similarity"], centre)
    write_rig(calibrated, work / "calibrated_true_frame.json")
    parts = []
    for part in args.parts:
        folders = simulate_parts(work / "parts", part, args.count, args.part_seed, truth)
        m = Measurer(folders, part, truth.footprint_mm(), all_or_none=True)
        exact, cal = m(truth, f"{part}, exact rig"), m(calibrated, f"{part}, calibrated rig")
        gap = None if exact["mean_px"] is None or cal["mean_px"] is None else cal["mean_px"] - exact["mean_px"]
        met = gap is not None and abs(gap) <= BAR_BCPS_PX and all(v == "pass" for v in cal["verdicts"])
        parts.append({"part": part, "exact": exact, "calibrated": cal, "gap_px": gap, "met": met})
    out["parts"] = parts
    ok = geometry_ok and all(p["met"] for p in parts)
    out["met"] = ok

    # --- the table
    c = out["calibrate"]
    lines = [f"Calibration end to end: 16 cameras 1024², {'k1 = 0.1 every camera' if args.uniform else 'a lens per camera (|k1| 0.08-0.12, k2, p1, p2, f +-1 %, centre +-8 px)'}; "
             f"{report['poses']} poses of charuco_cube.toml, supersample {args.supersample}, blur 0.7 px, noise sigma 2",
             f"calibrate: {c['wall_s']} s wall (load {c['load_1min']}), stages {c['timings_s']}; RMS {c['rms_px']} px over "
             f"{c['corners']} corners; rejected {c['rejected_steep']} steep board views (> 70 deg) and "
             f"{c['rejected_residual']} by residual; similarity scale {out['scale_ppm']:+.1f} ppm",
             "",
             f"| camera | reprojection RMS px (r {args.radius_mm:g} mm) | RMS px (r {args.radius_mm_wide:g} mm) | max px "
             "| focal error % | centre error mm | k1 true / est |",
             "|---|---|---|---|---|---|---|"]
    for r in cams:
        lines.append(f"| {r['camera']} | {r['rms_px']:.4f} | {r['rms_px_wide']:.4f} | {r['max_px']:.4f} | "
                     f"{r['f_err_pct']:.3f} | {r['centre_err_mm']:.3f} | {r['k1_true']:+.4f} / {r['k1_est']:+.4f} |")
    worst = {k: max(r[k] for r in cams) for k in ("rms_px", "rms_px_wide", "f_err_pct", "centre_err_mm")}
    lines.append(f"| **worst** | **{worst['rms_px']:.4f}** (bar {BAR_RMS_PX}) | {worst['rms_px_wide']:.4f} | | "
                 f"**{worst['f_err_pct']:.3f}** (bar {BAR_F_PCT}) | **{worst['centre_err_mm']:.3f}** (bar {BAR_CENTRE_MM}) | |")
    lines += ["", "| part | rig | BCPS mean px | BCPS p99 px | verdicts | calibrated - exact |", "|---|---|---|---|---|---|"]
    for p in parts:
        for which in ("exact", "calibrated"):
            q = p[which]
            v = q["verdicts"]
            mean = "-" if q["mean_px"] is None else f"{q['mean_px']:.4f}"
            p99 = "-" if q["p99_px"] is None else f"{q['p99_px']:.3f}"
            gap = "" if which == "exact" or p["gap_px"] is None else (
                f"{p['gap_px']:+.4f} px: **{'MET' if p['met'] else 'NOT MET'}** (bar {BAR_BCPS_PX})")
            lines.append(f"| {p['part']} ({len(v)} captures) | {which} | {mean} | {p99} | "
                         f"{sum(x == 'pass' for x in v)}/{len(v)} pass | {gap} |")
    lines += ["", f"geometry bars {'MET' if geometry_ok else 'NOT MET'}; overall {'MET' if ok else 'NOT MET'}"]
    text = "\n".join(lines)
    print()
    print(text)
    out["table"] = text
    if args.json:
        args.json.write_text(json.dumps(out, indent=1, default=float) + "\n")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
