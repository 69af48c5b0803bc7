"""Measure the product's BCPS points against the true surface of a foreign capture.

Independent of the product (imports nothing from ``inspector``, ``inspector_plugins`` or
``inspector_drivers``). Reads ``<out>/<capture>/bcps_points.ply`` and ``result.json``
written by ``inspector run`` (CONTRACT) and the truth written by ``foreign_capture.py``
(``true_world.npz``: posed true mesh, world mm, float64; ``truth.json``: pose, footprint).

Distances are exact point-to-triangle distances in float64: Open3D's BVH query
(``RaycastingScene.compute_closest_points``, float32, on coordinates centred on the part
so rounding stays ~1e-6 mm) only picks the nearest triangle; the distance to that
triangle is then recomputed in float64.

CLI::

    python tests/acceptance/measure.py OUT/<capture> ROOT/truth/<capture>
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d
import trimesh
from plyfile import PlyData

__all__ = ["closest_on_triangles", "distances_to_mesh", "measure", "pose_misfit", "read_points"]


def read_points(path: str | Path) -> dict[str, np.ndarray]:
    """Vertices of a PLY point cloud: ``xyz`` (n, 3) float64 mm plus every other vertex property."""
    v = PlyData.read(str(path))["vertex"].data
    out = {name: np.asarray(v[name]) for name in v.dtype.names}
    out["xyz"] = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
    return out


def closest_on_triangles(P: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Closest point to ``P`` on triangle ``(A, B, C)``, row by row (Ericson, *Real-Time Collision Detection* 5.1.5).

    Parameters
    ----------
    P, A, B, C : (n, 3) float64
        Query points and triangle corners, mm.

    Returns
    -------
    (n, 3) float64
        Closest points, mm.
    """
    def dot(x, y):
        return np.einsum("ij,ij->i", x, y)

    ab, ac, ap = B - A, C - A, P - A
    d1, d2 = dot(ab, ap), dot(ac, ap)
    bp = P - B
    d3, d4 = dot(ab, bp), dot(ac, bp)
    cp = P - C
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2

    # Interior by default, then overwrite with the edge and vertex regions (most specific last).
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        out = A + ab * (vb / denom)[:, None] + ac * (vc / denom)[:, None]
        m = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)  # edge BC
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        out[m] = B[m] + w[m, None] * (C - B)[m]
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)  # edge AC
        w = d2 / (d2 - d6)
        out[m] = A[m] + w[m, None] * ac[m]
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)  # edge AB
        w = d1 / (d1 - d3)
        out[m] = A[m] + w[m, None] * ab[m]
    m = (d6 >= 0) & (d5 <= d6)
    out[m] = C[m]
    m = (d3 >= 0) & (d4 <= d3)
    out[m] = B[m]
    m = (d1 <= 0) & (d2 <= 0)
    out[m] = A[m]
    return out


