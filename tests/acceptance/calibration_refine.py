"""Acceptance of ``inspector calibrate --refine`` (issue 24, "Refinement"): a perturbed rig,
refined from captures of good parts, inspects *other* captures as well as the exact rig.

For each case (every camera turned by a random rotation of ``--sigma-px`` RMS; one camera
turned by ``--knock-px``):

1. simulate good parts (the default 16-camera rig, 1024², 0.1 mm/px): ``--refine-count``
   captures to refine from (seed ``--refine-seed``) and ``--eval-count`` other captures
   (seed ``--eval-seed``); folders kept in ``--work`` and reused when there;
2. write the perturbed rig and refine it with the real command line
   (``inspector calibrate --refine PERTURBED --captures REFINE --reference builtin:PART
   --out REFINED --json``), timed;
3. inspect the other captures with (a) the exact rig, (b) the perturbed rig and (c) the
   refined rig (the shipped ``default.toml``), and measure their BCPS points against the
   true surface (``truth/part.ply``, exact point-to-triangle distances of
   :func:`measure.distances_to_mesh`), mean and p99 in px.

Perturbations (seeded by ``--perturb-seed``): a camera turned about its optical centre by a
world rotation vector. "Random σ px": each component drawn from N(0, (σ/f)²/2), which moves
the image centre by σ px RMS over the cameras. "Knock κ px": camera ``--knock-camera`` turned
about a random axis in its image plane by κ/f (its image moves by κ px), every other camera
exact.

Bars: the refined rig's BCPS mean on the other captures within 0.01 px of the exact rig's,
and every (good) part passes with it. Exit 0 when met, 1 when not.

Usage::

    .venv/bin/python tests/acceptance/calibration_refine.py --work /tmp/refine-acceptance
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # siblings, when run as a script

from calibration_common import Measurer, inspector_exe, relax_watchdog, simulate_parts

TOLERANCE_PX = 0.01


def perturbed(rig: Any, rng: np.random.Generator, sigma_px: float = 0.0, knock: int | None = None,
              knock_px: float = 0.0) -> Any:
    """``rig`` with its cameras turned (see the module docstring)."""
    from inspector.kernels.silhouette_fit import turn_camera
    from inspector.model import Camera, Rig

    cams = []
    for i, c in enumerate(rig.cameras):
        f = float(np.sqrt(c.K[0, 0] * c.K[1, 1]))
        if knock is None:
            theta = rng.normal(size=3) * sigma_px / f / np.sqrt(2.0)
        elif i == knock:
            a = rng.normal(size=2)
            a /= np.linalg.norm(a)
            theta = c.R.T @ np.array([a[0], a[1], 0.0]) * knock_px / f
        else:
            theta = np.zeros(3)
        R, t = turn_camera(c.R, c.t, theta, np.zeros(3))
        cams.append(Camera(c.name, c.width, c.height, c.K, c.dist, R, t))
    return Rig(tuple(cams))


def reprojection_px(rig: Any, exact: Any, half_mm: float = 20.0) -> np.ndarray:
    """Per camera, the RMS (px) between where ``rig`` and ``exact`` project points of the
    working volume (a cube of ``half_mm`` about the origin)."""
    P = np.random.default_rng(0).uniform(-half_mm, half_mm, size=(4000, 3))
    return np.array([float(np.sqrt(np.mean(np.sum((a.project(P)[0] - b.project(P)[0]) ** 2, axis=1))))
                     for a, b in zip(rig.cameras, exact.cameras)])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/inspector-refine-acceptance"))
    ap.add_argument("--part", default="cube30")
    ap.add_argument("--refine-count", type=int, default=5)
    ap.add_argument("--eval-count", type=int, default=4)
    ap.add_argument("--refine-seed", type=int, default=100)
    ap.add_argument("--eval-seed", type=int, default=200)
    ap.add_argument("--sigma-px", type=float, default=0.3)
    ap.add_argument("--knock-px", type=float, default=2.0)
    ap.add_argument("--knock-camera", type=int, default=5)
    ap.add_argument("--perturb-seed", type=int, default=7)
    ap.add_argument("--intrinsics", action="store_true", help="refine focal lengths and principal points too")
    ap.add_argument("--json", type=Path, help="write every figure here")
    args = ap.parse_args(argv)

    from inspector.calibration.command import write_rig
    from inspector_drivers.sim.simulate import SimParams, sim_rig

    relax_watchdog()
    work = args.work
    work.mkdir(parents=True, exist_ok=True)
    refine_dir, eval_dir = work / "refine", work / "eval"
    simulate_parts(refine_dir, args.part, args.refine_count, args.refine_seed)
    eval_folders = simulate_parts(eval_dir, args.part, args.eval_count, args.eval_seed)
    exact = sim_rig(SimParams(part=args.part))
    rng = np.random.default_rng(args.perturb_seed)
    cases = [
        (f"every camera turned, {args.sigma_px:g} px RMS", "random", perturbed(exact, rng, sigma_px=args.sigma_px)),
        (f"cam{args.knock_camera:02d} turned by {args.knock_px:g} px", "knock",
         perturbed(exact, rng, knock=args.knock_camera, knock_px=args.knock_px)),
    ]
    measure = Measurer(eval_folders, args.part)
    out: dict[str, Any] = {"exact": measure(exact, "exact rig"), "cases": []}
    for title, key, rig in cases:
        folder = work / key
        folder.mkdir(exist_ok=True)
        bad = write_rig(rig, folder / "perturbed.json")
        refined_path = folder / "refined.json"
        cmd = [inspector_exe(), "calibrate", "--refine", str(bad), "--captures", str(refine_dir), "--reference",
               f"builtin:{args.part}", "--out", str(refined_path), "--force", "--json"]
        if args.intrinsics:
            cmd.append("--intrinsics")
        print(f"refine ({title}): {' '.join(cmd)}", flush=True)
        t = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t
        if proc.returncode != 0:
            print(proc.stdout[-2000:], proc.stderr[-2000:], file=sys.stderr)
            return 2
        report = json.loads(proc.stdout)
        from inspector.capture_folder import read_rig

        refined = read_rig(refined_path)
        case = {"title": title, "wall_s": round(wall, 1), "refinement": {k: report[k] for k in (
            "iterations", "converged", "seconds_inspect", "seconds_refine", "median_before_px", "median_after_px",
            "gauge_cameras")},
            "reprojection_px": {"perturbed": reprojection_px(rig, exact).tolist(),
                                "refined": reprojection_px(refined, exact).tolist()},
            "perturbed": measure(rig, f"{key}, perturbed rig"), "refined": measure(refined, f"{key}, refined rig")}
        out["cases"].append(case)

    ex = out["exact"]
    lines = [f"Refinement from {args.refine_count} captures of good {args.part} (seeds {args.refine_seed}..), "
             f"BCPS to the true surface on {args.eval_count} other captures (seeds {args.eval_seed}..), "
             "16 cameras, 1024², 0.1 mm/px, default recipe",
             "",
             "| case | rig | BCPS mean px | BCPS p99 px | verdicts | worst camera reprojection px |",
             "|---|---|---|---|---|---|",
             f"| - | exact | {ex['mean_px']:.4f} | {ex['p99_px']:.3f} | {_verdicts(ex)} | 0 |"]
    ok = True
    for c in out["cases"]:
        for which in ("perturbed", "refined"):
            m = c[which]
            worst = max(c["reprojection_px"][which])
            lines.append(f"| {c['title']} | {which} | {m['mean_px']:.4f} | {m['p99_px']:.3f} | {_verdicts(m)} "
                         f"| {worst:.3f} |")
        gap = c["refined"]["mean_px"] - ex["mean_px"]
        passed = all(v == "pass" for v in c["refined"]["verdicts"])
        good = abs(gap) <= TOLERANCE_PX and passed
        ok &= good
        r = c["refinement"]
        c["verdict"] = {"gap_px": gap, "all_pass": passed, "met": good}
        lines.append(f"|   | refined − exact: {gap:+.4f} px ({'within' if abs(gap) <= TOLERANCE_PX else 'beyond'} "
                     f"{TOLERANCE_PX} px), good parts {'all pass' if passed else 'NOT all pass'}: "
                     f"**{'MET' if good else 'NOT MET'}**; refinement {r['iterations']} iterations, "
                     f"{r['seconds_inspect']} s inspecting + {r['seconds_refine']} s refining "
                     f"(wall {c['wall_s']} s); median residual {r['median_before_px']} -> {r['median_after_px']} px | | | | |")
    text = "\n".join(lines)
    print()
    print(text)
    if args.json:
        args.json.write_text(json.dumps(out, indent=1) + "\n")
    return 0 if ok else 1


def _verdicts(m: dict[str, Any]) -> str:
    v = m["verdicts"]
    return f"{sum(x == 'pass' for x in v)}/{len(v)} pass"


if __name__ == "__main__":
    sys.exit(main())
