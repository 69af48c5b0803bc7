"""What the two calibration acceptance scripts share (calibration_e2e.py: the whole
commissioning chain; calibration_refine.py: refinement from the parts' silhouettes): where
the ``inspector`` command is, good parts rendered with a rig, and the measurement of a rig by
the BCPS points of those parts against their true surfaces."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # siblings, when run as a script

import measure as ms

ROOT = Path(__file__).resolve().parents[2]


def inspector_exe() -> str:
    """The ``inspector`` command of this environment (else of the checkout's .venv, else PATH)."""
    for cand in (Path(sys.executable).parent / "inspector", ROOT / ".venv" / "bin" / "inspector"):
        if cand.exists():
            return str(cand)
    return "inspector"


def relax_watchdog() -> None:
    """Accuracy, not speed, is measured here: on a loaded machine a slow stage must not become
    an error by the watchdog's limits (the recipe's [budget], read when a recipe is loaded; the
    commands run as children inherit them)."""
    os.environ.setdefault("INSPECTOR_STAGE_LIMIT_S", "3600")
    os.environ.setdefault("INSPECTOR_INSPECTION_LIMIT_S", "7200")


def simulate_parts(folder: Path, part: str, count: int, seed: int, rig: Any = None) -> list[Path]:
    """``count`` good parts in ``folder`` rendered with ``rig`` (default: the simulator's own
    rig); a capture already there with the same rig is reused."""
    from inspector.capture_folder import read_rig, save_capture
    from inspector_drivers.sim.simulate import SimParams, sim_rig
    from inspector_drivers.sim.simulate import simulate as render

    p = SimParams(part=part, count=count, seed=seed)
    rig = rig if rig is not None else sim_rig(p)
    out = []
    for i in range(count):
        target = folder / f"{part}-s{seed + i:04d}"
        same = False
        if (target / "truth" / "part.ply").is_file() and (target / "rig.json").is_file():
            old = read_rig(target / "rig.json")
            same = all(np.allclose(a.K, b.K) and np.allclose(a.dist, b.dist) and np.allclose(a.R, b.R)
                       and np.allclose(a.t, b.t) for a, b in zip(old.cameras, rig.cameras))
        if not same:
            t = time.perf_counter()
            save_capture(render(p, i, rig), target, overwrite=True)
            print(f"simulated {target.name} ({time.perf_counter() - t:.1f} s)", flush=True)
        out.append(target)
    return out


class Measurer:
    """Inspect a part's captures with a rig (the shipped default recipe); the BCPS points
    against the true surfaces, in px of ``footprint_mm`` (the true rig's pixel at its centre).

    ``all_or_none``: the means are None unless every capture gave points (the end-to-end
    bars); else the mean of those that did."""

    def __init__(self, folders: list[Path], part: str, footprint_mm: float = 0.1, *, all_or_none: bool = False) -> None:
        import trimesh

        from inspector.manager import create_plugin_manager
        from inspector.recipe import load_recipe
        from inspector.reference import Reference
        from inspector.resources import recipe_path

        self.folders, self.fp, self.all_or_none = folders, footprint_mm, all_or_none
        self.pm = create_plugin_manager()
        self.recipe = load_recipe(recipe_path("default.toml"), self.pm, reference=f"builtin:{part}")
        self.ref = Reference.load(self.recipe.reference)
        self.truth = []
        for f in folders:
            m = trimesh.load(f / "truth" / "part.ply", force="mesh", process=False)
            self.truth.append((np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)))

    def __call__(self, rig: Any, label: str) -> dict[str, Any]:
        from inspector.calibration.refine import inspect_with_rig

        done = inspect_with_rig(self.folders, rig, self.recipe, self.ref, self.pm, label=f"inspect ({label})",
                                progress=lambda line: print(line, flush=True))
        rows = []
        for d, (V, F) in zip(done, self.truth):
            if d.points is None or not len(d.points):
                rows.append({"capture": d.name, "verdict": d.verdict, "mean_px": None, "p99_px": None})
                continue
            dist, _ = ms.distances_to_mesh(d.points, V, F)
            rows.append({"capture": d.name, "verdict": d.verdict, "mean_px": float(dist.mean() / self.fp),
                         "p99_px": float(np.percentile(dist, 99) / self.fp), "n": int(len(dist)),
                         "deviation_mean_px": d.bcps_signed_px})
        means = [r["mean_px"] for r in rows if r["mean_px"] is not None]
        p99 = [r["p99_px"] for r in rows if r["p99_px"] is not None]
        enough = len(means) == len(rows) if self.all_or_none else bool(means)
        return {"rows": rows, "mean_px": float(np.mean(means)) if enough else None,
                "p99_px": float(np.mean(p99)) if (len(p99) == len(rows) if self.all_or_none else bool(p99)) else None,
                "verdicts": [r["verdict"] for r in rows]}