def distances_to_mesh(P: np.ndarray, V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact distance from points to a closed triangle mesh, with a sign.

    Parameters
    ----------
    P : (n, 3) float64
        Points, mm.
    V : (m, 3) float64
        Mesh vertices, mm.
    F : (k, 3) int
        Triangles.

    Returns
    -------
    dist : (n,) float64
        Unsigned distance to the surface, mm.
    signed : (n,) float64
        ``dist`` with the CONTRACT sign: negative inside the solid.
    """
    origin = V.mean(axis=0)  # keep float32 coordinates small in the BVH
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor((V - origin).astype(np.float32)), o3d.core.Tensor(F.astype(np.uint32)))
    q = o3d.core.Tensor((P - origin).astype(np.float32))
    prim = scene.compute_closest_points(q)["primitive_ids"].numpy().astype(np.int64)
    tri = V[F[prim]]
    foot = closest_on_triangles(P, tri[:, 0], tri[:, 1], tri[:, 2])
    dist = np.linalg.norm(P - foot, axis=1)
    inside = scene.compute_occupancy(q, nsamples=3).numpy() > 0.5
    return dist, np.where(inside, -dist, dist)


def pose_misfit(nominal: trimesh.Trimesh, pose_true: np.ndarray, pose_est: np.ndarray, n: int = 20000) -> dict[str, float]:
    """How far the product's pose puts the nominal surface from where the true pose puts it.

    Symmetry-proof (torus, nut): seeded samples of the nominal surface moved by
    ``pose_est`` are measured against the nominal mesh moved by ``pose_true``.

    Returns
    -------
    dict
        ``mean_mm``, ``max_mm`` of those distances and the naive ``translation_mm``
        (difference of the two translations, i.e. of where the part centre is put).
    """
    rng = np.random.default_rng(0)
    area = nominal.area_faces / nominal.area_faces.sum()
    f = rng.choice(len(nominal.faces), size=n, p=area)
    a, b = rng.random((2, n))
    flip = a + b > 1
    a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
    t = nominal.triangles[f]
    S = t[:, 0] + a[:, None] * (t[:, 1] - t[:, 0]) + b[:, None] * (t[:, 2] - t[:, 0])
    S_est = S @ pose_est[:3, :3].T + pose_est[:3, 3]
    V_true = nominal.vertices @ pose_true[:3, :3].T + pose_true[:3, 3]
    d, _ = distances_to_mesh(S_est, V_true, nominal.faces)
    return {"mean_mm": float(d.mean()), "max_mm": float(d.max()),
            "translation_mm": float(np.linalg.norm(pose_est[:3, 3] - pose_true[:3, 3]))}


def measure(result_dir: str | Path, truth_dir: str | Path) -> dict[str, Any]:
    """Distances from the BCPS points of one inspected capture to its true surface.

    Parameters
    ----------
    result_dir : path
        ``OUTDIR/<capture>/`` written by ``inspector run``.
    truth_dir : path
        ``ROOT/truth/<capture>/`` written by ``foreign_capture.make_capture``.

    Returns
    -------
    dict
        ``n_points``; ``mean``, ``p99``, ``max`` in mm (``*_mm``) and in pixel footprints
        (``*_px``); ``signed_mean_mm``; ``footprint_mm``; ``verdict`` and ``error`` from
        result.json; ``pose`` (see :func:`pose_misfit`), ``per_camera`` (mean px, p99 px,
        n by camera, when the PLY has a ``camera`` property) and ``worst`` (the 10 farthest
        points: xyz, signed distance mm, camera, u, v).
    """
    result_dir, truth_dir = Path(result_dir), Path(truth_dir)
    res = json.loads((result_dir / "result.json").read_text())
    truth = json.loads((truth_dir / "truth.json").read_text())
    out: dict[str, Any] = {"verdict": res.get("verdict"), "error": res.get("error"),
                           "footprint_mm": truth["footprint_mm"], "total_s": res.get("timings_s", {}).get("total")}
    ply = result_dir / "bcps_points.ply"
    if res.get("verdict") == "error" or not ply.exists():
        return {**out, "n_points": 0}
    pts = read_points(ply)
    tw = np.load(truth_dir / "true_world.npz")
    dist, signed = distances_to_mesh(pts["xyz"], tw["vertices"], tw["faces"])
    fp = truth["footprint_mm"]
    out.update({
        "n_points": int(len(dist)),
        "mean_mm": float(dist.mean()), "p99_mm": float(np.percentile(dist, 99)), "max_mm": float(dist.max()),
        "signed_mean_mm": float(signed.mean()),
    })
    out.update({f"{k}_px": out[f"{k}_mm"] / fp for k in ("mean", "p99", "max")})
    if res.get("pose") is not None:
        nominal = trimesh.load_mesh(truth_dir / "reference.stl")
        out["pose"] = pose_misfit(nominal, np.asarray(truth["pose"]), np.asarray(res["pose"]))
    if "camera" in pts:
        cams = pts["camera"].astype(int)
        out["per_camera"] = {int(c): {"n": int((cams == c).sum()), "mean_px": float(dist[cams == c].mean() / fp),
                                      "p99_px": float(np.percentile(dist[cams == c], 99) / fp)}
                             for c in np.unique(cams)}
    worst = np.argsort(dist)[::-1][:10]
    out["worst"] = [{"xyz": pts["xyz"][i].round(4).tolist(), "signed_mm": float(signed[i]),
                     **{k: float(pts[k][i]) for k in ("camera", "u", "v") if k in pts}} for i in worst]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("result_dir", type=Path, help="OUTDIR/<capture> written by inspector run")
    ap.add_argument("truth_dir", type=Path, help="ROOT/truth/<capture> written by foreign_capture.py")
    args = ap.parse_args(argv)
    print(json.dumps(measure(args.result_dir, args.truth_dir), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
