"""Accuracy against the simulator's ground truth (when a capture has ``truth/``)."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["distance_to_truth", "truth_stats"]


def distance_to_truth(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unsigned distance (mm) of world points (N, 3) to the true surface."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(np.asarray(points, np.float32))).numpy().astype(float)


def _summary(d: np.ndarray, px: float) -> dict[str, float]:
    return {
        "mean_mm": float(d.mean()),
        "p99_mm": float(np.percentile(d, 99)),
        "max_mm": float(d.max()),
        "mean_px": float(d.mean() / px),
        "p99_px": float(np.percentile(d, 99) / px),
    }


def truth_stats(capture: Any, bcps_points: np.ndarray | None, recon_points: np.ndarray | None) -> dict[str, Any] | None:
    """Distances of the BCPS and reconstruction points to the true surface, or None."""
    if capture.truth is None:
        return None
    try:
        mesh = capture.truth.mesh_arrays()
    except Exception as e:  # noqa: BLE001 - truth is a diagnostic; never fail an inspection for it
        return {"error": f"truth/part.ply: unreadable ({type(e).__name__})"}
    if mesh is None:
        return None
    px = capture.rig.footprint_mm()
    out: dict[str, Any] = {"footprint_mm": px}
    for key, pts in (("bcps", bcps_points), ("reconstruction", recon_points)):
        if pts is not None and len(pts):
            out[key] = _summary(distance_to_truth(pts, *mesh), px)
    return out
