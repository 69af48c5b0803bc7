"""``inspector bench``: the issue's performance targets, measured in one command.

Targets (16 cameras, the 2-core production machine; :func:`cycle_target_s`):

1. cycle: a full inspection in the batch runner (read the capture folder, every stage of
   the recipe, write the outputs), median, interpreter start excluded: **<= 0.5 s** for
   images up to 1024x1024 (1 MP), **<= 1.0 s** up to 2448x2048 (5 MP; issue 26); other
   camera counts: the target scaled with the count (the cost must be linear in it);
2. memory: peak resident memory of the process **<= 1.5 GB** (1.5e9 bytes) up to 1 MP,
   **<= 2.5 GB** up to 5 MP;
3. carving: :func:`inspector.kernels.carving.carve` at 0.1 mm at least **10x faster**
   than Open3D's ``VoxelGrid.carve_silhouette`` at 0.25 mm on the same masks.

How it is measured
------------------
- A capture is simulated (``--part``, ``--seed``, ``--cameras``, ``--size`` ``N`` or
  ``WxH`` (non-square, e.g. ``2448x2048``), ``--mm-per-px``) in a child process, so its rendering never counts in this process's
  peak memory, and written to a temporary capture folder without ``truth/`` (a production
  capture has none). ``--capture DIR`` uses an existing folder instead (its ``truth/``, if
  any, is dropped after reading, so truth statistics never count in the cycle).
- The batch path of ``inspector run`` (:func:`inspector.runner.run_batch`) inspects that
  folder ``1 + --runs`` times in this process, writing the outputs to a temporary folder;
  the first run (Numba compilation, lazy imports, caches) is left out of the statistics.
  Per run: ``load`` and each stage (``result.timings_s``), ``outputs`` (writing the result
  folder and the ``on_result`` hook: the rest of the run) and ``cycle`` (the whole run),
  with the machine's 1-minute load average before and after it (``loadavg``): on a
  shared machine other jobs' load stands beside every figure.
- Memory: ``resource.getrusage(RUSAGE_SELF).ru_maxrss`` after the runs (the process's
  high-water mark, imports included), and its increase over the warm-up and timed runs.
- Carving comparison, after the memory figure is taken: the capture's images are
  segmented with :func:`inspector_plugins.segment.segment_image` (the recipe's segment
  parameters); both carvers get the same masks and the same box
  (:func:`~inspector.kernels.carving.default_bounds`). Ours: ``carve(...)`` at
  ``--carve-voxel``, median of ``--carve-runs``. Open3D: ``VoxelGrid.create_dense`` over
  the box at ``--open3d-voxel`` then ``carve_silhouette`` per camera (float32 mask images,
  ``keep_voxels_outside_image=False``), once. The ratio (the target) uses Open3D's
  ``carve_silhouette`` calls only (not ``create_dense``) against the whole ``carve`` call
  (distance transforms, cell tests, surface points with normals and display mesh; the
  box is given): the conservative ratio, since Open3D only produces an occupancy grid. An
  informative ratio without our display mesh (Open3D against our cells and surface
  points, the median of ``time_s["carve"] + time_s["points"]``) is reported beside it;
  our cell tests alone are not timed apart (the finest level is tested together with
  the surface points). A grid that would need more than ``--open3d-max-gb`` (about 100
  bytes per voxel) is refused with a message. As a sanity check, the fraction of our
  surface points that fall in a voxel Open3D kept is reported (about 1 when both use the
  cameras alike).

Exit status: 0 every measured target met, 1 a target not met, 3 an inspection failed.
Importing this module is cheap: numpy, Open3D and the pipeline are imported when used.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from inspector import hookimpl

if TYPE_CHECKING:
    from inspector.manager import PluginManager
    from inspector.recipe import Recipe
    from inspector.reference import Reference
    from inspector.registry import CommandRegistry

__all__ = [
    "CYCLE_TARGET_S",
    "MEMORY_TARGET_MB",
    "CARVE_RATIO_TARGET",
    "CYCLE_TARGET_5MP_S",
    "MEMORY_TARGET_5MP_MB",
    "cycle_target_s",
    "memory_target_mb",
    "parse_size",
    "image_size",
    "O3D_BYTES_PER_VOXEL",
    "add_parser",
    "run",
    "bench_cycles",
    "compare_carving",
]

#: Median cycle target, seconds: 16 cameras of 1 MP (issue 26).
CYCLE_TARGET_S = 0.5
#: Peak memory target, MB (1.5 GB = 1.5e9 bytes): 16 cameras of 1 MP.
MEMORY_TARGET_MB = 1500.0
#: Issue 26, 16 cameras of 5 MP (2448 x 2048): median cycle, s, and peak memory, MB.
CYCLE_TARGET_5MP_S = 1.0
MEMORY_TARGET_5MP_MB = 2500.0
#: Pixels of the largest image each pair of targets is for.
ONE_MP = 1024 * 1024
FIVE_MP = 2448 * 2048
#: The camera count the targets are for (others: the cycle target scaled with the count).
TARGET_CAMERAS = 16
#: Open3D (``--open3d-voxel``) carving time over ours (``--carve-voxel``).
CARVE_RATIO_TARGET = 10.0
#: Issue 15: a new process (kernels cached) reaches its first verdict within this, s.
COLD_START_TARGET_S = 3.0
#: Issue 15: the kernels' first compile (an empty Numba cache; ``make setup`` does it once,
#: with a progress line per kernel), s.
FIRST_RUN_TARGET_S = 60.0
#: Memory of one voxel of an Open3D ``VoxelGrid`` (hash map node: index, colour, key;
#: measured about 92 bytes with Open3D 0.20), bytes.
O3D_BYTES_PER_VOXEL = 100

_MB = 1e6


# --------------------------------------------------------------------------- helpers


def cycle_target_s(width: int, height: int, cameras: int = TARGET_CAMERAS) -> float | None:
    """The median cycle target (s) for ``cameras`` images of ``width`` x ``height`` px:
    :data:`CYCLE_TARGET_S` up to 1 MP, :data:`CYCLE_TARGET_5MP_S` up to 5 MP (None beyond:
    no target), times ``cameras / 16`` (cost linear in the camera count)."""
    px = width * height
    base = CYCLE_TARGET_S if px <= ONE_MP else CYCLE_TARGET_5MP_S if px <= FIVE_MP else None
    return None if base is None else base * cameras / TARGET_CAMERAS


def memory_target_mb(width: int, height: int) -> float | None:
    """The peak memory target (MB) for images of ``width`` x ``height`` px (None beyond 5 MP)."""
    px = width * height
    return MEMORY_TARGET_MB if px <= ONE_MP else MEMORY_TARGET_5MP_MB if px <= FIVE_MP else None


def parse_size(text: str) -> tuple[int, int]:
    """``"N"`` or ``"WxH"`` (``x`` or ``X``) -> ``(width, height)`` px; ValueError otherwise."""
    parts = str(text).lower().split("x")
    if len(parts) not in (1, 2) or not all(p.strip().isdigit() for p in parts):
        raise ValueError(f"expected N or WxH in pixels (e.g. 1024 or 2448x2048), got {text!r}")
    w = int(parts[0])
    return w, (int(parts[1]) if len(parts) == 2 else w)


class _SizeAction(argparse.Action):
    """``--size N|WxH``: ``args.size`` the width (an int, as before), ``args.height`` the height."""

    def __call__(self, parser: Any, namespace: argparse.Namespace, values: Any, option_string: str | None = None) -> None:
        try:
            w, h = parse_size(values)
        except ValueError as e:
            parser.error(f"{option_string}: {e}")
        namespace.size, namespace.height = w, h


def image_size(args: argparse.Namespace) -> tuple[int, int]:
    """``(width, height)`` of the simulated images from ``--size``."""
    h = getattr(args, "height", None)
    return int(args.size), int(h if h is not None else args.size)


def _loadavg() -> float | None:
    """The 1-minute load average (None where the platform has none)."""
    try:
        return round(os.getloadavg()[0], 2)
    except (OSError, AttributeError):  # pragma: no cover
        return None


def _recipes_dir() -> Path:
    from inspector.resources import recipes_dir

    return recipes_dir()


def _maxrss_mb() -> float | None:
    """``ru_maxrss`` of this process, MB (None where ``resource`` is missing)."""
    try:
        import resource
    except ImportError:  # pragma: no cover - not on Linux/macOS
        return None
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return r / _MB if sys.platform == "darwin" else r * 1024 / _MB


def _rss_mb() -> float | None:
    """Current resident memory, MB (Linux ``/proc``; None elsewhere)."""
    try:
        with open("/proc/self/statm", encoding="ascii") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / _MB
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def _stats(values: Sequence[float]) -> dict[str, float]:
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def _machine() -> dict[str, Any]:
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except (OSError, AttributeError):  # pragma: no cover
        load = None
    try:
        usable: int | None = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        usable = os.cpu_count()
    return {
        "cpu_count": os.cpu_count(),
        "usable_cpus": usable,
        "loadavg_1_5_15": load,
        "python": platform.python_version(),
        "platform": platform.platform(),
        "numba_threads": os.environ.get("NUMBA_NUM_THREADS"),
    }


# --------------------------------------------------------------------------- capture

_SIM_CHILD = """
import json, sys
from inspector.params import build_params
from inspector.capture_folder import write_capture
from inspector_drivers.sim.simulate import SimParams, simulate
folder, name, table = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
p = build_params(SimParams, table, "bench")
cap = simulate(p, 0, name=name)
write_capture(folder, cap.rig, cap.images, metadata=dict(cap.metadata), polarity=cap.polarity, overwrite=True)
"""


def simulate_capture(folder: Path, table: dict[str, Any]) -> Path:
    """Simulate one capture (:class:`SimParams` ``table``) into ``folder``, in a child
    process (its memory never counts here); written without ``truth/``."""
    from inspector.errors import InspectorError

    proc = subprocess.run(
        [sys.executable, "-c", _SIM_CHILD, str(folder), Path(folder).name, json.dumps(table)],
        capture_output=True,
        text=True,
        check=False,
    )
    if proc.returncode != 0:
        lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
        raise InspectorError(f"bench: simulation failed: {lines[-1] if lines else f'exit status {proc.returncode}'}")
    return Path(folder)


def _acquisition(folder: Path) -> Any:
    """One replay :class:`Acquisition` of ``folder`` (truth dropped: production captures have none)."""
    import dataclasses

    from inspector.registry import Acquisition
    from inspector.capture_folder import read_capture

    def load() -> Any:
        cap = read_capture(folder)
        return dataclasses.replace(cap, truth=None) if cap.truth is not None else cap

    return Acquisition(folder.name, load)


# --------------------------------------------------------------------------- cycles

_COMPILE_CHILD = """
import sys
from inspector_frontends.cli import main
sys.exit(main(sys.argv[1:]))
"""


def compile_kernels(recipe_path: str, reference: str | None, folder: Path, outdir: Path) -> dict[str, Any]:
    """Inspect ``folder`` once in a child process, so that the compiled kernels are in
    Numba's on-disk cache before the measured runs.

    The first inspection after an install compiles every kernel (minutes, and about 3 GB
    of LLVM memory, once); a production line then always runs with the cache. Compiling
    here would put that one-time peak into this process's ``ru_maxrss``.

    Returns ``{"seconds": wall time of the child, "exit": its exit status}``.
    """
    cmd = [sys.executable, "-c", _COMPILE_CHILD, "run", str(recipe_path), "--capture", str(folder),
           "--out", str(outdir), "-q"]
    if reference is not None:
        cmd += ["--reference", str(reference)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    return {"seconds": time.perf_counter() - t0, "exit": proc.returncode}


def bench_cycles(recipe: Recipe, reference: Reference | None, pm: PluginManager, folder: Path, outdir: Path, runs: int,
                 progress: Any = None) -> dict[str, Any]:
    """Inspect ``folder`` ``1 + runs`` times with :func:`run_batch` (first run = warm-up).

    Returns a dict: ``warmup_s``, ``warmup`` (the warm-up run's record), ``runs`` (per run: ``verdict``, ``error``, ``cycle_s``,
    ``timings_s`` with ``outputs`` added, ``loadavg``: the 1-minute load average before and after, ``cpu_s``: this
    process's CPU time, every thread), ``loadavg`` (min,
    median, max of those over the timed runs), ``stages`` (name -> median/min/max over the
    timed runs, ``load``, the stages, ``outputs``, ``total``: timings' total,
    ``cycle`` and ``cycle_cpu``), ``memory`` (MB).
    """
    from inspector.runner import run_batch

    mem: dict[str, Any] = {"rss_before_mb": _rss_mb(), "maxrss_before_mb": _maxrss_mb()}
    records: list[dict[str, Any]] = []
    warmup_s, warmup = 0.0, None
    for i in range(runs + 1):
        it = run_batch(recipe, [_acquisition(folder)], pm, reference=reference, outdir=outdir / f"run{i:02d}")
        load0 = _loadavg()
        t0, c0 = time.perf_counter(), time.process_time()
        outcome = next(it)
        cycle, cpu = time.perf_counter() - t0, time.process_time() - c0
        load1 = _loadavg()
        for _ in it:  # pragma: no cover - one acquisition
            pass
        res = outcome.result
        timings = dict(res.timings_s)
        timings["outputs"] = max(cycle - timings.get("total", cycle), 0.0)
        rec = {"verdict": res.verdict, "error": res.error, "cycle_s": cycle, "timings_s": timings,
               "loadavg": [load0, load1], "cpu_s": cpu}
        if i == 0:
            warmup_s, warmup = cycle, rec
            mem["maxrss_after_warmup_mb"] = _maxrss_mb()
        else:
            records.append(rec)
        if progress is not None:
            label = "warm-up" if i == 0 else f"run {i}/{runs}"
            progress(f"  {label}: {res.verdict} in {cycle:.3f} s (load {load0} -> {load1})"
                     + (f" ({res.error})" if res.error else ""))
        if res.verdict == "error":
            break
    mem["maxrss_after_mb"] = _maxrss_mb()
    mem["rss_after_mb"] = _rss_mb()
    if mem["maxrss_after_mb"] is not None:
        mem["peak_mb"] = mem["maxrss_after_mb"]
        mem["increase_mb"] = mem["maxrss_after_mb"] - mem["maxrss_before_mb"]
        if mem.get("maxrss_after_warmup_mb") is not None:
            mem["increase_timed_mb"] = mem["maxrss_after_mb"] - mem["maxrss_after_warmup_mb"]
    stages: dict[str, dict[str, float]] = {}
    if records:
        names = [k for k in records[0]["timings_s"] if k not in ("total", "outputs") and not k.startswith("hook:")]
        names += ["outputs", "total"]  # lifecycle hooks' times ("hook:PLUGIN:HOOK") are not stages
        for name in names:
            vals = [r["timings_s"][name] for r in records if name in r["timings_s"]]
            if vals:
                stages[name] = _stats(vals)
        stages["cycle"] = _stats([r["cycle_s"] for r in records])
        # CPU seconds of this process (every thread): what a cycle costs whatever else runs.
        stages["cycle_cpu"] = _stats([r["cpu_s"] for r in records])
    loads = [x for r in records for x in r["loadavg"] if x is not None]
    load = {"min": min(loads), "max": max(loads), "median": statistics.median(loads)} if loads else None
    return {"warmup_s": warmup_s, "warmup": warmup, "runs": records, "stages": stages, "memory": mem, "loadavg": load}


# --------------------------------------------------------------------------- carving


def _segment_params(recipe: Any) -> Any:
    from inspector_plugins.segment import SegmentParams

    for step in recipe.steps:
        if isinstance(step.params, SegmentParams):
            return step.params
    return SegmentParams()


def _masks(capture: Any, sp: Any) -> tuple[list[Any], list[Any], list[bool]]:
    from inspector.errors import StageError
    from inspector_plugins.segment import segment_image

    polarity = capture.polarity if sp.polarity == "auto" else sp.polarity
    use_bg = sp.background == "on" or (sp.background == "auto" and bool(capture.backgrounds))
    cams, masks, border = [], [], []
    for cam in capture.rig.cameras:
        bg = capture.backgrounds.get(cam.name) if use_bg else None
        if use_bg and bg is None:
            raise StageError(f"camera {cam.name}: no background image (background/{cam.name}.png)")
        sil = segment_image(capture.images[cam.name], bg, polarity, sp, cam.name)
        cams.append(cam)
        masks.append(sil.mask)
        border.append(bool(sil.touches_border))
    return cams, masks, border


def compare_carving(capture: Any, recipe: Any, *, carve_voxel: float, open3d_voxel: float, carve_runs: int = 3,
                    use_open3d: bool = True, open3d_max_gb: float = 4.0, progress: Any = None) -> dict[str, Any]:
    """Our ``carve`` at ``carve_voxel`` against Open3D's dense carving at ``open3d_voxel``.

    Returns a dict: ``ours`` (times, points), ``open3d`` (grid, times, kept voxels, or
    ``refused``/``skipped`` with the reason), ``ratio`` (Open3D ``carve_silhouette`` time
    over our median ``carve`` time, or None), ``ratio_with_create`` (with
    ``create_dense``) and ``ratio_without_mesh`` (over our median time without the
    display mesh; informative).
    """
    import numpy as np

    from inspector.kernels.carving import carve, default_bounds

    out: dict[str, Any] = {"carve_voxel_mm": carve_voxel, "open3d_voxel_mm": open3d_voxel}
    t0 = time.perf_counter()
    cams, masks, border = _masks(capture, _segment_params(recipe))
    out["segment_s"] = time.perf_counter() - t0
    out["open_border_cameras"] = [c.name for c, b in zip(cams, border) if b]
    bounds = np.asarray(default_bounds(cams, masks, open_border=border), float)
    out["bounds_mm"] = bounds.tolist()

    times: list[float] = []
    no_mesh: list[float] = []
    st: dict[str, Any] = {}
    recon = None
    for _ in range(max(carve_runs, 1)):
        t = time.perf_counter()
        recon = carve(cams, masks, voxel_mm=carve_voxel, bounds=bounds, open_border=border, stats=st)
        times.append(time.perf_counter() - t)
        ts = st.get("time_s") or {}
        no_mesh.append(ts.get("carve", 0.0) + ts.get("points", 0.0))
    assert recon is not None
    out["ours"] = {
        "runs_s": times,
        **{f"{k}_s": v for k, v in _stats(times).items()},
        "without_mesh_median_s": statistics.median(no_mesh),
        "n_points": int(len(recon.points)),
        "n_finest_evaluated": st.get("n_finest_evaluated"),
        "n_dense_finest": st.get("n_dense_finest"),
        "time_breakdown_s": st.get("time_s"),
    }
    if progress is not None:
        progress(f"  ours: carve at {carve_voxel} mm: median {out['ours']['median_s']:.3f} s over {len(times)} runs, "
                 f"{len(recon.points)} surface points")
    out["ratio"] = out["ratio_with_create"] = out["ratio_without_mesh"] = None
    if not use_open3d:
        out["open3d"] = {"skipped": "--no-open3d"}
        return out

    ext = bounds[1] - bounds[0]
    n = [max(1, math.ceil(float(e) / open3d_voxel - 1e-9)) for e in ext]
    n_vox = n[0] * n[1] * n[2]
    est_gb = n_vox * O3D_BYTES_PER_VOXEL / 1e9
    o3: dict[str, Any] = {"grid": n, "n_voxels": n_vox, "estimated_gb": est_gb}
    out["open3d"] = o3
    if est_gb > open3d_max_gb:
        o3["refused"] = (f"Open3D dense grid {n[0]}x{n[1]}x{n[2]} = {n_vox:,} voxels at {open3d_voxel} mm would need about "
                         f"{est_gb:.1f} GB (> --open3d-max-gb {open3d_max_gb:g}); use a larger --open3d-voxel")
        if progress is not None:
            progress("  open3d: refused: " + o3["refused"])
        return out
    try:
        import open3d as o3d
    except ImportError as e:
        o3["skipped"] = f"open3d cannot be imported ({e})"
        return out
    o3["version"] = o3d.__version__
    notes = []
    if any(c.has_distortion for c in cams):
        notes.append("lens distortion ignored by Open3D (pinhole only)")
    if any(abs(float(c.K[0, 1])) > 0 for c in cams):
        notes.append("camera skew kept in the intrinsic matrix")
    if border.count(True):
        notes.append("silhouettes touching the image border: Open3D carves outside the image")
    o3["notes"] = notes

    t = time.perf_counter()
    views = []
    for cam, m in zip(cams, masks):
        intr = o3d.camera.PinholeCameraIntrinsic(int(cam.width), int(cam.height), np.asarray(cam.K, float))
        prm = o3d.camera.PinholeCameraParameters()
        prm.intrinsic = intr
        ext4 = np.eye(4)
        ext4[:3, :3] = cam.R
        ext4[:3, 3] = cam.t
        prm.extrinsic = ext4
        # carve_silhouette samples the mask with Image.FloatValueAt: float32 images only.
        views.append((o3d.geometry.Image(np.ascontiguousarray(m, dtype=np.float32)), prm))
    o3["prepare_s"] = time.perf_counter() - t
    rss0 = _rss_mb()
    t = time.perf_counter()
    vg = o3d.geometry.VoxelGrid.create_dense(bounds[0].astype(float), np.zeros(3), float(open3d_voxel),
                                             n[0] * open3d_voxel, n[1] * open3d_voxel, n[2] * open3d_voxel)
    o3["create_dense_s"] = time.perf_counter() - t
    rss1 = _rss_mb()
    if rss0 is not None and rss1 is not None:
        o3["grid_rss_mb"] = rss1 - rss0
    per_cam = []
    t = time.perf_counter()
    for img, prm in views:
        tc = time.perf_counter()
        vg.carve_silhouette(img, prm, keep_voxels_outside_image=False)
        per_cam.append(time.perf_counter() - tc)
    o3["carve_silhouette_s"] = time.perf_counter() - t
    o3["per_camera_s"] = per_cam
    o3["total_s"] = o3["create_dense_s"] + o3["carve_silhouette_s"]
    # check_if_included maps a query to its voxel; len(get_voxels()) would build a list.
    kept = np.asarray(vg.check_if_included(o3d.utility.Vector3dVector(np.asarray(recon.points, float))), bool) \
        if len(recon.points) else np.zeros(0, bool)
    o3["n_voxels_kept"] = int(len(vg.get_voxels())) if n_vox <= 20_000_000 else None
    o3["our_points_in_kept_voxels"] = float(kept.mean()) if kept.size else None
    del vg, views
    ours = out["ours"]["median_s"]
    out["ratio"] = o3["carve_silhouette_s"] / ours if ours > 0 else None
    out["ratio_with_create"] = o3["total_s"] / ours if ours > 0 else None
    # Informative only: Open3D's occupancy grid against our cells and surface points with
    # normals, without the display mesh (Open3D makes none).
    nm = out["ours"]["without_mesh_median_s"]
    out["ratio_without_mesh"] = o3["carve_silhouette_s"] / nm if nm > 0 else None
    if progress is not None:
        progress(f"  open3d {o3['version']}: {n[0]}x{n[1]}x{n[2]} grid at {open3d_voxel} mm: create_dense "
                 f"{o3['create_dense_s']:.2f} s, carve_silhouette x{len(per_cam)} {o3['carve_silhouette_s']:.2f} s")
    return out


# --------------------------------------------------------------------------- report


def _targets(cycles: dict[str, Any], carving: dict[str, Any] | None, startup: dict[str, Any] | None = None, *,
             size: tuple[int, int] = (1024, 1024), cameras: int = TARGET_CAMERAS) -> dict[str, Any]:
    t: dict[str, Any] = {}
    cyc = cycles["stages"].get("cycle")
    ct = cycle_target_s(size[0], size[1], cameras)
    load = cycles.get("loadavg")
    t["cycle"] = {"target": f"median cycle <= {ct:.3g} s" if ct is not None else "no cycle target beyond 5 MP",
                  "target_s": ct, "value_s": cyc["median"] if cyc else None,
                  "met": (cyc["median"] <= ct) if cyc and ct is not None else None, "loadavg": load}
    peak = cycles["memory"].get("peak_mb")
    mt = memory_target_mb(*size)
    t["memory"] = {"target": f"peak memory <= {mt / 1000:g} GB" if mt is not None else "no memory target beyond 5 MP",
                   "target_mb": mt, "value_mb": peak, "met": (peak <= mt) if peak is not None and mt is not None else None}
    for key, what, target in (("cold_start", "verdict_s", COLD_START_TARGET_S), ("first_run", "seconds", FIRST_RUN_TARGET_S)):
        got = (startup or {}).get(key) or {}
        value = got.get(what) if (got.get("exit") == 0 or key == "cold_start") else None  # a verdict line is one
        t[key] = {"target": f"{key.replace('_', ' ')} <= {target:g} s", "value_s": value,
                  "met": (value <= target) if value is not None else None}
    ratio = carving.get("ratio") if carving else None
    t["carve_ratio"] = {"target": f"carve ratio >= {CARVE_RATIO_TARGET:g}", "value": ratio,
                        "met": (ratio >= CARVE_RATIO_TARGET) if ratio is not None else None}
    return t


def _word(met: bool | None) -> str:
    return "MET" if met else ("NOT MEASURED" if met is None else "NOT MET")


def _print_report(doc: dict[str, Any]) -> None:
    cfg, cyc = doc["config"], doc["cycles"]
    cap = cfg["capture"]
    m = doc["machine"]
    print()
    print(f"inspector bench: recipe {cfg['recipe']} ({cfg['recipe_name']}), reference {cfg['reference']}")
    print(f"  capture {cap['name']}: {cap['cameras']} cameras, {cap['width']}x{cap['height']} px ({cap['source']})")
    print(f"  machine: {m['usable_cpus']} usable CPUs, load average {m['loadavg_1_5_15']} at start "
          "(timings depend on other jobs on this machine)")
    comp = doc.get("compile")
    if comp:
        print(f"  kernels compiled/loaded in a child process first: {comp['seconds']:.1f} s (exit {comp['exit']}; "
              "the first inspection after an install compiles them, once)")
    st = doc.get("startup") or {}
    if st.get("first_run"):
        fr = st["first_run"]
        print(f"  first run (empty Numba cache, `python -m inspector_tools.precompile`): {fr['seconds']:.1f} s, "
              f"{fr['kernels']} kernels compiled (exit {fr['exit']})")
    if st.get("cold_start"):
        cs = st["cold_start"]
        shown = f"{cs['verdict_s']:.2f} s" if cs["verdict_s"] is not None else "no verdict"
        print(f"  cold process (new `inspector run`, kernels cached): start -> verdict {shown}, exit after {cs['exit_s']:.2f} s")
    ld = cyc.get("loadavg")
    print(f"  warm-up run {cyc['warmup_s']:.3f} s (left out); {len(cyc['runs'])} timed run(s)"
          + (f"; 1-minute load average during them {ld['min']:.2f}-{ld['max']:.2f} (median {ld['median']:.2f}) "
             f"on {m['usable_cpus']} CPUs" if ld else ""))
    if cyc["stages"]:
        print()
        print(f"  {'stage':<18}{'median s':>10}{'min s':>10}{'max s':>10}")
        for name, s in cyc["stages"].items():
            if name in ("total", "cycle", "cycle_cpu"):
                continue
            print(f"  {name:<18}{s['median']:>10.3f}{s['min']:>10.3f}{s['max']:>10.3f}")
        for name, label in (("total", "load+stages"), ("cycle", "cycle (all)"), ("cycle_cpu", "cycle CPU s")):
            s = cyc["stages"].get(name)
            if s:
                print(f"  {label:<18}{s['median']:>10.3f}{s['min']:>10.3f}{s['max']:>10.3f}")
    mem = cyc["memory"]
    if mem.get("peak_mb") is not None:
        print(f"\n  memory: peak RSS {mem['peak_mb']:.0f} MB (ru_maxrss); before the runs {mem['maxrss_before_mb']:.0f} MB, "
              f"+{mem['increase_mb']:.0f} MB over warm-up and runs (+{mem.get('increase_timed_mb', 0.0):.0f} MB over the timed runs)")
    c = doc.get("carving")
    if c:
        o = c["ours"]
        print(f"\n  carving on the same masks, box {' x '.join(f'{b - a:.1f}' for a, b in zip(*c['bounds_mm']))} mm:")
        print(f"    ours   carve() at {c['carve_voxel_mm']} mm: median {o['median_s']:.3f} s (min {o['min_s']:.3f}, "
              f"max {o['max_s']:.3f}), {o['n_points']} surface points, {o['n_finest_evaluated']} finest cells tested")
        br = o.get("time_breakdown_s") or {}
        if br:
            print(f"           last run: distance transforms and cell tests {br.get('carve', 0):.3f} s, finest cells "
                  f"and surface points {br.get('points', 0):.3f} s, display mesh {br.get('mesh', 0):.3f} s")
        o3 = c["open3d"]
        if "refused" in o3 or "skipped" in o3:
            print(f"    open3d: {o3.get('refused') or 'skipped: ' + o3['skipped']}")
        else:
            print(f"    open3d VoxelGrid at {c['open3d_voxel_mm']} mm: {'x'.join(map(str, o3['grid']))} = {o3['n_voxels']:,} voxels"
                  f" (~{o3.get('grid_rss_mb', float('nan')):.0f} MB); create_dense {o3['create_dense_s']:.2f} s, "
                  f"carve_silhouette x{len(o3['per_camera_s'])} {o3['carve_silhouette_s']:.2f} s")
            kept = o3.get("n_voxels_kept")
            inside = o3.get("our_points_in_kept_voxels")
            print(f"    open3d kept {kept if kept is not None else '?'} voxels; our surface points in kept voxels: "
                  f"{'n/a' if inside is None else f'{100 * inside:.2f} %'}")
            for note in o3.get("notes", []):
                print(f"    note: {note}")
            print(f"    ratio (carve_silhouette / our whole carve()): {c['ratio']:.1f}x; with create_dense: "
                  f"{c['ratio_with_create']:.1f}x"
                  + (f"; against ours without the display mesh: {c['ratio_without_mesh']:.1f}x (informative)"
                     if c.get("ratio_without_mesh") else ""))
    print("\n  targets:")
    t = doc["targets"]
    cv, ct, ld = t["cycle"]["value_s"], t["cycle"].get("target_s"), t["cycle"].get("loadavg")
    print(f"    cycle <= {ct if ct is not None else float('nan'):.3g} s (median, {cap['cameras']} x {cap['width']}x{cap['height']}):  "
          f"{_word(t['cycle']['met'])}" + (f" ({cv:.3f} s" if cv is not None else "")
          + (f"; load average {ld['min']:.1f}-{ld['max']:.1f} on {m['usable_cpus']} CPUs)" if cv is not None and ld else
             (")" if cv is not None else "")))
    mv, mt = t["memory"]["value_mb"], t["memory"].get("target_mb")
    print(f"    peak memory <= {(mt or float('nan')) / 1000:g} GB:   {_word(t['memory']['met'])}"
          + (f" ({mv / 1000:.2f} GB)" if mv is not None else ""))
    rv = t["carve_ratio"]["value"]
    print(f"    carve ratio >= {CARVE_RATIO_TARGET:g}x:     {_word(t['carve_ratio']['met'])}"
          + (f" ({rv:.1f}x: Open3D {c['open3d_voxel_mm']} mm vs ours {c['carve_voxel_mm']} mm)" if rv is not None and c else ""))
    for key, label in (("cold_start", f"new process -> verdict <= {COLD_START_TARGET_S:g} s"),
                       ("first_run", f"first compile <= {FIRST_RUN_TARGET_S:g} s")):
        got = t.get(key) or {}
        v = got.get("value_s")
        print(f"    {label}: {_word(got.get('met'))}" + (f" ({v:.2f} s)" if v is not None else ""))


# --------------------------------------------------------------------------- CLI


def add_parser(subparsers: Any) -> None:
    """Add the ``bench`` sub-command to ``subparsers`` (from ``add_subparsers``)."""
    b = subparsers.add_parser(
        "bench",
        help="measure the cycle time, peak memory and carving speed against Open3D (the performance targets)",
        description="Simulate (or read) one capture, inspect it 1 + RUNS times with the batch runner in this process "
        "(first run left out), report per-stage medians and peak memory, then compare our carving with Open3D's "
        "VoxelGrid.carve_silhouette on the same masks. Exit 0 when every measured target is met, 1 otherwise.",
    )
    b.add_argument("--recipe", default=str(_recipes_dir() / "default.toml"), metavar="TOML",
                   help="recipe to run (default recipes/default.toml)")
    b.add_argument("--reference", metavar="MESH", help="reference mesh or builtin:NAME (default: the recipe's, else builtin:PART)")
    b.add_argument("--part", default="cube30", help="simulated part, built-in name (default cube30)")
    b.add_argument("--seed", type=int, default=0, help="simulation seed (default 0)")
    b.add_argument("--cameras", type=int, default=16, help="simulated cameras (default 16)")
    b.add_argument("--size", action=_SizeAction, default=1024, metavar="N|WxH",
                   help="simulated image size, px: N (N x N) or WxH, e.g. 2448x2048 for 5 MP (default 1024)")
    b.set_defaults(height=None)
    b.add_argument("--mm-per-px", type=float, default=0.1, help="simulated pixel footprint at the rig centre, mm (default 0.1)")
    b.add_argument("--capture", metavar="DIR", help="use this capture folder instead of simulating one")
    b.add_argument("--no-first-run", dest="first_run", action="store_false",
                   help="skip the first-run compile time (a child compiling every kernel into an empty cache, about a minute)")
    b.add_argument("--runs", type=int, default=5, help="timed runs after the warm-up (default 5)")
    b.add_argument("--json", metavar="OUT.json", help="write every figure to this JSON file")
    b.add_argument("--no-open3d", action="store_true", help="skip the Open3D carving comparison")
    b.add_argument("--open3d-voxel", type=float, default=0.25, metavar="MM", help="Open3D voxel, mm (default 0.25)")
    b.add_argument("--open3d-max-gb", type=float, default=4.0, metavar="GB",
                   help="refuse an Open3D dense grid needing more memory than this (default 4)")
    b.add_argument("--carve-voxel", type=float, default=0.1, metavar="MM", help="our carving voxel, mm (default 0.1)")
    b.add_argument("--carve-runs", type=int, default=3, help="runs of our carving; the median is compared (default 3)")
    b.add_argument("--keep", metavar="DIR", help="write the capture and the outputs here instead of a temporary folder")
    b.add_argument("--acquisition", type=int, default=0, metavar="N",
                   help="also measure the trigger-to-all-frames latency of N emulated GigE Vision cameras "
                        "(aravis driver; needs root and the aravis packages), e.g. 16")
    b.add_argument("--triggers", type=int, default=40, help="timed triggers for --acquisition (default 40)")
    b.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    b.add_argument("--gui", action="store_true",
                   help="measure the operator window instead (needs a display; --recipe defaults to recipes/demo.toml "
                        "there): trigger to verdict shown against the headless cycle (median of --runs), event-loop "
                        "stall during inspections, memory growth over --gui-inspections (inspector_tools.bench.gui)")
    b.add_argument("--dask", action="store_true",
                   help="measure archive re-inspection throughput instead, captures per minute: in this process, then "
                        "on local Dask clusters (inspector run --workers N) of --dask-workers; --dask-captures copies of 4 "
                        "simulated captures (--part, --cameras, --size, --mm-per-px, --seed)")
    b.add_argument("--dask-captures", type=int, default=20, metavar="N", help="with --dask: captures in the archive (default 20)")
    b.add_argument("--dask-workers", type=int, nargs="+", default=[1, 2], metavar="N",
                   help="with --dask: the local clusters' worker counts (default 1 2)")
    b.add_argument("--gui-inspections", type=int, default=200, metavar="N",
                   help="with --gui: inspections in one window; memory is sampled after 20 and after N (default 200)")
    b.add_argument("--opcua", action="store_true",
                   help="measure `inspector serve` instead: trigger-to-verdict latency seen by an OPC UA client (median, "
                        "p99) against the headless cycle of the same parts (--recipe defaults to recipes/demo.toml "
                        "there; inspector_tools.bench.opcua)")
    b.add_argument("--opcua-parts", type=int, default=100, metavar="N", help="with --opcua: timed parts (default 100)")


def _default_reference(recipe_path: str, part: str) -> str | None:
    """``builtin:PART`` when the recipe names no reference (None: keep the recipe's)."""
    import tomllib

    try:
        with open(recipe_path, "rb") as f:
            head = tomllib.load(f).get("recipe", {})
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError):
        return None  # load_recipe reports the problem
    return None if isinstance(head, dict) and head.get("reference") else f"builtin:{part}"


