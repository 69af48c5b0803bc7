"""Benchmark: what measuring 20 characteristics adds to one part (issue 28: <= 50 ms).

The built-in bracket (17 features: 13 planes, 4 bores), points sampled on its construction
scaled by 1.002 (the "true part", 512-section holes) with 3 um of normal noise, in the number
a 16-camera capture gives (``--points``; the bcps stage keeps 10-15 thousand), and 20
characteristics of the mix a drawing has: diameters, radii, distances, angles, positions
and one of each form. The reference's features and its closest-point index are built
before the timing (the stage builds them once per reference).

Prints the median and the spread of the wall time and of the process CPU time over
``--repeat`` runs (the CPU time is the figure to read on a shared machine). Not a test: no
timed assertion anywhere.

CLI::

    python tests/acceptance/characteristics_bench.py [--points 15000] [--repeat 20] [--profile]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))

from test_characteristics import _true_bracket

from inspector.characteristics.measure import Characteristic, measure
from inspector.kernels.features import find_features
from inspector.parts import make_part
from inspector.reference import Reference

SCALE = 1.002

#: Twenty characteristics of the bracket: 4 diameters, 2 radii, 6 distances, 2 angles,
#: 3 positions, flatness, roundness, cylindricity.
CHARS = [
    *[Characteristic(f"D{i}", "diameter", (f,), -0.05, 0.05) for i, f in enumerate(("F14", "F15", "F16", "F17"), 1)],
    Characteristic("R1", "radius", ("F16",), -0.05, 0.05),
    Characteristic("R2", "radius", ("F14",), -0.05, 0.05),
    Characteristic("L1", "distance", ("F01", "F04"), -0.05, 0.05),
    Characteristic("L2", "distance", ("F02", "F03"), -0.05, 0.05),
    Characteristic("L3", "distance", ("F09", "F01"), -0.05, 0.05),
    Characteristic("L4", "distance", ("F14", "F15"), -0.1, 0.1),
    Characteristic("L5", "distance", ("F16", "F17"), -0.1, 0.1),
    Characteristic("L6", "distance", ("F05", "F06"), -0.1, 0.1),
    Characteristic("A1", "angle", ("F01", "F02"), -0.1, 0.1),
    Characteristic("A2", "angle", ("F04", "F03"), -0.1, 0.1),
    Characteristic("P1", "position", ("F14",), 0.0, 0.1),
    Characteristic("P2", "position", ("F15",), 0.0, 0.1),
    Characteristic("P3", "position", ("F16",), 0.0, 0.1),
    Characteristic("FL", "flatness", ("F01",), 0.0, 0.05),
    Characteristic("RO", "roundness", ("F17",), 0.0, 0.05),
    Characteristic("CY", "cylindricity", ("F14",), 0.0, 0.05),
]


def setup(n_points: int, seed: int = 3) -> tuple[Reference, list, np.ndarray]:
    """The bracket reference, its features (index built) and ``n_points`` noisy points."""
    ref = Reference.from_mesh("builtin:bracket", make_part("bracket"))
    feats = find_features(ref.vertices, ref.faces)
    true = _true_bracket(SCALE)
    rng = np.random.default_rng(seed)
    P, fid = trimesh.sample.sample_surface(true, n_points, seed=seed + 1)
    P = P + (0.003 * rng.standard_normal(len(P)))[:, None] * true.face_normals[fid]
    ref.distance.closest(P[:10])  # the closest-point index: built once per reference, not per part
    return ref, feats, P


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=15000)
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--profile", action="store_true", help="print a cProfile of one run")
    args = ap.parse_args(argv)
    ref, feats, P = setup(args.points)
    res = measure(CHARS, feats, P, None, ref)  # warm-up (imports, SciPy's HiGHS)
    wall, cpu = [], []
    for _ in range(args.repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        res = measure(CHARS, feats, P, None, ref)
        wall.append(1e3 * (time.perf_counter() - t0))
        cpu.append(1e3 * (time.process_time() - c0))
    verdicts = {v: sum(r.verdict == v for r in res) for v in ("ok", "nok", "not_measurable")}
    print(f"measure(): {len(CHARS)} characteristics, {len(P)} points, {args.repeat} runs; verdicts {verdicts}")
    for what, t in (("wall", wall), ("cpu", cpu)):
        print(f"  {what:4s} ms: median {statistics.median(t):.1f}  min {min(t):.1f}  max {max(t):.1f}")
    if args.profile:
        import cProfile
        import pstats

        prof = cProfile.Profile()
        prof.runcall(measure, CHARS, feats, P, None, ref)
        pstats.Stats(prof).sort_stats("cumulative").print_stats(25)
    return 0


if __name__ == "__main__":
    sys.exit(main())
