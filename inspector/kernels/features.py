"""Geometric features of a triangle mesh: planes, cylinders, cones, spheres and tori as face sets.

A CAD mesh is its B-rep's faces tessellated: a plane is a set of coplanar triangles, a
cylinder a ring of long facets whose normals are all perpendicular to one axis, a cone facets
whose normals make one angle with its axis (and whose planes all pass through the apex), a
sphere facets whose normals all point at one centre, a torus (a fillet round a circular edge,
a groove) facets whose normal lines all meet its axis. Every vertex of such a tessellation lies
on the true surface (the facets are chords inside a convex surface, outside a concave one), so
a primitive fitted to the *vertices* recovers the CAD's nominal exactly, whatever the facet
size. The segmentation:

1. **Planar regions** -- region growing over edge-adjacent triangles, largest first: a
   neighbour joins when its normal is within ``angle_tol_deg`` of the seed's and its vertices
   within ``dist_tol_mm`` of the seed's plane.
2. **Smooth groups** -- planar regions meeting at a dihedral angle below ``smooth_deg`` (the
   facets of a curved surface: 2.8 degrees for 128 sections, 11 for 32) form connected groups;
   a region several times larger than the group's median (a flat face tangent to a curved one,
   e.g. the sides of a keyway slot) stays a plane -- but large regions smoothly adjacent to each
   other (a cylinder's long facets next to a tangent fillet's small ones) form a group.
3. **Primitive fitting** -- each group's vertices are fitted with a cylinder (axis: the
   direction most perpendicular to every facet normal), a sphere (centre: the point nearest to
   every facet's normal line) and a cone (axis: the normal of the circle the facet normals
   lie on; apex: the point nearest to every facet plane) by
   :mod:`inspector.kernels.fits`; the simplest that holds 95 % of the vertices within
   ``dist_tol_mm`` wins; only when none holds is a torus tried (axis: the line every facet's
   normal line meets). A group that no single primitive fits is split by growing regions from
   seeds, accepting each neighbour whose vertices the current primitive holds (tori are not
   grown: what the seeds leave, connected, is tried whole).
4. Planar regions not part of a curved feature, with at least ``min_area_mm2``, are planes.

Ids are stable: the same mesh gives the same features in the same order -- by kind (plane,
cylinder, cone, sphere, torus), then area (largest first), then centroid -- numbered ``F01``,
``F02`` ... .

Units: mm, degrees in the parameters and nominals.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from inspector.kernels import fits

__all__ = ["Feature", "KINDS", "find_features", "mesh_topology"]

#: Feature kinds, in the order the ids are given.
KINDS = ("plane", "cylinder", "cone", "sphere", "torus")
#: A planar region this many times the median region of its smooth group is a face of its own.
_LARGE = 4.0
#: Smooth groups are grown from seeds of at least this many planar regions when split.
_SEED_REGIONS = 6
#: A curved feature's facet normals must turn by at least this much (degrees).
_MIN_TURN_DEG = 10.0
#: Fraction of a group's vertices a primitive must hold within the distance tolerance.
_HOLD = 0.95
#: Seeds tried when a smooth group that no primitive fits is split.
_MAX_SEEDS = 25


@dataclass(frozen=True, eq=False)
class Feature:
    """A geometric feature of the reference: a set of its triangles and a primitive.

    Attributes
    ----------
    id : str
        ``F01``, ``F02`` ... (stable for a given mesh).
    kind : str
        One of :data:`KINDS`.
    nominal : dict
        The primitive, mm and degrees, vectors as 3-tuples. ``plane``: ``point``, ``normal``
        (outward). ``cylinder``: ``point`` (on the axis, mid-length), ``direction`` (unit,
        largest component positive), ``radius``, ``length``, ``convex`` (True: a boss or an
        outer cylinder; False: a bore). ``cone``: ``apex``, ``axis`` (unit, from the apex
        into the cone), ``half_angle_deg``, ``convex``. ``sphere``: ``centre``, ``radius``,
        ``convex``. ``torus``: ``centre`` (of the circle the tube's centre runs on), ``axis``
        (unit, largest component positive), ``major_radius`` (that circle's), ``minor_radius``
        (the tube's: a fillet's radius), ``convex`` (True: material inside the tube, a rounded
        outer edge; False: a fillet in an inner corner, a groove).
    faces : (T,) int
        Indices of its triangles in the mesh, sorted.
    area_mm2 : float
    triangles : int
    """

    id: str
    kind: str
    nominal: dict[str, Any]
    faces: np.ndarray
    area_mm2: float
    triangles: int

    def to_json(self) -> dict[str, Any]:
        """``{id, kind, nominal, area_mm2, triangles}`` (plain JSON types)."""
        return {"id": self.id, "kind": self.kind, "nominal": {k: _plain(v) for k, v in self.nominal.items()},
                "area_mm2": float(self.area_mm2), "triangles": int(self.triangles)}

    @property
    def direction(self) -> np.ndarray | None:
        """The plane's normal or the axis direction (3,), None for a sphere."""
        for key in ("normal", "direction", "axis"):
            if key in self.nominal:
                return np.asarray(self.nominal[key], float)
        return None


def _plain(v: Any) -> Any:
    if isinstance(v, (tuple, list, np.ndarray)):
        return [float(x) for x in v]
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (float, int, np.floating, np.integer)):
        return float(v)
    return v


def _tuple(v: np.ndarray) -> tuple[float, ...]:
    return tuple(float(x) for x in np.asarray(v, float).ravel())


# --------------------------------------------------------------------------- topology


def mesh_topology(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Merged vertices and the triangles' edge adjacency.

    Parameters
    ----------
    vertices : (V, 3) float
        mm.
    faces : (F, 3) int

    Returns
    -------
    V : (V', 3) float
        Vertices with exact duplicates merged.
    Fm : (F, 3) int
        Faces on ``V``.
    normals : (F, 3) float
        Unit face normals (zero for degenerate faces).
    areas : (F,) float
        mm^2.
    pairs : (E, 2) int
        Pairs of triangles sharing an edge.
    """
    V0 = np.asarray(vertices, float)
    F0 = np.asarray(faces, np.int64)
    V, inv = np.unique(V0, axis=0, return_inverse=True)
    Fm = inv.reshape(-1)[F0]
    cr = np.cross(V[Fm[:, 1]] - V[Fm[:, 0]], V[Fm[:, 2]] - V[Fm[:, 0]])
    norm = np.linalg.norm(cr, axis=1)
    areas = 0.5 * norm
    normals = np.where(norm[:, None] > 0, cr / np.maximum(norm, 1e-300)[:, None], 0.0)
    e = np.sort(np.stack([Fm[:, [0, 1]], Fm[:, [1, 2]], Fm[:, [2, 0]]], axis=1).reshape(-1, 2), axis=1)
    owner = np.repeat(np.arange(len(Fm)), 3)
    order = np.lexsort((owner, e[:, 1], e[:, 0]))
    e, owner = e[order], owner[order]
    same = np.all(e[1:] == e[:-1], axis=1)
    pairs = np.column_stack([owner[:-1][same], owner[1:][same]])
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    return V, Fm, normals, areas, pairs


def _csr(n: int, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    both = np.concatenate([pairs, pairs[:, ::-1]])
    both = both[np.lexsort((both[:, 1], both[:, 0]))]
    start = np.searchsorted(both[:, 0], np.arange(n + 1))
    return start, both[:, 1]


# --------------------------------------------------------------------------- planar regions


def _planar_regions(V: np.ndarray, Fm: np.ndarray, normals: np.ndarray, areas: np.ndarray, pairs: np.ndarray,
                    cos_tol: float, dist_tol: float) -> np.ndarray:
    n = len(Fm)
    start, nbr = _csr(n, pairs)
    cent = V[Fm].mean(axis=1)
    order = np.lexsort((cent[:, 2], cent[:, 1], cent[:, 0], -np.round(areas, 9)))
    label = np.full(n, -1, np.int64)
    k = 0
    for seed in order:
        if label[seed] >= 0:
            continue
        n0 = normals[seed]
        p0 = cent[seed]
        label[seed] = k
        stack = [int(seed)]
        if areas[seed] > 0:
            while stack:
                f = stack.pop()
                for g in nbr[start[f]:start[f + 1]]:
                    if label[g] >= 0 or areas[g] <= 0 or normals[g] @ n0 < cos_tol:
                        continue
                    if np.abs((V[Fm[g]] - p0) @ n0).max() > dist_tol:
                        continue
                    label[g] = k
                    stack.append(int(g))
        k += 1
    return label


# --------------------------------------------------------------------------- primitives


def _vertices_of(Fm: np.ndarray, faces: np.ndarray, V: np.ndarray) -> np.ndarray:
    return V[np.unique(Fm[faces].ravel())]


def _residual(prim: dict[str, Any], P: np.ndarray) -> np.ndarray:
    kind = prim["kind"]
    if kind == "cylinder":
        d = P - prim["point"]
        a = prim["direction"]
        return np.linalg.norm(d - (d @ a)[:, None] * a, axis=1) - prim["radius"]
    if kind == "sphere":
        return np.linalg.norm(P - prim["centre"], axis=1) - prim["radius"]
    if kind == "cone":
        d = P - prim["apex"]
        a = prim["axis"]
        h = d @ a
        rho = np.linalg.norm(d - h[:, None] * a, axis=1)
        al = np.radians(prim["half_angle_deg"])
        return rho * np.cos(al) - h * np.sin(al)
    if kind == "torus":
        d = P - prim["centre"]
        h = d @ prim["axis"]
        rho = np.linalg.norm(d - h[:, None] * prim["axis"], axis=1)
        return np.hypot(rho - prim["major_radius"], h) - prim["minor_radius"]
    raise ValueError(kind)


def _fit_primitives(P: np.ndarray, nrm: np.ndarray, wts: np.ndarray, cent: np.ndarray, tol: float,
                    size: float, torus: bool = True) -> dict[str, Any] | None:
    """The simplest primitive (sphere, cylinder, cone; a torus when none of them and ``torus``)
    that holds the vertices ``P`` (M, 3) of facets with normals ``nrm`` (K, 3), areas ``wts``
    (K,), centroids ``cent`` (K, 3)."""
    if len(P) < 6 or len(nrm) < 3:
        return None
    M = (nrm * wts[:, None]).T @ nrm
    ev, vec = np.linalg.eigh(M / max(wts.sum(), 1e-300))
    # How far the facet normals turn: a curved feature turns them by at least _MIN_TURN_DEG.
    spread = float(np.degrees(np.arccos(np.clip((nrm @ nrm.T).min(), -1.0, 1.0)))) if len(nrm) < 2000 else 180.0
    if spread < _MIN_TURN_DEG:
        return None
    cands: list[tuple[int, float, dict[str, Any]]] = []

    def judge(prim: dict[str, Any], nparams: int) -> None:
        r = np.abs(_residual(prim, P))
        if not np.isfinite(r).all():
            return
        if np.quantile(r, _HOLD) <= tol and r.max() <= 4.0 * tol:
            cands.append((nparams, float(np.sqrt(np.mean(r * r))), prim))

    # The normals' own scatter: normals on one circle of the unit sphere (a surface of
    # revolution cut by facets between rings: a cone or a cylinder) are no sphere, even when
    # two rings of vertices lie on one (they always do).
    mu = (nrm * wts[:, None]).sum(0) / wts.sum()
    C = ((nrm - mu) * wts[:, None]).T @ (nrm - mu) / max(wts.sum(), 1e-300)
    cev, cvec = np.linalg.eigh(C)
    on_circle = cev[0] < 1e-7
    # sphere: the facets' normal lines all pass near the centre
    if ev[0] > 1e-3 and not on_circle:
        f = fits.fit_sphere(P)
        if f.params and f.params["radius"] < size:
            judge({"kind": "sphere", "centre": f.params["centre"], "radius": f.params["radius"]}, 4)
    # cylinder: the axis most perpendicular to every normal
    a0 = vec[:, 0]
    if ev[0] < 1e-3:
        f = fits.fit_cylinder(P, axis=a0)
        if f.params and f.params["radius"] < size:
            judge({"kind": "cylinder", "point": f.params["point"], "direction": f.params["direction"],
                   "radius": f.params["radius"]}, 5)
    # cone: the normals lie on a circle of the unit sphere; its plane's normal is the axis
    ax = cvec[:, 0]
    s = float(mu @ ax)
    if 1e-3 < abs(s) < 0.999:
        # apex: the point nearest to every facet plane
        Apl = (nrm * wts[:, None]).T @ nrm
        bpl = (nrm * wts[:, None]).T @ np.einsum("ij,ij->i", nrm, cent)
        if np.linalg.cond(Apl) < 1e10:
            apex = np.linalg.solve(Apl, bpl)
            axis = ax if ((P - apex) @ ax).mean() > 0 else -ax
            half = float(np.degrees(np.arcsin(min(abs(s), 1.0))))
            f = fits.fit_cone(P, axis=axis, apex=apex, half_angle_deg=half)
            if f.params and 0.5 < f.params["half_angle_deg"] < 89.5 and np.linalg.norm(f.params["apex"] - P.mean(0)) < 2 * size:
                judge({"kind": "cone", "apex": f.params["apex"], "axis": f.params["axis"],
                       "half_angle_deg": f.params["half_angle_deg"]}, 6)
    if not cands and torus:
        # A torus only when no simpler primitive holds the vertices: with seven parameters it
        # would hold many a patch of a cylinder, cone or sphere as well, so the simplest that
        # holds still wins -- and meshes without tori pay nothing for it.
        tor = _torus(P, nrm, wts, cent, size)
        if tor is not None:
            judge(tor, 7)
    if not cands:
        return None
    cands.sort(key=lambda c: (c[0], c[1]))
    best = cands[0]
    for c in cands[1:]:
        if c[1] < best[1] / 3.0:
            best = c
    return best[2]


def _torus(P: np.ndarray, nrm: np.ndarray, wts: np.ndarray, cent: np.ndarray, size: float) -> dict[str, Any] | None:
    """A torus fitted to the vertices ``P`` (M, 3), its axis started as the line that every
    facet's normal line (through its centroid ``cent``; weight: area ``wts``) meets, as those of
    a surface of revolution do: in Plücker coordinates, ``n_i . m + m_i . a = 0`` for each facet
    line ``(n_i, m_i)`` -- the least-squares null vector ``(a, m)`` of a linear system."""
    cw = (cent * wts[:, None]).sum(0) / max(float(wts.sum()), 1e-300)
    A = np.column_stack([np.cross(cent - cw, nrm) / size, nrm]) * np.sqrt(wts)[:, None]
    v = np.linalg.svd(A, full_matrices=False)[2][-1]
    a, m = v[:3], v[3:] * size
    na = float(np.linalg.norm(a))
    if na < 1e-6:  # the normals all perpendicular to one direction: a cylinder's, not a torus's
        return None
    f = fits.fit_torus(P, axis=a / na, centre=cw + np.cross(a, m) / na ** 2)
    return _torus_of(f) if f.params and max(f.params["minor_radius"], f.params["major_radius"]) < size else None


def _torus_of(f: fits.Fit) -> dict[str, Any] | None:
    return {"kind": "torus", **{k: f.params[k] for k in ("centre", "axis", "major_radius", "minor_radius")}} if f.params else None


# --------------------------------------------------------------------------- segmentation


def find_features(vertices: np.ndarray, faces: np.ndarray, *, angle_tol_deg: float = 1.0, dist_tol_mm: float = 0.02,
                  smooth_deg: float = 20.0, min_area_mm2: float | None = None) -> list[Feature]:
    """Segment a triangle mesh into primitive features.

    Parameters
    ----------
    vertices : (V, 3) float
        mm.
    faces : (F, 3) int
    angle_tol_deg : float
        Largest angle between the normals of two triangles of one plane, degrees (below the
        angle between the facets of the finest curved surface).
    dist_tol_mm : float
        Largest distance of a vertex from its feature's surface, mm (above the chord error of
        vertices that booleans put on a facet).
    smooth_deg : float
        Largest dihedral angle between two facets of one curved surface, degrees.
    min_area_mm2 : float, optional
        Smallest plane reported, mm^2; default: 0.2 % of the mesh's area.

    Returns
    -------
    list of Feature
        Ordered by id.

    Raises
    ------
    ValueError
        Malformed arrays or tolerances.
    """
    mesh = _checked_mesh(vertices, faces, angle_tol_deg, dist_tol_mm, smooth_deg)
    if mesh is None:
        return []
    V, Fm, normals, areas, pairs = mesh_topology(mesh[0], mesh[1].astype(np.int64))
    total = float(areas.sum())
    min_area = 0.002 * total if min_area_mm2 is None else float(min_area_mm2)
    size = float(np.linalg.norm(np.ptp(V, axis=0)))
    cent = V[Fm].mean(axis=1)
    label = _planar_regions(V, Fm, normals, areas, pairs, float(np.cos(np.radians(angle_tol_deg))), dist_tol_mm)
    nreg = int(label.max()) + 1
    reg_area, reg_normal, reg_cent = _region_stats(label, nreg, normals, areas, cent)
    members = _members(label, nreg)

    rp, groups = _smooth_groups(label, nreg, pairs, normals, reg_area, smooth_deg)
    rstart, rnbr = _csr(nreg, rp)

    found: list[tuple[str, dict[str, Any], np.ndarray]] = []
    used = np.zeros(nreg, bool)
    tol = dist_tol_mm

    def region_data(regs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        fcs = np.concatenate([members[r] for r in regs])
        return fcs, _vertices_of(Fm, fcs, V), normals[fcs], areas[fcs], cent[fcs]

    for g in groups:
        if len(g) < 3:
            continue
        fcs, P, nrm, wts, cc = region_data(g)
        prim = _fit_primitives(P, nrm, wts, cc, tol, size)
        if prim is not None:
            found.append((prim["kind"], prim, fcs))
            used[g] = True
            continue
        # Split: grow from seeds (largest region first), accepting what the primitive holds.
        in_g = np.zeros(nreg, bool)
        in_g[g] = True
        seeds = sorted(g, key=lambda r: (-round(float(reg_area[r]), 9), *np.round(reg_cent[r], 6)))
        tried = 0
        for seed in seeds:
            if used[seed]:
                continue
            tried += 1
            if tried > _MAX_SEEDS:  # a free-form surface (a spring's coil, a twisted blade)
                break
            grown = _grow(int(seed), in_g, used, rstart, rnbr, V, Fm, members, normals, areas, cent, tol, size)
            if grown is not None:
                prim, regs = grown
                used[regs] = True
                found.append((prim["kind"], prim, np.concatenate([members[r] for r in regs])))
        for prim, regs in _leftover_tori(len(g), in_g & ~used, rp, nreg, region_data, tol, size):
            used[regs] = True
            found.append(("torus", prim, region_data(regs)[0]))

    found = _merge_curved(_absorb_tori(found, label, used, members, pairs, V, Fm, tol), pairs, len(Fm), V, Fm, tol)
    for r in range(nreg):
        if not used[r] and reg_area[r] >= min_area and reg_area[r] > 0:
            n_ = reg_normal[r]
            found.append(("plane", {"kind": "plane", "point": reg_cent[r], "normal": n_}, members[r]))

    feats = [_feature(kind, prim, np.sort(fcs), V, Fm, normals, areas, cent) for kind, prim, fcs in found]
    feats.sort(key=lambda f: (KINDS.index(f.kind), -round(f.area_mm2, 6),
                              *(round(x, 4) for x in _anchor(f))))
    width = max(2, len(str(len(feats))))
    return [Feature(f"F{k + 1:0{width}d}", f.kind, f.nominal, f.faces, f.area_mm2, f.triangles) for k, f in enumerate(feats)]


def _checked_mesh(vertices: np.ndarray, faces: np.ndarray, angle_tol_deg: float, dist_tol_mm: float,
                  smooth_deg: float) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`find_features`'s arguments checked: the (V, 3) float vertices (mm) and (F, 3)
    faces as arrays, or ``None`` for a mesh without faces.

    Raises
    ------
    ValueError
        Malformed arrays or tolerances.
    """
    Vin = np.asarray(vertices, float)
    Fin = np.asarray(faces)
    if Vin.ndim != 2 or Vin.shape[1] != 3 or Fin.ndim != 2 or Fin.shape[1] != 3:
        raise ValueError(f"vertices must be (V, 3) and faces (F, 3), got {Vin.shape} and {Fin.shape}")
    if len(Fin) == 0:
        return None
    if not np.isfinite(Vin).all():
        raise ValueError("vertices hold non-finite values")
    if Fin.min() < 0 or Fin.max() >= len(Vin):
        raise ValueError("faces index vertices that do not exist")
    if not (0 < angle_tol_deg < smooth_deg < 90) or dist_tol_mm <= 0:
        raise ValueError("need 0 < angle_tol_deg < smooth_deg < 90 and dist_tol_mm > 0")
    return Vin, Fin


def _region_stats(label: np.ndarray, nreg: int, normals: np.ndarray, areas: np.ndarray,
                  cent: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Area, mean normal and centroid of each planar region.

    Parameters
    ----------
    label : (F,) int
        Planar region of each triangle (``0 .. nreg - 1``).
    nreg : int
        Regions.
    normals : (F, 3) float
        Unit triangle normals.
    areas : (F,) float
        Triangle areas, mm^2.
    cent : (F, 3) float
        Triangle centroids, mm.

    Returns
    -------
    reg_area : (nreg,) float
        mm^2.
    reg_normal : (nreg, 3) float
        Area-weighted mean normal, unit.
    reg_cent : (nreg, 3) float
        Area-weighted centroid, mm.
    """
    reg_area = np.bincount(label, weights=areas, minlength=nreg)
    reg_normal = np.zeros((nreg, 3))
    np.add.at(reg_normal, label, normals * areas[:, None])
    reg_normal /= np.maximum(np.linalg.norm(reg_normal, axis=1), 1e-300)[:, None]
    reg_cent = np.zeros((nreg, 3))
    np.add.at(reg_cent, label, cent * areas[:, None])
    reg_cent /= np.maximum(reg_area, 1e-300)[:, None]
    return reg_area, reg_normal, reg_cent


def _smooth_groups(label: np.ndarray, nreg: int, pairs: np.ndarray, normals: np.ndarray, reg_area: np.ndarray,
                   smooth_deg: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """Planar regions meeting at a dihedral angle below ``smooth_deg``, in connected groups; a
    region more than ``_LARGE`` times its group's median area is a face of its own (a
    tangent plane) and joins no group.

    Parameters
    ----------
    label : (F,) int
        Planar region of each triangle.
    nreg : int
        Regions.
    pairs : (E, 2) int
        Edge-adjacent triangles.
    normals : (F, 3) float
        Unit triangle normals.
    reg_area : (nreg,) float
        Region areas, mm^2.
    smooth_deg : float
        Largest dihedral angle between two facets of one curved surface, degrees.

    Returns
    -------
    rp : (P, 2) int
        Smoothly adjacent region pairs (sorted, unique), the large regions' left out.
    groups : list of (k,) int
        Connected groups of regions over ``rp``.
    """
    la, lb = label[pairs[:, 0]], label[pairs[:, 1]]
    cos_smooth = float(np.cos(np.radians(smooth_deg)))
    sm = (la != lb) & (np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]]) > cos_smooth)
    rp = np.unique(np.sort(np.column_stack([la[sm], lb[sm]]), axis=1), axis=0)
    groups = _components(nreg, rp)
    # A region much larger than its group's median is a face of its own (tangent plane).
    large = np.zeros(nreg, bool)
    for g in groups:
        if len(g) > 1:
            med = float(np.median(reg_area[g]))
            large[g] = reg_area[g] > _LARGE * med
    keep = ~large[rp[:, 0]] & ~large[rp[:, 1]]
    # Large regions smoothly adjacent to each other (a cylinder's long facets next to a tangent
    # fillet's small ones) form groups of their own, with the same rule within them.
    rp2 = rp[large[rp[:, 0]] & large[rp[:, 1]]]
    large2 = np.zeros(nreg, bool)
    for g in _components(nreg, rp2) if len(rp2) else []:
        if len(g) > 1:
            large2[g] = reg_area[g] > _LARGE * float(np.median(reg_area[g]))
    rp = np.concatenate([rp[keep], rp2[~large2[rp2[:, 0]] & ~large2[rp2[:, 1]]]])
    return rp, _components(nreg, rp)


def _merge_curved(found: list[tuple[str, dict[str, Any], np.ndarray]], pairs: np.ndarray, nfaces: int, V: np.ndarray,
                  Fm: np.ndarray, tol: float) -> list[tuple[str, dict[str, Any], np.ndarray]]:
    """Curved features that share an edge and one primitive (a surface split at a seam, or
    grown from two seeds) become one."""
    if len(found) < 2:
        return found
    owner = np.full(nfaces, -1, np.int64)
    for k, (_, _, fcs) in enumerate(found):
        owner[fcs] = k
    oa, ob = owner[pairs[:, 0]], owner[pairs[:, 1]]
    touch = np.unique(np.sort(np.column_stack([oa, ob])[(oa >= 0) & (ob >= 0) & (oa != ob)], axis=1), axis=0)
    parent = list(range(len(found)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b in touch:
        ka, pa, fa = found[a]
        kb, pb, fb = found[b]
        if ka != kb:
            continue
        if (np.abs(_residual(pa, _vertices_of(Fm, fb, V))).max() <= tol
                and np.abs(_residual(pb, _vertices_of(Fm, fa, V))).max() <= tol):
            parent[root(int(b))] = root(int(a))
    groups: dict[int, list[int]] = {}
    for k in range(len(found)):
        groups.setdefault(root(k), []).append(k)
    out = []
    for ks in groups.values():
        big = max(ks, key=lambda k: len(found[k][2]))
        out.append((found[big][0], found[big][1], np.concatenate([found[k][2] for k in ks])))
    return out


def _absorb_tori(found: list[tuple[str, dict[str, Any], np.ndarray]], label: np.ndarray, used: np.ndarray,
                 members: list[np.ndarray], pairs: np.ndarray, V: np.ndarray, Fm: np.ndarray,
                 tol: float) -> list[tuple[str, dict[str, Any], np.ndarray]]:
    """Tori with the unused planar regions and other curved features that touch them and lie on
    them (``used`` updated): where a torus faces along its axis (next to the face a fillet blends
    into) its facets turn so little that a few grow into one region too large for the smooth
    group -- and a ring of such regions, between two circles of vertices, is a cone."""
    nf = len(found)
    piece = np.full(len(Fm), -1, np.int64)  # each triangle's feature, or nf + its unused region
    for j, (_, _, fcs) in enumerate(found):
        piece[fcs] = j
    free = ~used[label]
    piece[free] = nf + label[free]
    for k in range(nf):
        kind, prim, fcs = found[k]
        while kind == "torus":
            mine = piece == k
            touch = np.unique(np.concatenate([piece[pairs[mine[pairs[:, 0]], 1]], piece[pairs[mine[pairs[:, 1]], 0]]]))
            new = [int(j) for j in touch if j >= 0 and j != k and (j >= nf or found[j][0] != "torus")
                   and np.abs(_residual(prim, _vertices_of(Fm, np.flatnonzero(piece == j), V))).max() <= tol]
            if not new:
                break
            piece[np.isin(piece, new)] = k
            fcs = np.flatnonzero(piece == k)
        found[k] = (kind, prim, fcs)
    ours = (piece >= 0) & (piece < nf)
    used[label[ours]] = True
    return [found[j] for j in np.unique(piece[ours])]


def _members(label: np.ndarray, n: int) -> list[np.ndarray]:
    order = np.argsort(label, kind="stable")
    bounds = np.searchsorted(label[order], np.arange(n + 1))
    return [order[bounds[k]:bounds[k + 1]] for k in range(n)]


def _components(n: int, pairs: np.ndarray) -> list[np.ndarray]:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)) if len(pairs) else coo_matrix((n, n))
    _, lab = connected_components(g, directed=False)
    order = np.argsort(lab, kind="stable")
    bounds = np.searchsorted(lab[order], np.arange(lab.max() + 2))
    return [order[bounds[k]:bounds[k + 1]] for k in range(lab.max() + 1)]


def _grow(seed: int, in_g: np.ndarray, used: np.ndarray, rstart: np.ndarray, rnbr: np.ndarray, V: np.ndarray,
          Fm: np.ndarray, members: list[np.ndarray], normals: np.ndarray, areas: np.ndarray, cent: np.ndarray,
          tol: float, size: float) -> tuple[dict[str, Any], np.ndarray] | None:
    """A primitive grown from ``seed`` over smooth neighbours in its group, or None."""
    regs = [seed]
    seen = {seed}
    q: deque[int] = deque([seed])
    while q and len(regs) < _SEED_REGIONS:  # the seed's neighbourhood, accepted as it is
        r = q.popleft()
        for s in rnbr[rstart[r]:rstart[r + 1]]:
            s = int(s)
            if s not in seen and in_g[s] and not used[s]:
                seen.add(s)
                regs.append(s)
                q.append(s)
                if len(regs) >= _SEED_REGIONS:
                    break

    def fit(rs: list[int]) -> dict[str, Any] | None:
        fcs = np.concatenate([members[r] for r in rs])
        return _fit_primitives(_vertices_of(Fm, fcs, V), normals[fcs], areas[fcs], cent[fcs], tol, size, torus=False)

    prim = fit(regs)
    if prim is None:
        return None
    frontier = deque(int(s) for r in regs for s in rnbr[rstart[r]:rstart[r + 1]])
    last = len(regs)
    while frontier:
        s = frontier.popleft()
        if s in seen or not in_g[s] or used[s]:
            continue
        seen.add(s)
        P = _vertices_of(Fm, members[s], V)
        if np.abs(_residual(prim, P)).max() > tol:
            seen.discard(s)  # may join later, under a refined primitive
            continue
        regs.append(s)
        frontier.extend(int(t) for t in rnbr[rstart[s]:rstart[s + 1]])
        if len(regs) > 1.3 * last:
            refit = fit(regs)
            if refit is None:
                regs.pop()
                break
            prim, last = refit, len(regs)
    final = fit(regs)
    if final is None:
        return None
    return final, np.array(regs)


def _leftover_tori(n: int, left: np.ndarray, rp: np.ndarray, nreg: int, region_data: Any, tol: float,
                   size: float) -> list[tuple[dict[str, Any], np.ndarray]]:
    """Tori in what the seeds of a split group of ``n`` regions ``left``: each smoothly connected
    part (3 regions or more, not all) that a torus holds and no simpler primitive does. Tori are
    not grown from seeds -- a few facets of any bent tube (a spring's coil) are one within the
    tolerance -- but a fillet next to the faces it blends is what is left once they have grown."""
    out = []
    for regs in _components(nreg, rp[left[rp[:, 0]] & left[rp[:, 1]]]):
        if not left[regs[0]] or len(regs) < 3 or len(regs) == n:
            continue
        _, P, nrm, wts, cc = region_data(regs)
        prim = _fit_primitives(P, nrm, wts, cc, tol, size)
        if prim is not None and prim["kind"] == "torus":
            out.append((prim, regs))
    return out


def _refine(prim: dict[str, Any], P: np.ndarray) -> dict[str, Any]:
    """The primitive refitted to the vertices that lie on the true surface.

    A tessellation's own vertices lie on the surface and every point of its facets lies
    inside it (nearer the axis or centre); the vertices a boolean adds lie on facets. So the
    vertices farthest out are the exact ones: when there are enough of them, the primitive is
    refitted to them alone (a least-squares fit to all the vertices would come out up to the
    chord error small: a rod of radius 3 cut by a sphere, 2.9987).
    """
    kind = prim["kind"]
    cur = prim
    found = False
    # Peel towards the outer envelope: the outer fifth of the vertices, then those within a
    # window of the outermost that shrinks to 10 nm (at least 8), refitted each time.
    for window in (None, 1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 1e-5, 1e-5):
        r = _residual(cur, P)
        top = r >= (np.quantile(r, 0.8) if window is None else r.max() - window)
        if top.sum() < 8:
            top = np.zeros(len(P), bool)
            top[np.argsort(r)[-8:]] = True
        new = _fit_kind(kind, cur, P[top])
        if new is None:
            break
        cur = new
        found = window == 1e-5 and np.abs(_residual(new, P[top])).max() <= 1e-5
    if found:
        r2 = _residual(cur, P)
        if r2.max() <= 1e-5 and np.quantile(np.abs(r2), _HOLD) <= 2.0 * np.quantile(np.abs(_residual(prim, P)), _HOLD) + 1e-6:
            return cur
    if kind in ("cylinder", "sphere"):
        return {**prim, "radius": prim["radius"] + float(_residual(prim, P).max())}  # through the outermost vertices
    return prim


def _fit_kind(kind: str, prim: dict[str, Any], Q: np.ndarray) -> dict[str, Any] | None:
    if kind == "cylinder":
        f = fits.fit_cylinder(Q, axis=prim["direction"], point=prim["point"], radius=prim["radius"])
        return {"kind": kind, "point": f.params["point"], "direction": f.params["direction"],
                "radius": f.params["radius"]} if f.params else None
    if kind == "sphere":
        f = fits.fit_sphere(Q)
        return {"kind": kind, "centre": f.params["centre"], "radius": f.params["radius"]} if f.params else None
    if kind == "torus":
        return _torus_of(fits.fit_torus(Q, axis=prim["axis"], centre=prim["centre"], major_radius=prim["major_radius"],
                                        minor_radius=prim["minor_radius"]))
    f = fits.fit_cone(Q, axis=prim["axis"], apex=prim["apex"], half_angle_deg=prim["half_angle_deg"])
    return {"kind": kind, "apex": f.params["apex"], "axis": f.params["axis"],
            "half_angle_deg": f.params["half_angle_deg"]} if f.params else None


def _anchor(f: Feature) -> tuple[float, ...]:
    nm = f.nominal
    for key in ("point", "centre", "apex"):
        if key in nm:
            return tuple(nm[key])
    return (0.0, 0.0, 0.0)


def _canonical(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, float)
    a = a / np.linalg.norm(a)
    return a if a[np.argmax(np.abs(a))] > 0 else -a


def _feature(kind: str, prim: dict[str, Any], fcs: np.ndarray, V: np.ndarray, Fm: np.ndarray, normals: np.ndarray,
             areas: np.ndarray, cent: np.ndarray) -> Feature:
    area = float(areas[fcs].sum())
    w = areas[fcs]
    c = (cent[fcs] * w[:, None]).sum(0) / max(area, 1e-300)
    nrm = normals[fcs]
    nominal: dict[str, Any]
    if kind == "plane":
        n_ = (nrm * w[:, None]).sum(0)
        n_ /= np.linalg.norm(n_)
        nominal = {"point": _tuple(c), "normal": _tuple(n_)}
    elif kind == "cylinder":
        P = _vertices_of(Fm, fcs, V)
        prim = _refine(prim, P)
        a = _canonical(prim["direction"])
        h = (P - prim["point"]) @ a
        mid = prim["point"] + 0.5 * (h.min() + h.max()) * a
        radial = cent[fcs] - mid - ((cent[fcs] - mid) @ a)[:, None] * a
        convex = float(np.einsum("ij,ij->i", radial, nrm) @ w) > 0
        nominal = {"point": _tuple(mid), "direction": _tuple(a), "radius": float(prim["radius"]),
                   "length": float(np.ptp(h)), "convex": bool(convex)}
    elif kind == "cone":
        prim = _refine(prim, _vertices_of(Fm, fcs, V))
        apex, a = prim["apex"], prim["axis"] / np.linalg.norm(prim["axis"])
        radial = cent[fcs] - apex - ((cent[fcs] - apex) @ a)[:, None] * a
        convex = float(np.einsum("ij,ij->i", radial, nrm) @ w) > 0
        nominal = {"apex": _tuple(apex), "axis": _tuple(a), "half_angle_deg": float(prim["half_angle_deg"]),
                   "convex": bool(convex)}
    elif kind == "sphere":
        prim = _refine(prim, _vertices_of(Fm, fcs, V))
        ctr = prim["centre"]
        convex = float(np.einsum("ij,ij->i", cent[fcs] - ctr, nrm) @ w) > 0
        nominal = {"centre": _tuple(ctr), "radius": float(prim["radius"]), "convex": bool(convex)}
    else:  # torus
        prim = _refine(prim, _vertices_of(Fm, fcs, V))
        step = 1e-3 * float(prim["minor_radius"])  # convex: the facets face out of the tube
        convex = float((_residual(prim, cent[fcs] + step * nrm) - _residual(prim, cent[fcs])) @ w) > 0
        nominal = {"centre": _tuple(prim["centre"]), "axis": _tuple(_canonical(prim["axis"])),
                   "major_radius": float(prim["major_radius"]), "minor_radius": float(prim["minor_radius"]),
                   "convex": bool(convex)}
    fcs.setflags(write=False)
    return Feature("", kind, nominal, fcs, area, int(len(fcs)))