def _check(args: argparse.Namespace) -> None:
    from inspector.errors import RecipeError

    if args.runs < 1:
        raise RecipeError("bench --runs: expected a number >= 1")
    if args.carve_runs < 1:
        raise RecipeError("bench --carve-runs: expected a number >= 1")
    for flag, v in (("--open3d-voxel", args.open3d_voxel), ("--carve-voxel", args.carve_voxel),
                    ("--mm-per-px", args.mm_per_px), ("--open3d-max-gb", args.open3d_max_gb)):
        if not (v > 0 and math.isfinite(v)):
            raise RecipeError(f"bench {flag}: expected a positive number")
    if args.cameras < 3:
        raise RecipeError("bench --cameras: expected a number >= 3")
    if min(image_size(args)) < 16:
        raise RecipeError("bench --size: expected a width and height >= 16 px")
    if args.capture is not None and not Path(args.capture).is_dir():
        raise RecipeError(f"bench --capture {args.capture}: not a folder")


def run(args: argparse.Namespace) -> int:
    """Run ``inspector bench``; see the module docstring. Exit 0 targets met, 1 not met, 3 inspection error."""
    if args.gui:  # Qt is imported there, never by this module
        from inspector_tools.bench.gui import run_gui_bench

        return run_gui_bench(args)
    if getattr(args, "opcua", False):  # asyncua is imported there, never by this module
        from inspector_tools.bench.opcua import run_opcua_bench

        return run_opcua_bench(args)
    if getattr(args, "dask", False):
        return dask_throughput(args)
    from inspector.session import Session

    _check(args)
    machine = _machine()
    say = (lambda s: None) if args.quiet else (lambda s: print(s, flush=True))
    session = Session.open(args.recipe, ".", reference=args.reference or _default_reference(args.recipe, args.part),
                           pm=getattr(args, "plugin_manager", None))
    pm, recipe, ref = session.pm, session.recipe, session.reference

    with tempfile.TemporaryDirectory(prefix="inspector-bench-") as tmp:
        work = Path(args.keep) if args.keep else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        if args.capture:
            folder = Path(args.capture)
            source = str(folder.resolve())
        else:
            width, height = image_size(args)
            table = {"part": args.part, "seed": args.seed, "cameras": args.cameras, "width": width,
                     "height": height, "mm_per_px": args.mm_per_px}
            say(f"Simulating {args.part}: {args.cameras} cameras, {width}x{height} px at {args.mm_per_px} mm/px ...")
            folder = simulate_capture(work / "captures" / f"{args.part}-s{args.seed:04d}", table)
            source = f"simulated: part {args.part}, seed {args.seed}, {args.mm_per_px} mm/px"
        from inspector.errors import InspectorError
        from inspector.capture_folder import RIG_FILE, read_rig

        try:
            cams = list(read_rig(folder / RIG_FILE).cameras)
        except InspectorError:
            cams = []  # the inspection reports the problem
        cap_info: dict[str, Any] = {"name": folder.name, "source": source, "cameras": len(cams),
                    "width": cams[0].width if cams else None, "height": cams[0].height if cams else None}
        say("Compiling the kernels in a child process (once per install; seconds when cached) ...")
        compiled = compile_kernels(args.recipe, recipe.reference, folder, work / "compile")
        from inspector_tools.precompile import cold_start, first_run

        startup: dict[str, Any] = {}
        if args.first_run:
            say("First run: compiling every kernel into an empty Numba cache in a child process (about a minute) ...")
            startup["first_run"] = first_run(work / "first-run")
        say("Cold process: a new `inspector run` on the capture ...")
        startup["cold_start"] = cold_start(args.recipe, folder, work / "cold",
                                           reference=args.reference or _default_reference(args.recipe, args.part))
        say(f"Inspecting {folder.name} {1 + args.runs} times (first = warm-up) with {recipe.name} ...")
        cycles = bench_cycles(recipe, ref, pm, folder, work / "results", args.runs, progress=say)
        failed = [r for r in [cycles["warmup"], *cycles["runs"]] if r["verdict"] == "error"]
        if failed:
            print(f"inspector: error: bench: the inspection failed: {failed[0]['error']}", file=sys.stderr)
            return 3
        say("Carving comparison on the same capture ...")
        from inspector.capture_folder import read_capture

        carving = compare_carving(read_capture(folder), recipe, carve_voxel=args.carve_voxel, open3d_voxel=args.open3d_voxel,
                                  carve_runs=args.carve_runs, use_open3d=not args.no_open3d,
                                  open3d_max_gb=args.open3d_max_gb, progress=say)
    acquisition = acquisition_latency(args.acquisition, args.triggers, progress=say) if args.acquisition else None
    doc: dict[str, Any] = {
        "acquisition": acquisition,
        "config": {
            "recipe": str(args.recipe), "recipe_name": recipe.name, "reference": recipe.reference, "capture": cap_info,
            "runs": args.runs, "warmup_runs": 1, "carve_runs": args.carve_runs, "carve_voxel_mm": args.carve_voxel,
            "open3d_voxel_mm": args.open3d_voxel, "open3d": not args.no_open3d,
        },
        "machine": machine,
        "compile": compiled,
        "startup": startup,
        "cycles": cycles,
        "carving": carving,
    }
    sim_w, sim_h = image_size(args)
    doc["targets"] = _targets(cycles, carving, startup, size=(int(cap_info["width"] or sim_w), int(cap_info["height"] or sim_h)),
                              cameras=int(cap_info["cameras"] or args.cameras))
    verdicts = [r["verdict"] for r in cycles["runs"]]
    doc["verdicts"] = verdicts
    if not args.quiet:
        _print_report(doc)
        if acquisition is not None:
            if "skipped" in acquisition:
                print(f"\n  acquisition latency: not measured ({acquisition['skipped']})")
            else:
                print(f"\n  acquisition: {acquisition['cameras']} emulated GigE Vision cameras, trigger -> all frames: "
                      f"median {acquisition['median_ms']:.1f} ms (p10 {acquisition['p10_ms']:.1f}, p90 {acquisition['p90_ms']:.1f}; "
                      f"camera {acquisition['camera_median_ms']:.1f} + driver {acquisition['overhead_median_ms']:.1f} ms), "
                      f"{acquisition['ok']} ok / {acquisition['failed']} failed")
    if args.json:
        say(f"\n  figures written to {write_figures(args.json, doc)}")
    measured = [t["met"] for t in doc["targets"].values() if t["met"] is not None]
    return 0 if all(measured) else 1


