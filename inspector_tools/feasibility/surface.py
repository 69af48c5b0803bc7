"""The reference's surface as a study sees it: elements of about equal area, and regions.

A *surface element* is the patch of the reference nearest to one of a set of surface points
spaced about ``element_mm`` apart (a Poisson-disk sample): elements have about the same
area whatever the CAD tessellation (a cube's 12 triangles, a boolean's slivers). A point,
mapped into the reference frame, belongs to the element of the nearest centre. The display
mesh is the reference subdivided to a fraction of the element size; each of its faces and
vertices carries its element, for the PLY and the pictures.

A *region* is what the study reports on: the recipe's named tolerance boxes (reference
frame, the last box containing a point wins, as in ``evaluate.tolerance``; ``default`` holds
the rest), or, when the recipe has none, six patches by the direction of the outward normal
(``+x`` holds the surface facing +x most, and so on).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

__all__ = ["PATCHES", "Regions", "SurfaceMap", "build_map", "sample_surface"]

#: Patch names when the recipe has no regions, in label order.
PATCHES = ("+x", "-x", "+y", "-y", "+z", "-z")


@dataclass(frozen=True)
class Regions:
    """How surface points are grouped into the regions a study reports on.

    Attributes
    ----------
    names : tuple of str
        Label ``i`` is ``names[i]``. Boxes: ``"default"`` first, then the recipe's regions in
        its order. Patches: :data:`PATCHES`.
    boxes : tuple of ((3,), (3,)) float
        Boxes (min, max corner, reference frame, mm) of ``names[1:]``; empty for patches.
    bands : tuple of (float, float)
        Tolerance band (lower, upper) of each name, mm.
    """

    names: tuple[str, ...]
    boxes: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = ()
    bands: tuple[tuple[float, float], ...] = ()

    @property
    def patches(self) -> bool:
        return not self.boxes

    def label(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Region of each surface point.

        Parameters
        ----------
        points : (N, 3) float
            Reference frame, mm.
        normals : (N, 3) float
            Outward unit normals there.

        Returns
        -------
        (N,) int
            Index into :attr:`names`.
        """
        p = np.asarray(points, float).reshape(-1, 3)
        if self.patches:
            n = np.asarray(normals, float).reshape(-1, 3)
            axis = np.argmax(np.abs(n), axis=1)
            negative = n[np.arange(len(n)), axis] < 0
            return (2 * axis + negative).astype(np.int64)
        out = np.zeros(len(p), np.int64)
        for k, (lo, hi) in enumerate(self.boxes):
            inside = np.all((p >= np.asarray(lo)) & (p <= np.asarray(hi)), axis=1)
            out[inside] = k + 1
        return out


def sample_surface(vertices: np.ndarray, faces: np.ndarray, count: int, rng: np.random.Generator
                   ) -> tuple[np.ndarray, np.ndarray]:
    """``count`` points uniform on the surface (area-weighted), with the outward normal of
    their triangle; (count, 3) mm and (count, 3)."""
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces, np.int64), process=False)
    pts, fid = trimesh.sample.sample_surface(mesh, int(count), seed=rng)
    return np.asarray(pts, float), np.asarray(mesh.face_normals[fid], float)


