"""``inspector bench --characteristics``: what measuring 20 characteristics adds to one part.

Target (issue 28): the characteristics stage adds at most :data:`TARGET_MS` (50 ms) per
part for 20 characteristics. The figure compared with it is the median **process CPU
time** of :func:`inspector.characteristics.measure.measure`: on a shared machine other
jobs stretch the wall time, not this process's CPU time (both are reported, with the
1-minute load average at the start and at the end beside them).

The workload (that of the former standalone script, built here without importing the
tests):

- the reference: the built-in bracket (``Reference.from_mesh("builtin:bracket",
  make_part("bracket"))``; 17 features: 13 planes, 4 bores,
  :func:`inspector.kernels.features.find_features`), its closest-point index built before
  the timing (the stage builds it once per reference, not per part);
- the points: ``--characteristics-points`` (default 15000, what the bcps stage keeps of a
  16-camera capture) sampled with ``trimesh.sample.sample_surface`` (fixed seed) on the
  "true part", with 3 um of normal noise along the face normals. The true part is the
  bracket's construction (:func:`true_bracket`: the same boxes and holes as
  :mod:`inspector.parts`, but 512-section holes, chord error 0.1 um, united and cut with
  manifold3d) scaled by :data:`SCALE` (1.002) about its bounding-box centre: the same
  part the tests of the characteristics use;
- :data:`CHARACTERISTICS`: 20 of the mix a drawing has: 4 diameters, 2 radii,
  6 distances, 2 angles, 3 positions, flatness, roundness, cylindricity.

``measure()`` runs once as a warm-up (imports, HiGHS, the compiled cylinder fit), then
``--characteristics-runs`` times (default 20), each timed with ``time.perf_counter`` and
``time.process_time``. No timed assertion anywhere: the figures are read, not tested.

The surface points have no contour rays, so they never reach the snap of the points near
sharp edges onto the edges their rays show (:mod:`inspector.characteristics.edges`). A
second workload does: the same 20 characteristics measured, as the stage measures them, on
the BCPS points of a simulated capture of the same true part (``--characteristics-cameras``
cameras, default 16, of 1024 x 1024 at 0.1 mm/px; 0 leaves it out), with their cameras as
groups and the cameras' centres as the rays' origins. The target holds for both.
Exit 0 target met, 1 not met.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from inspector.characteristics.definitions import features_and_edges
from inspector.characteristics.edges import snap_to_edges
from inspector.characteristics.measure import Characteristic, measure
from inspector.errors import InspectorError, RecipeError
from inspector.kernels.bcps import confidence
from inspector.kernels.features import Feature, find_features
from inspector.parts import make_part
from inspector.reference import Reference
from inspector.resources import recipes_dir
from inspector.runner import run_batch
from inspector.session import Session
from inspector_tools.bench.common import loadavg, machine, simulate_capture, write_figures
from inspector_tools.bench.cycles import acquisition

__all__ = ["TARGET_MS", "SCALE", "CHARACTERISTICS", "true_bracket", "workload", "capture_workload",
           "bench_characteristics", "print_characteristics", "run_characteristics_bench"]

#: Median process CPU time of ``measure()`` for the 20 characteristics, ms (issue 28).
TARGET_MS = 50.0

#: Scale of the true part against the reference (a part 0.2 % large: every size deviates).
SCALE = 1.002

#: Normal noise added to the sampled points along the surface normal, mm.
NOISE_MM = 0.003

#: Twenty characteristics of the bracket: 4 diameters, 2 radii, 6 distances, 2 angles,
#: 3 positions, flatness, roundness, cylindricity.
CHARACTERISTICS: list[Characteristic] = [
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

_VERDICTS = ("ok", "nok", "not_measurable")


def true_bracket(scale: float = SCALE, sections: int = 512) -> trimesh.Trimesh:
    """The built-in bracket's construction with finely sectioned holes, scaled about its centre.

    Parameters
    ----------
    scale : float
        Uniform scale about the bounding-box centre (1.0: the nominal part).
    sections : int
        Sections of each hole's cylinder (512: chord error 0.1 um for the Ø8 holes).

    Returns
    -------
    trimesh.Trimesh
        The "true part" whose surface the benchmark's points sample, centred on its
        bounding-box centre as the built-in reference is.
    """
    def box(ext: tuple[float, float, float], c: tuple[float, float, float]) -> trimesh.Trimesh:
        b = trimesh.creation.box(extents=ext)
        b.apply_translation(c)
        return b

    def cyl(r: float, p0: tuple[float, float, float], p1: tuple[float, float, float]) -> trimesh.Trimesh:
        return trimesh.creation.cylinder(radius=r, segment=np.array([p0, p1], float), sections=sections)

    body = trimesh.boolean.union([box((60, 40, 6), (30, 20, 3)), box((60, 6, 40), (30, 3, 20))], engine="manifold")
    cut = [cyl(3.0, (10, 28, -1), (10, 28, 7)), cyl(3.0, (50, 28, -1), (50, 28, 7)),
           cyl(4.0, (15, -1, 28), (15, 7, 28)), cyl(4.0, (45, -1, 28), (45, 7, 28)), box((20, 12, 4), (30, 26, 5))]
    m = trimesh.boolean.difference([body, *cut], engine="manifold")
    m.apply_translation(-m.bounds.mean(axis=0))
    m.apply_scale(scale)
    return m


def workload(n_points: int, seed: int = 3) -> tuple[Reference, list[Feature], np.ndarray]:
    """The bracket reference, its features and ``n_points`` noisy points of the true part.

    Parameters
    ----------
    n_points : int
        Points sampled on :func:`true_bracket` (area-weighted, ``seed + 1``).
    seed : int
        Seed of the noise (``numpy.random.default_rng(seed)``).

    Returns
    -------
    reference : Reference
        ``builtin:bracket``, its closest-point index already built.
    features : list of Feature
        Its features (:func:`~inspector.kernels.features.find_features`).
    points : (n_points, 3) float
        The sampled points with :data:`NOISE_MM` of normal noise along the face normals, mm,
        in the reference frame.
    """
    ref = Reference.from_mesh("builtin:bracket", make_part("bracket"))
    feats = find_features(ref.vertices, ref.faces)
    true = true_bracket(SCALE)
    rng = np.random.default_rng(seed)
    P, fid = trimesh.sample.sample_surface(true, n_points, seed=seed + 1)
    P = P + (NOISE_MM * rng.standard_normal(len(P)))[:, None] * true.face_normals[fid]
    ref.distance.closest(P[:10])  # the closest-point index: built once per reference, not per part
    return ref, feats, np.asarray(P, dtype=float)


def capture_workload(folder: Path, cameras: int = 16, seed: int = 3) -> dict[str, Any]:
    """What the characteristics stage gets from a simulated capture of the bracket.

    Parameters
    ----------
    folder : Path
        A work folder (the capture and the inspection's results are written there).
    cameras : int
        Cameras of the simulated rig (1024 x 1024 at 0.1 mm/px).
    seed : int
        The simulation's seed (pose and noise).

    Returns
    -------
    dict
        ``reference``, ``features``, ``points`` (N, 3, reference frame), ``weights`` (N,: the
        bcps per-point confidence), ``groups`` (N,),
        ``origins`` (N, 3: each point's camera centre, reference frame) and ``edges``, the
        arguments :func:`~inspector.characteristics.measure.measure` gets from the stage.
    """
    cap = simulate_capture(folder / "bracket", {"part": "bracket", "scale": SCALE, "seed": seed, "cameras": cameras})
    session = Session.open(recipes_dir() / "default.toml", folder, reference="builtin:bracket")
    res = next(run_batch(session.recipe, [acquisition(cap)], session.pm, reference=session.reference,
                         outdir=folder / "out")).result
    if res.bcps is None or res.pose is None or res.rig is None:
        raise InspectorError(f"bench --characteristics: the simulated capture was not inspected: {res.error}")
    ref = session.reference
    assert ref is not None  # Session.open with a reference
    cam = np.asarray(res.bcps.camera, np.int64)
    centres = np.stack([c.centre for c in res.rig])
    feats, edges = features_and_edges(ref.vertices, ref.faces)
    return {"reference": ref, "features": feats,
            "points": ref.to_reference_frame(res.bcps.points, res.pose), "groups": cam,
            "weights": confidence(res.bcps.segment_mm, res.rig.footprint_mm()),
            "origins": ref.to_reference_frame(centres, res.pose)[cam], "edges": edges}


def _timed(call: Callable[[], Any], runs: int) -> tuple[Any, float, list[float], list[float]]:
    """One warm-up call, then ``runs`` timed ones: (last result, warm-up wall ms, wall ms, CPU ms)."""
    t0 = time.perf_counter()
    res = call()
    warmup_ms = 1e3 * (time.perf_counter() - t0)
    wall, cpu = [], []
    for _ in range(runs):
        t0, c0 = time.perf_counter(), time.process_time()
        res = call()
        wall.append(1e3 * (time.perf_counter() - t0))
        cpu.append(1e3 * (time.process_time() - c0))
    return res, warmup_ms, wall, cpu


def _stats(values: list[float]) -> dict[str, float]:
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def bench_characteristics(n_points: int = 15000, runs: int = 20, *, seed: int = 3, cameras: int = 16,
                          work: Path | None = None, progress: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    """Time :func:`~inspector.characteristics.measure.measure` of :data:`CHARACTERISTICS`.

    Parameters
    ----------
    n_points : int
        Points of the part (see :func:`workload`).
    runs : int
        Timed runs after one warm-up run.
    seed : int
        Seed of the points (see :func:`workload`) and of the simulated capture.
    cameras : int
        Cameras of the simulated capture (see :func:`capture_workload`); 0: no capture.
    work : Path, optional
        Work folder of the capture (default: a temporary one, removed after).
    progress : callable
        Called with one line before each step.

    Returns
    -------
    dict
        ``points``, ``characteristics`` (counts), ``runs``, ``wall_ms`` and ``cpu_ms``
        (``median``, ``min``, ``max`` over the timed runs), ``warmup_ms`` (wall),
        ``target_ms`` (:data:`TARGET_MS`), ``met`` (CPU median <= target, for both
        workloads), ``load`` (``start``, ``end``: the 1-minute load average), ``verdicts``
        (counts of ``ok``, ``nok``, ``not_measurable`` in the last run); ``capture`` (None
        without one): the same figures (``cameras``, ``points``, ``moved``: the points moved
        onto edges, ``wall_ms``, ``cpu_ms``, ``warmup_ms``, ``met``, ``verdicts``) on the
        simulated capture's points.
    """
    if n_points < 100:
        raise RecipeError("bench --characteristics-points: expected a number >= 100")
    if runs < 1:
        raise RecipeError("bench --characteristics-runs: expected a number >= 1")
    if cameras != 0 and not 3 <= cameras <= 64:
        raise RecipeError("bench --characteristics-cameras: expected 0 or a number in 3..64")
    load_start = loadavg()
    progress(f"Characteristics: the bracket reference, its features and {n_points} points of the true part ...")
    ref, feats, P = workload(n_points, seed)
    progress(f"Timing measure() of {len(CHARACTERISTICS)} characteristics: 1 warm-up + {runs} runs ...")
    # The stage groups the points by the camera whose contour gave them (the per-camera
    # uncertainty: design effect, plane jackknife); these points have no camera, so 16 labels
    # by azimuth about the part's centre stand in for them, for the same work.
    d = P - P.mean(0)
    cams = (np.floor((np.arctan2(d[:, 1], d[:, 0]) + np.pi) / (2 * np.pi) * 16).astype(int)) % 16
    res, warmup_ms, wall, cpu = _timed(lambda: measure(CHARACTERISTICS, feats, P, None, ref, groups=cams), runs)
    cpu_ms = _stats(cpu)
    capture = None
    if cameras:
        with tempfile.TemporaryDirectory(prefix="inspector-bench-chars-") as tmp:
            progress(f"Simulating a {cameras}-camera capture of the bracket and inspecting it ...")
            got = capture_workload(Path(work or tmp), cameras, seed)
        progress(f"Timing measure() on its {len(got['points'])} BCPS points: 1 warm-up + {runs} runs ...")
        moved = _moved(got)
        res_c, warm_c, wall_c, cpu_c = _timed(lambda: measure(
            CHARACTERISTICS, got["features"], got["points"], got["weights"], got["reference"], groups=got["groups"],
            origins=got["origins"], edges=got["edges"]), runs)
        capture = {"cameras": cameras, "points": int(len(got["points"])), "moved": moved, "wall_ms": _stats(wall_c),
                   "cpu_ms": _stats(cpu_c), "warmup_ms": warm_c, "met": _stats(cpu_c)["median"] <= TARGET_MS,
                   "verdicts": {v: sum(r.verdict == v for r in res_c) for v in _VERDICTS}}
    return {
        "points": int(len(P)),
        "characteristics": len(CHARACTERISTICS),
        "runs": runs,
        "wall_ms": _stats(wall),
        "cpu_ms": cpu_ms,
        "warmup_ms": warmup_ms,
        "target_ms": TARGET_MS,
        "met": cpu_ms["median"] <= TARGET_MS and (capture is None or capture["met"]),
        "load": {"start": load_start, "end": loadavg()},
        "verdicts": {v: sum(r.verdict == v for r in res) for v in _VERDICTS},
        "capture": capture,
    }


def _moved(got: dict[str, Any]) -> int:
    """How many of the capture's points the stage moves onto edges (for the report)."""
    return int(len(snap_to_edges(got["points"], got["origins"], got["edges"], 0.5, groups=got["groups"]).index))


def _print_times(d: dict[str, Any], load: str) -> None:
    """The verdicts and the CPU and wall times of one workload's figures ``d``."""
    v = d["verdicts"]
    print(f"    verdicts: {v['ok']} ok, {v['nok']} nok, {v['not_measurable']} not measurable")
    for key, label in (("cpu_ms", "CPU ms "), ("wall_ms", "wall ms")):
        s = d[key]
        print(f"    {label}: median {s['median']:7.1f}  min {s['min']:7.1f}  max {s['max']:7.1f}   ({load})")


def print_characteristics(doc: dict[str, Any]) -> None:
    """Print the figures of :func:`bench_characteristics` (``doc``, with ``machine``)."""
    ld, cpus = doc["load"], (doc.get("machine") or {}).get("usable_cpus")
    load = (f"load {ld['start']} -> {ld['end']}" if ld["start"] is not None else "load n/a") + (
        f" on {cpus} CPUs" if cpus else "")
    print(f"\n  characteristics: measure() of {doc['characteristics']} characteristics of the bracket, "
          f"{doc['points']} points, {doc['runs']} runs after a warm-up ({doc['warmup_ms']:.0f} ms)")
    _print_times(doc, load)
    c = doc.get("capture")
    if c:
        print(f"\n  on the BCPS points of a simulated {c['cameras']}-camera capture of the bracket: {c['points']} points, "
              f"{c['moved']} moved onto edges")
        _print_times(c, load)
    worst = max(doc["cpu_ms"]["median"], c["cpu_ms"]["median"] if c else 0.0)
    print(f"    target: CPU median <= {doc['target_ms']:g} ms (issue 28; CPU time is the figure to read on a shared "
          f"machine): {'MET' if doc['met'] else 'NOT MET'} ({worst:.1f} ms, the slower workload; {load})")


def run_characteristics_bench(args: argparse.Namespace) -> int:
    """``inspector bench --characteristics``; see the module docstring. Exit 0 target met, 1 not met."""
    say = (lambda s: None) if args.quiet else (lambda s: print(s, flush=True))
    figures_machine = machine()
    doc = bench_characteristics(int(args.characteristics_points), int(args.characteristics_runs),
                                cameras=int(args.characteristics_cameras), progress=say)
    doc["machine"] = figures_machine
    if not args.quiet:
        print_characteristics(doc)
    if args.json:
        say(f"\n  figures written to {write_figures(args.json, doc)}")
    return 0 if doc["met"] else 1