def dask_throughput(args: argparse.Namespace) -> int:
    """``inspector bench --dask`` (issue 17): archive re-inspection throughput, captures per
    minute, in this process (``inspector run``), then on a local Dask cluster of each
    ``--dask-workers`` count (``inspector run --workers N``, one thread per worker).

    The archive holds ``--dask-captures`` copies of 4 simulated captures. Each cluster is
    started, and each of its workers inspects one capture, before the clock starts (imports,
    the kernels' cache, the reference's index: once per worker process): the figures are the
    steady rate of a running cluster, result folders and history rows written. Also measured,
    for a cluster of N machines: the client's own time per capture (its result folder and
    history row, :func:`inspector.runner.record_outcome`), and the bytes a worker reads
    (the capture folder) and sends back (the pickled result). Exit 0, or 3 if a capture failed.
    """
    import pickle
    import shutil

    from inspector_frontends.distributed import connect, inspect_folder, run_on_cluster, worker_setup
    from inspector.errors import RecipeError
    from inspector.runner import Outcome, record_outcome
    from inspector.session import Session, Source

    _check(args)
    if args.dask_captures < 1 or any(w < 1 for w in args.dask_workers):
        raise RecipeError("bench --dask-captures and --dask-workers: expected numbers >= 1")
    say = (lambda s: None) if args.quiet else (lambda s: print(s, flush=True))
    ref = args.reference or _default_reference(args.recipe, args.part)
    session = Session.open(args.recipe, ".", reference=ref, pm=getattr(args, "plugin_manager", None))
    doc: dict[str, Any] = {"machine": _machine(), "captures": args.dask_captures, "recipe": str(args.recipe),
                           "capture": {"part": args.part, "cameras": args.cameras, "size": list(image_size(args)),
                                       "mm_per_px": args.mm_per_px},
                           "runs": []}
    with tempfile.TemporaryDirectory(prefix="inspector-bench-dask-") as tmp:
        work = Path(args.keep) if args.keep else Path(tmp)
        distinct = []
        for i in range(min(4, args.dask_captures)):
            say(f"Simulating capture {i + 1} of {min(4, args.dask_captures)} ...")
            table = {"part": args.part, "seed": args.seed + i, "cameras": args.cameras, "width": image_size(args)[0],
                     "height": image_size(args)[1], "mm_per_px": args.mm_per_px}
            distinct.append(simulate_capture(work / "src" / f"{args.part}-s{args.seed + i:04d}", table))
        archive = work / "archive"
        for i in range(args.dask_captures):
            shutil.copytree(distinct[i % len(distinct)], archive / f"c{i:04d}")
        doc["capture"]["bytes"] = sum(f.stat().st_size for f in distinct[0].rglob("*") if f.is_file())
        compile_kernels(args.recipe, session.recipe.reference, distinct[0], work / "compile")
        setup = worker_setup(session)
        result, _ = inspect_folder(setup, str(distinct[0]))  # warm, in this process
        doc["result_bytes"] = len(pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))
        rec = []
        for _ in range(5):
            t0 = time.perf_counter()
            record_outcome(Outcome(result, None), session.recipe, session.pm, work / "out-record")
            rec.append(time.perf_counter() - t0)
        doc["client_record_s"] = statistics.median(rec)
        failed = 0
        for workers in [0, *args.dask_workers]:
            label = "in this process" if not workers else f"on a local cluster of {workers} worker{'s' if workers > 1 else ''}"
            run_session = Session(session.recipe, session.reference, session.pm, work / f"out-{workers}")
            row: dict[str, Any] = {"workers": workers, "label": label}
            client: Any = None
            cluster: Any = None
            try:
                if workers:
                    say(f"Starting a local Dask cluster of {workers} worker process(es) ...")
                    t0 = time.perf_counter()
                    client, cluster = connect(None, workers)
                    row["start_s"] = time.perf_counter() - t0
                    t0 = time.perf_counter()
                    client.run(inspect_folder, setup, str(distinct[0]))  # every worker, once
                    row["warmup_s"] = time.perf_counter() - t0
                say(f"Inspecting {args.dask_captures} captures {label} ...")
                row["loadavg_before"] = os.getloadavg()[0]  # a shared machine: other jobs' load beside each figure
                # CPU seconds (this process, and each worker's): what a capture costs whatever else the machine runs.
                cpu0 = client.run(time.process_time) if workers else {}
                t0, c0 = time.perf_counter(), time.process_time()
                if workers:
                    summary = run_on_cluster(run_session, [str(archive)], client=client)
                else:
                    summary = run_session.run(Source(captures=(str(archive),)))
                row["seconds"] = time.perf_counter() - t0
                n = max(summary.inspected, 1)
                row["cpu_s_per_capture"] = (time.process_time() - c0) / n  # in this process (the client's, for a cluster)
                if workers:
                    cpu1 = client.run(time.process_time)
                    row["worker_cpu_s_per_capture"] = sum(cpu1[a] - cpu0[a] for a in cpu1 if a in cpu0) / n
                row["loadavg_after"] = os.getloadavg()[0]
            finally:
                if client is not None:
                    client.close()
                if cluster is not None:
                    cluster.close()
            row["captures_per_min"] = 60.0 * summary.inspected / row["seconds"]
            row["counts"] = dict(summary.counts)
            failed += summary.counts.get("error", 0)
            doc["runs"].append(row)
            cpu = row.get("worker_cpu_s_per_capture", row["cpu_s_per_capture"])
            say(f"  {label}: {row['captures_per_min']:.1f} captures/min ({row['seconds'] / summary.inspected:.2f} s per capture; "
                f"CPU {cpu:.2f} s per capture" + (f", client {row['cpu_s_per_capture']:.3f} s" if workers else "") + ")"
                + (f"; cluster start {row['start_s']:.1f} s and warm-up {row['warmup_s']:.1f} s not counted" if workers else "")
                + f" (load {row['loadavg_before']:.1f} -> {row['loadavg_after']:.1f})")
    say(f"  client, per capture: result folder and history row {1000 * doc['client_record_s']:.0f} ms (one client: at most "
        f"{60 / doc['client_record_s']:.0f} captures/min); a worker reads {doc['capture']['bytes'] / 1e6:.1f} MB per capture "
        f"and sends back {doc['result_bytes'] / 1e6:.2f} MB")
    if args.json:
        say(f"  figures written to {write_figures(args.json, doc)}")
    return 3 if failed else 0


