"""Measure the product's BCPS points against the true surface of a foreign capture.

Independent of the product (imports nothing from ``inspector``, ``inspector_plugins`` or
``inspector_drivers``). Reads ``<out>/<capture>/bcps_points.ply`` and ``result.json``
written by ``inspector run`` (CONTRACT) and the truth written by ``foreign_capture.py``
(``true_world.npz``: posed true mesh, world mm, float64; ``truth.json``: pose, footprint).

Distances are exact point-to-triangle distances in float64: Open3D's BVH query
(``RaycastingScene.compute_closest_points``, float32, on coordinates centred on the part
so rounding stays ~1e-6 mm) picks a triangle, the distance to it is recomputed in float64,
and since that pick is not always the nearest triangle (next to long thin triangles it can
be 0.02 mm off), every triangle that could be nearer is then tested too (``exact_refine``).

CLI::

    python tests/acceptance/measure.py OUT/<capture> ROOT/truth/<capture>
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import open3d as o3d
import trimesh
from plyfile import PlyData

__all__ = ["DENT_MARGIN_MM", "closest_on_triangles", "dent_footprint", "distances_to_mesh", "exact_refine", "TriangleIndex",
           "measure", "pose_misfit", "read_points", "stats_px"]

#: A point within the removed sphere's radius plus this (mm) of its centre is on the dent's
#: footprint: where a contour ray may pass over the dent and the method gives a lower bound
#: of the missing depth (docs/acceptance.md). Everything farther is surface the silhouettes
#: observe as on a part without the dent.
DENT_MARGIN_MM = 0.5


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


def distances_to_mesh(P: np.ndarray, V: np.ndarray, F: np.ndarray, *, exact: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Exact distance from points to a closed triangle mesh, with a sign.

    Parameters
    ----------
    P : (n, 3) float64
        Points, mm.
    V : (m, 3) float64
        Mesh vertices, mm.
    F : (k, 3) int
        Triangles.
    exact : bool
        False: the distance to the triangle Open3D's query picks, an upper bound that is
        exact for all but a few points (see :func:`exact_refine`).

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
    if exact:
        dist = exact_refine(P, V, F, dist)
    inside = scene.compute_occupancy(q, nsamples=3).numpy() > 0.5
    return dist, np.where(inside, -dist, dist)


def _triangle_samples(tri: np.ndarray, gap: float) -> tuple[np.ndarray, np.ndarray]:
    """Points covering each triangle (k, 3, 3): every point of a triangle is within
    ``sqrt(2) * gap`` of one of its samples. Rows parallel to the shortest edge, ``gap`` apart
    at most, with as many points on each row as the shortest edge needs (so a 19.5 x 0.12 mm
    sliver gets a few hundred points, not a grid of its long edge squared).

    Returns
    -------
    samples : (m, 3) float64
    owner : (m,) int64
        The triangle of each sample.
    """
    e = np.linalg.norm(tri[:, [1, 2, 0]] - tri[:, [2, 0, 1]], axis=2)  # e[:, k]: edge opposite vertex k
    apex = e.argmin(axis=1)
    k = np.arange(len(tri))
    A, B, C = tri[k, apex], tri[k, (apex + 1) % 3], tri[k, (apex + 2) % 3]
    nr = np.maximum(np.ceil(np.maximum(e[k, (apex + 1) % 3], e[k, (apex + 2) % 3]) / gap), 1).astype(np.int64)
    nc = np.maximum(np.ceil(e[k, apex] / gap), 1).astype(np.int64)
    samples, owner = [], []
    for r, c in np.unique(np.stack([nr, nc], axis=1), axis=0):
        idx = np.flatnonzero((nr == r) & (nc == c))
        s, u = np.meshgrid(np.arange(r + 1) / r, np.arange(c + 1) / c, indexing="ij")
        s, u = s.ravel()[None, :, None], u.ravel()[None, :, None]
        a, b, cc = A[idx][:, None], B[idx][:, None], C[idx][:, None]
        pts = a + s * ((b - a) + u * (cc - b))  # row s: from A + s(B - A) to A + s(C - A)
        samples.append(pts.reshape(-1, 3))
        owner.append(np.repeat(idx, s.size))
    return np.concatenate(samples), np.concatenate(owner)


class TriangleIndex:
    """Samples covering each triangle of a mesh (V, F), in a k-d tree: the candidate search of
    :func:`exact_refine`, built once per mesh when many point sets are measured against it."""

    def __init__(self, V: np.ndarray, F: np.ndarray, h: float = 0.3) -> None:
        from scipy.spatial import cKDTree

        self.tri = np.asarray(V, float)[np.asarray(F)]
        self.h = h
        samples, self.owner = _triangle_samples(self.tri, h / math.sqrt(2.0))
        self.tree = cKDTree(samples)

    def distances(self, P: np.ndarray) -> np.ndarray:
        """Open3D's upper bounds (n,) of the distances of points ``P`` (n, 3) to the mesh, mm
        (its pick, measured in float64; the scene is built once)."""
        import open3d as o3d

        if not hasattr(self, "_scene"):
            V = self.tri.reshape(-1, 3)
            self._origin = V.mean(axis=0)
            self._scene = o3d.t.geometry.RaycastingScene()
            self._scene.add_triangles(o3d.core.Tensor((V - self._origin).astype(np.float32)),
                                      o3d.core.Tensor(np.arange(len(V), dtype=np.uint32).reshape(-1, 3)))
        q = o3d.core.Tensor((P - self._origin).astype(np.float32))
        t = self.tri[self._scene.compute_closest_points(q)["primitive_ids"].numpy().astype(np.int64)]
        return np.linalg.norm(P - closest_on_triangles(P, t[:, 0], t[:, 1], t[:, 2]), axis=1)

    def refine(self, P: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """Exact distances (n,) of points ``P`` (n, 3) given upper bounds ``upper`` (n,), mm."""
        tri, nf = self.tri, len(self.tri)
        hits = self.tree.query_ball_point(P, upper + self.h * (1.0 + 1e-9))
        ii = np.repeat(np.arange(len(P)), [len(x) for x in hits])
        jj = self.owner[np.concatenate([np.asarray(x, np.int64) for x in hits])] if len(ii) else np.zeros(0, np.int64)
        pair = np.unique(ii * nf + jj)
        ii, jj = pair // nf, pair % nf
        d = np.linalg.norm(P[ii] - closest_on_triangles(P[ii], tri[jj, 0], tri[jj, 1], tri[jj, 2]), axis=1)
        out = np.array(upper, float)
        np.minimum.at(out, ii, d)
        return out


def exact_refine(P: np.ndarray, V: np.ndarray, F: np.ndarray, upper: np.ndarray, h: float = 0.3,
                 index: TriangleIndex | None = None) -> np.ndarray:
    """Exact distances, given an upper bound ``upper`` (n,) for each point (mm).

    Open3D's closest-point query is not always exact: next to long thin triangles (the
    walls of a cross hole, 19.5 x 0.12 mm) it can return a triangle 0.0075-0.02 mm farther
    than the nearest one (measured: 0.3 % of the surface samples of the foreign shaft,
    1.1 % of the housing's). So every triangle that can be nearer than the bound is tested
    exactly in float64: each triangle is covered by samples ``h`` apart at most, and a triangle
    whose nearest point is within the bound has a sample within bound + ``h`` of the point;
    the smallest exact distance wins. ``index``: a prebuilt :class:`TriangleIndex` of (V, F).
    """
    return (index or TriangleIndex(V, F, h)).refine(P, upper)


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


def dent_footprint(truth: dict[str, Any], xyz: np.ndarray, margin_mm: float = DENT_MARGIN_MM) -> np.ndarray | None:
    """Which points ``xyz`` (n, 3) world mm lie on a removed bump's footprint: within the
    sphere's radius + ``margin_mm`` of its centre (truth.json ``defect.at_mm``, part frame,
    moved by ``pose``). None when the capture has no removed bump."""
    d = truth.get("defect") or {}
    if d.get("kind") != "bump_removed":
        return None
    pose = np.asarray(truth["pose"], float)
    centre = pose[:3, :3] @ np.asarray(d["at_mm"], float) + pose[:3, 3]
    return np.linalg.norm(np.asarray(xyz, float) - centre, axis=1) <= float(d["radius_mm"]) + margin_mm


def stats_px(dist: np.ndarray, footprint_mm: float) -> dict[str, Any]:
    """``n``, ``mean_px``, ``p99_px``, ``max_px`` of distances ``dist`` (mm); None values when empty."""
    if len(dist) == 0:
        return {"n": 0, "mean_px": None, "p99_px": None, "max_px": None}
    return {"n": int(len(dist)), "mean_px": float(dist.mean() / footprint_mm),
            "p99_px": float(np.percentile(dist, 99) / footprint_mm), "max_px": float(dist.max() / footprint_mm)}


def measure(result_dir: str | Path, truth_dir: str | Path, dent_margin_mm: float = DENT_MARGIN_MM) -> dict[str, Any]:
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
        points: xyz, signed distance mm, camera, u, v). A capture with a removed bump also
        gets ``observable`` and ``dent`` (:func:`stats_px` of the points outside and on the
        dent's footprint, :func:`dent_footprint`; ``dent`` adds ``radius_mm``, ``margin_mm``,
        ``centre`` (world mm) and the indices ``idx`` of its points in the PLY).
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
    foot = dent_footprint(truth, pts["xyz"], dent_margin_mm)
    if foot is not None:
        d = truth["defect"]
        pose = np.asarray(truth["pose"], float)
        out["observable"] = stats_px(dist[~foot], fp)
        out["dent"] = {**stats_px(dist[foot], fp), "radius_mm": float(d["radius_mm"]), "margin_mm": dent_margin_mm,
                       "centre": (pose[:3, :3] @ np.asarray(d["at_mm"], float) + pose[:3, 3]).tolist(),
                       "idx": np.flatnonzero(foot).tolist()}
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