@dataclass(frozen=True, eq=False)
class SurfaceMap:
    """The reference cut into surface elements (see the module's docstring).

    Attributes
    ----------
    element_mm : float
        Spacing of the element centres, mm.
    centres, normals : (E, 3) float
        Element centres on the surface (reference frame, mm) and their outward normals.
    area : (E,) float
        Element areas, mm² (they partition the surface).
    region : (E,) int
        Region of each element (index into ``regions.names``).
    vertices : (V, 3) float
    faces : (F, 3) int
        The display mesh (the reference subdivided), reference frame, mm.
    face_element : (F,) int
    vertex_element : (V,) int
        Element of each display face (by its centroid) and vertex.
    regions : Regions
    """

    element_mm: float
    centres: np.ndarray
    normals: np.ndarray
    area: np.ndarray
    region: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    face_element: np.ndarray
    vertex_element: np.ndarray
    regions: Regions

    @property
    def n(self) -> int:
        return len(self.centres)

    @cached_property
    def tree(self) -> Any:
        from scipy.spatial import cKDTree

        return cKDTree(self.centres)

    def assign(self, points: np.ndarray) -> np.ndarray:
        """Element of each point, (N, 3) reference frame mm -> (N,) int (nearest centre)."""
        p = np.asarray(points, float).reshape(-1, 3)
        if not len(p):
            return np.zeros(0, np.int64)
        return np.asarray(self.tree.query(p)[1], np.int64)

    def region_area(self) -> np.ndarray:
        """Area of each region, mm², (len(regions.names),)."""
        return np.bincount(self.region, weights=self.area, minlength=len(self.regions.names))


def default_element_mm(vertices: np.ndarray, footprint_mm: float) -> float:
    """About 1/60 of the part's bounding-box diagonal, at least two pixel footprints, mm."""
    v = np.asarray(vertices, float)
    diag = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    return max(diag / 60.0, 2.0 * footprint_mm)


def build_map(vertices: np.ndarray, faces: np.ndarray, element_mm: float, regions: Regions, *, seed: int = 0,
              max_elements: int = 60_000) -> SurfaceMap:
    """Cut the reference into elements of about ``element_mm`` (deterministic for ``seed``).

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int
        The reference, its own frame, mm.
    element_mm : float
        Target spacing of the element centres, mm (raised so that there are at most
        ``max_elements``).
    regions : Regions
    seed : int

    Returns
    -------
    SurfaceMap
    """
    import trimesh

    V = np.asarray(vertices, float)
    F = np.asarray(faces, np.int64)
    mesh = trimesh.Trimesh(V, F, process=False)
    total = float(mesh.area)
    element_mm = max(float(element_mm), float(np.sqrt(total / max_elements)))
    rng = np.random.default_rng(seed)
    count = int(min(4 * total / element_mm**2, 8 * max_elements)) + 16
    import logging

    quiet = logging.getLogger("trimesh")
    level = quiet.level
    quiet.setLevel(logging.ERROR)  # "only got N/M samples": the thinning is the point
    try:
        # Thinning keeps no two centres closer than the radius; they end about 1.7 radii apart.
        centres, fid = trimesh.sample.sample_surface_even(mesh, count, radius=element_mm / 1.7, seed=rng)
    finally:
        quiet.setLevel(level)
    centres = np.asarray(centres, float)
    normals = np.asarray(mesh.face_normals[np.asarray(fid)], float)
    dv, df = trimesh.remesh.subdivide_to_size(V, F, max_edge=1.5 * element_mm, max_iter=12)
    dv, df = np.asarray(dv, float), np.asarray(df, np.int64)
    from scipy.spatial import cKDTree

    tree = cKDTree(centres)
    tri = dv[df]
    face_element = np.asarray(tree.query(tri.mean(axis=1))[1], np.int64)
    vertex_element = np.asarray(tree.query(dv)[1], np.int64)
    # Areas: the share of uniform surface samples nearest to each centre.
    n_mc = int(min(max(50 * len(centres), 100_000), 1_000_000))
    mc, _ = trimesh.sample.sample_surface(mesh, n_mc, seed=rng)
    area = np.bincount(np.asarray(tree.query(mc)[1]), minlength=len(centres)) * (total / n_mc)
    out = SurfaceMap(element_mm, centres, normals, area, regions.label(centres, normals), dv, df, face_element,
                     vertex_element, regions)
    out.__dict__["tree"] = tree  # the cached_property, already built
    return out


def region_names_with_surface(m: SurfaceMap, names: Sequence[str] | None = None) -> list[str]:
    """The region names (of ``names``, default all) that hold some surface."""
    area = m.region_area()
    wanted = list(m.regions.names) if names is None else list(names)
    return [n for n in wanted if area[m.regions.names.index(n)] > 0]
