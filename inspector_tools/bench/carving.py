"""``inspector bench``: our carving against Open3D's dense carving on the same masks
(:func:`compare_carving`; the measurement is described in :mod:`inspector_tools.bench.command`)."""

from __future__ import annotations

import math
import statistics
import time
from typing import Any

import numpy as np

from inspector.errors import StageError
from inspector.kernels.carving import carve, default_bounds
from inspector_plugins.segment import SegmentParams, segment_image
from inspector_tools.bench.common import rss_mb, stats

__all__ = ["O3D_BYTES_PER_VOXEL", "compare_carving"]

#: Memory of one voxel of an Open3D ``VoxelGrid`` (hash map node: index, colour, key;
#: measured about 92 bytes with Open3D 0.20), bytes.
O3D_BYTES_PER_VOXEL = 100


def _segment_params(recipe: Any) -> Any:
    for step in recipe.steps:
        if isinstance(step.params, SegmentParams):
            return step.params
    return SegmentParams()


def _masks(capture: Any, sp: Any) -> tuple[list[Any], list[Any], list[bool]]:
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
    out: dict[str, Any] = {"carve_voxel_mm": carve_voxel, "open3d_voxel_mm": open3d_voxel}
    t0 = time.perf_counter()
    cams, masks, border = _masks(capture, _segment_params(recipe))
    out["segment_s"] = time.perf_counter() - t0
    out["open_border_cameras"] = [c.name for c, b in zip(cams, border) if b]
    bounds = np.asarray(default_bounds(cams, masks, open_border=border), float)
    out["bounds_mm"] = bounds.tolist()

    out["ours"], recon = _ours(cams, masks, border, bounds, carve_voxel, carve_runs)
    if progress is not None:
        progress(f"  ours: carve at {carve_voxel} mm: median {out['ours']['median_s']:.3f} s over "
                 f"{len(out['ours']['runs_s'])} runs, {len(recon.points)} surface points")
    out["ratio"] = out["ratio_with_create"] = out["ratio_without_mesh"] = None
    if not use_open3d:
        out["open3d"] = {"skipped": "--no-open3d"}
        return out
    _open3d(out, cams, masks, border, bounds, recon, open3d_voxel, open3d_max_gb, progress)
    return out


def _ours(cams: list[Any], masks: list[Any], border: list[bool], bounds: Any, carve_voxel: float,
          carve_runs: int) -> tuple[dict[str, Any], Any]:
    """Our ``carve`` ``carve_runs`` times: (its figures, the last reconstruction)."""
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
    ours = {
        "runs_s": times,
        **{f"{k}_s": v for k, v in stats(times).items()},
        "without_mesh_median_s": statistics.median(no_mesh),
        "n_points": int(len(recon.points)),
        "n_finest_evaluated": st.get("n_finest_evaluated"),
        "n_dense_finest": st.get("n_dense_finest"),
        "time_breakdown_s": st.get("time_s"),
    }
    return ours, recon


def _open3d(out: dict[str, Any], cams: list[Any], masks: list[Any], border: list[bool], bounds: Any, recon: Any,
            open3d_voxel: float, open3d_max_gb: float, progress: Any) -> None:
    """Open3D's dense carving on the same masks and box: ``out["open3d"]`` and the ratios."""
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
        return
    try:
        import open3d as o3d
    except ImportError as e:
        o3["skipped"] = f"open3d cannot be imported ({e})"
        return
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
    rss0 = rss_mb()
    t = time.perf_counter()
    vg = o3d.geometry.VoxelGrid.create_dense(bounds[0].astype(float), np.zeros(3), float(open3d_voxel),
                                             n[0] * open3d_voxel, n[1] * open3d_voxel, n[2] * open3d_voxel)
    o3["create_dense_s"] = time.perf_counter() - t
    rss1 = rss_mb()
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