def acquisition_latency(n: int, triggers: int, progress=lambda s: None) -> dict[str, Any]:
    """Median trigger-to-all-frames latency of ``n`` emulated GigE Vision cameras.

    Starts ``n`` ``arv-fake-gv-camera-0.8`` emulators in a private network namespace
    (:class:`inspector_tools.emulators.aravis.EmulatedRig`) and drives them with the
    ``aravis`` driver; returns ``{"skipped": reason}`` where that is not possible here.
    """
    from inspector_tools.emulators.aravis import EmulatedRig, missing_requirements, write_rig

    why = missing_requirements()
    if why:
        return {"skipped": why}
    with tempfile.TemporaryDirectory(prefix="inspector-acq-") as tmp:
        root = Path(tmp)
        write_rig(root / "rig.json", n)
        progress(f"Starting {n} emulated cameras ...")
        with EmulatedRig(n, log_dir=root / "logs") as rig:  # started on entry
            with rig.client() as client:
                params = {"rig": str(root / "rig.json"), "serials": rig.serials_table(), "count": 0, "timeout_s": 1.0}
                r = client.request({"cmd": "open", "driver": "aravis", "params": params}, timeout=120)
                if not r.get("ok"):
                    return {"skipped": f"could not open the emulated cameras: {r.get('error')}"}
                progress(f"Triggering {triggers} times ...")
                stats = client.request({"cmd": "latency", "triggers": triggers, "warmup": 3}, timeout=600)
    keys = ("cameras", "ok", "failed", "median_ms", "p10_ms", "p90_ms", "min_ms", "max_ms", "camera_median_ms", "overhead_median_ms")
    return {k: stats.get(k) for k in keys}


def write_figures(path: str | Path, doc: Any) -> Path:
    """Write a benchmark's figures as indented JSON (numpy values as lists and numbers),
    creating the folder; returns the path."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(doc, indent=2, default=_json_default) + "\n", encoding="utf-8")
    return p


def _json_default(o: Any) -> Any:
    try:
        import numpy as np

        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, np.generic):
            return o.item()
    except ImportError:  # pragma: no cover
        pass
    return repr(o)


# --------------------------------------------------------------------------- plugin
@hookimpl
def inspector_register_commands(registry: CommandRegistry) -> None:
    """``inspector bench``: a built-in plugin (entry point ``bench``), like any command."""
    from inspector.registry import CommandSpec

    registry.add(CommandSpec("bench", add_parser, run, "cycle time per stage, memory, carving vs Open3D"))
