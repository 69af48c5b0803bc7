"""Foreign capture writer: CAD-like parts the product has never seen, rendered by another program.

This module is deliberately independent of the product: it imports nothing from
``inspector``, ``inspector_plugins`` or ``inspector_drivers``. It builds its own parts
(trimesh + manifold3d), its own rig (golden-spiral sphere, random roll; 16 cameras, or
8, 12, ...), its own exact anti-aliased silhouette renderer (shapely polygon union + exact
pixel-box areas) and writes capture folders in the CONTRACT format of ``docs/architecture.md``:

    <root>/captures/<name>/rig.json, images/camNN.png, capture.json
    <root>/truth/<name>/reference.stl   nominal part, part frame (bounding-box centred), mm
    <root>/truth/<name>/true_world.ply  the true surface (pose + defect applied), world mm
    <root>/truth/<name>/truth.json      pose, defect, rig summary, pixel footprint

The truth lives *outside* the capture folder so the product cannot see it.

Conventions (CONTRACT): mm, ``x_cam = R @ x_world + t``, pixel ``(u, v)`` with ``(0, 0)``
the centre of the top-left pixel, ``u`` right, ``v`` down. Pixel ``(j, i)`` therefore covers
the box ``[j - 0.5, j + 0.5] x [i - 0.5, i + 0.5]`` in image coordinates.

Each part also declares its rotational symmetry group (:data:`SYMMETRY`, rotations in the
part frame), verified on the mesh by ``selfcheck`` (:func:`check_symmetry`): pose errors are
measured up to it (``pose_sweep.py``).

CLI::

    python tests/acceptance/foreign_capture.py selfcheck [--parts flange hub] [--quick]
    python tests/acceptance/foreign_capture.py write ROOT --part hexnut --condition grey \
        --defect scale --seed 3 [--scale 0.97] [--cameras 8]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import shapely
import trimesh
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

__all__ = [
    "CONDITIONS",
    "DEFECTS",
    "PARTS",
    "SYMMETRY",
    "Camera",
    "check_symmetry",
    "OPTICS",
    "coverage",
    "empty_field",
    "fibonacci_rig",
    "make_capture",
    "make_part",
    "optics_image",
    "self_check",
    "silhouette",
    "symmetry_group",
    "to_image",
    "vignetting",
]

#: Imaging conditions with what real optics do to an image (issue 26): the ``grey`` condition
#: (anti-aliased, noise sigma 2) with one effect, or all of them, applied to the noise-free
#: image before the noise (:func:`optics_image`). ``reference``: the capture holds the empty
#: field of each camera (``background/<cam>.png``, :func:`empty_field`: the same vignetting and
#: dust, 4 frames averaged); the ``-noref`` variants leave it out (the product must then model
#: the background itself). Effects: ``vignetting`` the background's level at the image corners
#: (radial polynomial, 1 at the centre); ``dust`` dark specks per camera, 1-4 px across, 30-90 %
#: deep, in the same places in every capture of that camera; ``bloom`` (fraction of the light,
#: halo radius px); ``defocus`` Gaussian sigma px; ``motion`` blur length px along a direction
#: fixed per camera.
OPTICS: dict[str, dict[str, Any]] = {
    "vignetting": {"vignetting": 0.6, "reference": True},
    "vignetting-noref": {"vignetting": 0.6, "reference": False},
    "dust": {"dust": 40, "reference": True},
    "dust-noref": {"dust": 40, "reference": False},
    "blooming": {"bloom": (0.15, 6.0), "reference": False},
    "defocus": {"defocus": 1.5, "reference": False},
    "motion": {"motion": 3.0, "reference": False},
    "optics": {"vignetting": 0.6, "dust": 40, "bloom": (0.15, 6.0), "defocus": 1.5, "motion": 3.0, "reference": True},
    "optics-noref": {"vignetting": 0.6, "dust": 40, "bloom": (0.15, 6.0), "defocus": 1.5, "motion": 3.0,
                     "reference": False},
}
#: Imaging conditions of the acceptance requirement, and ``exact``: what the silhouettes
#: themselves allow (no noise, 16-bit, so the image is the exact coverage to 1/50000); then
#: the optics conditions (:data:`OPTICS`).
CONDITIONS = ("grey", "binary", "strong", "exact", *OPTICS)
#: Seed of the dust specks' places (with the camera's index): a property of the rig, the same
#: in every capture.
DUST_SEED = 2600
#: Frames averaged into the empty-field reference image.
REFERENCE_FRAMES = 4
#: Defects applied to the true part (the reference stays nominal).
DEFECTS = ("none", "scale", "bump_removed", "scale_up", "bump_added")
#: Grey levels (background, object) for a dark object on a bright (backlit) background.
LEVELS_DARK = (200.0, 40.0)

# Round features: enough sections that the part looks round, not more (the truth is
# the mesh itself and the product is given the same nominal mesh as reference).
SECTIONS = 128
#: Holes of the silhouette union smaller than this (px^2) are rounding slivers, not geometry.
HOLE_MIN_PX2 = 1e-6


# --------------------------------------------------------------------------- parts


def _union(meshes: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    return trimesh.boolean.union(meshes, engine="manifold")


def _difference(meshes: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    return trimesh.boolean.difference(meshes, engine="manifold")


def _intersection(meshes: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    return trimesh.boolean.intersection(meshes, engine="manifold")


def _cyl(radius: float, p0: tuple[float, float, float], p1: tuple[float, float, float]) -> trimesh.Trimesh:
    """Cylinder of ``radius`` mm with its axis from ``p0`` to ``p1`` (mm)."""
    return trimesh.creation.cylinder(radius=radius, segment=np.array([p0, p1], float), sections=SECTIONS)


def _box(extents: tuple[float, float, float], centre: tuple[float, float, float] = (0, 0, 0)) -> trimesh.Trimesh:
    m = trimesh.creation.box(extents=np.asarray(extents, float))
    m.apply_translation(np.asarray(centre, float))
    return m


def _revolve(profile_rz: list[tuple[float, float]]) -> trimesh.Trimesh:
    """Solid of revolution about z of a closed (r, z) profile whose ends lie on the axis."""
    return trimesh.creation.revolve(np.asarray(profile_rz, float), sections=SECTIONS)


def _torus() -> trimesh.Trimesh:
    """Torus, major radius 11 mm, minor radius 4 mm (30 x 30 x 8 mm)."""
    return trimesh.creation.torus(major_radius=11.0, minor_radius=4.0, major_sections=SECTIONS, minor_sections=64)


def _hexnut() -> trimesh.Trimesh:
    """Hex nut: 30 mm across flats, 12 mm thick, 30 deg chamfered corners, Ø14 bore with 0.8 mm chamfers."""
    r_corner = 15.0 / math.cos(math.pi / 6)
    prism = trimesh.creation.cylinder(radius=r_corner, height=12.0, sections=6)
    # Double cone at 30 deg to the faces, touching them on the across-flats circle.
    k = math.tan(math.radians(60.0))  # dr/dz of a cone at 30 deg to the face plane
    chamfer = _revolve([(0.0, -6.0), (15.0, -6.0), (15.0 + 6.0 * k, 0.0), (15.0, 6.0), (0.0, 6.0)])
    # Bore with 45 deg countersinks, overshooting both faces so the boolean is clean.
    bore = _revolve([(0.0, -7.0), (8.8, -7.0), (7.0, -5.2), (7.0, 5.2), (8.8, 7.0), (0.0, 7.0)])
    return _difference([_intersection([prism, chamfer]), bore])


def _shaft() -> trimesh.Trimesh:
    """Stepped shaft Ø20 x 16 + Ø12 x 16 along z, Ø5 cross hole in the Ø20 step, milled flat on the Ø12 step."""
    body = _union([_cyl(10.0, (0, 0, -16.0), (0, 0, 0.0)), _cyl(6.0, (0, 0, -0.01), (0, 0, 16.0))])
    cross = _cyl(2.5, (-12.0, 0, -8.0), (12.0, 0, -8.0))
    # Flat 4.5 mm from the axis, 10 mm long, ending 2 mm before the end of the shaft.
    flat = _box((4.0, 14.0, 10.0), (4.5 + 2.0, 0.0, 9.0))
    return _difference([body, cross, flat])


def _housing() -> trimesh.Trimesh:
    """Box 26 x 20 x 14 mm, 16 x 10 x 8 mm pocket open on +z, two Ø4 through holes along z."""
    box = _box((26.0, 20.0, 14.0))
    pocket = _box((16.0, 10.0, 8.01), (0.0, 0.0, 7.0 - 4.0 + 0.005))
    holes = [_cyl(2.0, (sx * 10.5, 0.0, -8.0), (sx * 10.5, 0.0, 8.0)) for sx in (-1.0, 1.0)]
    return _difference([box, pocket, *holes])


# Near-symmetric parts (issue 14): the rotation about the axis is fixed only by small
# features (a hole circle, a notch, a keyway, a flat, a missing tooth). Each is built so
# that its declared symmetry group (SYMMETRY below) is exact on the *mesh*, not only on
# the ideal solid: every polygonal circle has a vertex count that the group permutes
# (a multiple of 4 and of twice the hole count, a vertex on the x axis), and repeated
# features are rotated copies of one feature, never re-tessellated translates. Axis: z.


def _rotz(mesh: trimesh.Trimesh, angle: float) -> trimesh.Trimesh:
    """``mesh`` turned by ``angle`` (rad) about the z axis (a copy)."""
    m = mesh.copy()
    m.apply_transform(trimesh.transformations.rotation_matrix(angle, (0.0, 0.0, 1.0)))
    return m


def _sections(n: int, at_least: int = 120) -> int:
    """Vertex count of a round outline that the dihedral group D_n (and the quarter turns that
    keep the bounding box centred) maps onto itself: a multiple of lcm(2n, 4), >= ``at_least``."""
    m = math.lcm(2 * n, 4)
    return m * math.ceil(at_least / m)


def _ncyl(radius: float, z0: float, z1: float, sections: int, centre: tuple[float, float] = (0.0, 0.0)) -> trimesh.Trimesh:
    """Cylinder along z from ``z0`` to ``z1`` (mm) with ``sections`` vertices, one at angle 0."""
    m = trimesh.creation.cylinder(radius=radius, segment=np.array([[0, 0, z0], [0, 0, z1]], float), sections=sections)
    m.apply_translation((centre[0], centre[1], 0.0))
    return m


def _hole_circle(n: int, r_circle: float, r_hole: float, z0: float, z1: float, phase: float = 0.0) -> list[trimesh.Trimesh]:
    """``n`` holes of radius ``r_hole`` on a circle of radius ``r_circle``, the first at angle
    ``phase``: rotated copies of one hole (32 sections, a vertex on its radial line)."""
    one = _ncyl(r_hole, z0, z1, 32, (r_circle, 0.0))
    return [_rotz(one, phase + 2.0 * math.pi * k / n) for k in range(n)]


def _disc_holes(n: int) -> trimesh.Trimesh:
    """Disc Ø46 x 8 mm with ``n`` Ø6 through holes on a Ø30 circle, the first on +x (no bore)."""
    disc = _ncyl(23.0, -4.0, 4.0, _sections(n))
    return _difference([disc, *_hole_circle(n, 15.0, 3.0, -5.0, 5.0)])


def _flange() -> trimesh.Trimesh:
    """Flange: disc Ø50 x 8 with a Ø26 x 10 boss on +z, Ø14 bore, four Ø5 bolt holes on a Ø38 circle (on ±x, ±y).

    50 x 50 x 18 mm.
    """
    disc = _ncyl(25.0, 0.0, 8.0, 128)
    boss = _ncyl(13.0, 7.99, 18.0, 128)
    bore = _ncyl(7.0, -1.0, 19.0, 64)
    return _difference([_union([disc, boss]), bore, *_hole_circle(4, 19.0, 2.5, -1.0, 9.0)])


def _hub() -> trimesh.Trimesh:
    """Hub: disc Ø50 x 10, Ø16 bore, six Ø6 holes on a Ø32 circle (first on +x), a 6 mm wide,
    4.5 mm deep notch in the rim on +x. ~49.9 x 50 x 10 mm."""
    disc = _ncyl(25.0, -5.0, 5.0, _sections(6))
    bore = _ncyl(8.0, -6.0, 6.0, 64)
    notch = _box((6.0, 6.0, 12.0), (25.0 - 4.5 + 3.0, 0.0, 0.0))
    return _difference([disc, bore, notch, *_hole_circle(6, 16.0, 3.0, -6.0, 6.0)])


def _keyshaft() -> trimesh.Trimesh:
    """Keyed shaft along z: Ø20 x 24 stepping to Ø14 x 16 (40 mm long); on the Ø20 step a
    6 mm wide, 3.5 mm deep keyway with round ends, 14 mm long, on +x."""
    body = _union([_ncyl(10.0, -20.0, 4.0, 128), _ncyl(7.0, 3.99, 20.0, 128)])
    # End-milled slot: the cutter's axis is radial (x); round ends of radius 3.
    slot = _box((4.5, 6.0, 8.0), (6.5 + 2.25, 0.0, -10.0))
    ends = [_cyl(3.0, (6.5, 0.0, z), (11.0, 0.0, z)) for z in (-14.0, -6.0)]
    return _difference([body, _union([slot, *ends])])


def _flatshaft() -> trimesh.Trimesh:
    """Shaft Ø20 x 40 along z with a flat 2.5 mm deep (7.5 mm from the axis) and 16 mm long,
    centred on its length, on +x."""
    body = _ncyl(10.0, -20.0, 20.0, 128)
    flat = _box((4.0, 24.0, 16.0), (7.5 + 2.0, 0.0, 0.0))
    return _difference([body, flat])


def _gear(teeth: int = 20, module: float = 2.0, pressure_deg: float = 20.0) -> trimesh.Trimesh:
    """Spur gear, ``teeth`` involute teeth of module ``module`` (Ø44 tip, Ø35 root for 20 x 2),
    10 mm thick, Ø12 bore, the tooth on +x missing."""
    rp = module * teeth / 2.0
    ra, rf = rp + module, rp - 1.25 * module
    rb = rp * math.cos(math.radians(pressure_deg))

    def inv(a: float) -> float:
        return math.tan(a) - a

    half_p = math.pi / (2.0 * teeth) + inv(math.radians(pressure_deg))  # half tooth angle at the base circle
    flank = []
    for r in np.linspace(max(rb, rf), ra, 12):
        a = math.acos(min(rb / r, 1.0))
        flank.append((r, half_p - inv(a)))
    tip = flank[-1][1]
    pts2 = [(rf - 1.0, half_p), *flank, *[(ra, th) for th in np.linspace(tip, 0.0, 4)[1:]]]
    pts2 += [(r, -th) for r, th in pts2]  # mirror about the tooth's centre line (x)
    xy = np.array([(r * math.cos(th), r * math.sin(th)) for r, th in pts2])
    prism = np.concatenate([np.c_[xy, np.full(len(xy), -5.0)], np.c_[xy, np.full(len(xy), 5.0)]])
    tooth = trimesh.convex.convex_hull(prism)
    root = _ncyl(rf, -5.0, 5.0, _sections(teeth, 120))
    body = _union([root, *[_rotz(tooth, 2.0 * math.pi * k / teeth) for k in range(1, teeth)]])
    return _difference([body, _ncyl(6.0, -6.0, 6.0, 64)])


def _cube() -> trimesh.Trimesh:
    """Cube, 30 mm (the optics rows' plain part: long straight silhouette edges and sharp corners)."""
    return _box((30.0, 30.0, 30.0))


def _bracket() -> trimesh.Trimesh:
    """L-bracket 44 x 30 x 30 mm: base plate 44 x 30 x 5 with two Ø5 holes and a 16 x 9 x 2.5 mm
    pocket, flange 44 x 5 x 30 standing on its y = 0 edge with two Ø6 holes."""
    base = _box((44.0, 30.0, 5.0), (0.0, 0.0, -12.5))
    flange = _box((44.0, 5.0, 30.0), (0.0, -12.5, 0.0))
    cutters = [
        *[_cyl(2.5, (x, 6.0, -16.0), (x, 6.0, -9.0)) for x in (-14.0, 14.0)],
        *[_cyl(3.0, (x, -16.0, 5.0), (x, -9.0, 5.0)) for x in (-11.0, 11.0)],
        _box((16.0, 9.0, 3.5), (0.0, 6.0, -10.75)),
    ]
    return _difference([_union([base, flange]), *cutters])


PARTS: dict[str, Any] = {
    "torus": _torus,
    "hexnut": _hexnut,
    "shaft": _shaft,
    "housing": _housing,
    # Near-symmetric parts (issue 14), appended so the matrix's per-part seed offsets stay.
    **{f"disc{n}": (lambda n=n: _disc_holes(n)) for n in range(2, 9)},
    "flange": _flange,
    "hub": _hub,
    "keyshaft": _keyshaft,
    "flatshaft": _flatshaft,
    "gear": _gear,
    # The optics rows' parts (issue 26), appended so the other parts' seed offsets stay.
    "cube": _cube,
    "bracket": _bracket,
}


def make_part(name: str) -> trimesh.Trimesh:
    """Nominal part ``name`` in its part frame: bounding-box centre at the origin, mm.

    The product's ``load_reference`` re-centres a file reference on its bounding-box
    centre; building the parts already centred makes the part frame and the product's
    reference frame the same, so a true pose can be compared with ``result.json``.

    Raises
    ------
    KeyError
        Unknown part name.
    RuntimeError
        The boolean result is not a closed, positively wound solid.
    """
    mesh = PARTS[name]()
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    _check_solid(mesh, name)
    return mesh


def _check_solid(mesh: trimesh.Trimesh, what: str) -> None:
    if not (len(mesh.faces) and mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0):
        raise RuntimeError(f"{what}: not a closed solid (faces={len(mesh.faces)}, watertight={mesh.is_watertight})")


# --------------------------------------------------------------------------- symmetry groups


def _rot(axis: tuple[float, float, float], angle: float) -> np.ndarray:
    return Rotation.from_rotvec(np.asarray(axis, float) / np.linalg.norm(axis) * angle).as_matrix()


def cyclic(n: int) -> list[np.ndarray]:
    """C_n about z: the turns by 2 pi k / n, k = 0 .. n-1 (the first is the identity)."""
    return [np.eye(3)] + [_rot((0, 0, 1), 2.0 * math.pi * k / n) for k in range(1, n)]


def flip(angle: float) -> np.ndarray:
    """Half turn about the in-plane (xy) axis at ``angle`` (rad) from +x."""
    return _rot((math.cos(angle), math.sin(angle), 0.0), math.pi)


def dihedral(n: int) -> list[np.ndarray]:
    """D_n: C_n about z and the n half turns about the in-plane axes at pi k / n from +x."""
    return cyclic(n) + [flip(math.pi * k / n) for k in range(n)]


#: Each part's rotational symmetry group, in its part frame: the rotations ``S`` (3, 3) with
#: ``S @ part == part`` (all about the bounding-box centre, the origin). A pose ``R`` and
#: ``R @ S`` place the part identically. None: no finite group declared (the torus turns
#: freely about its axis; the nut's D6 holds only to the 128-gon's 5 µm sagitta).
SYMMETRY: dict[str, Any] = {
    "torus": None,
    "hexnut": None,
    "shaft": lambda: [np.eye(3)],  # a step, a cross hole and a flat on one side
    "housing": lambda: cyclic(2),  # pocket on +z, holes at ±x: the half turn about z
    # Discs with n holes and nothing else: D_n (through a hole / between holes).
    **{f"disc{n}": (lambda n=n: dihedral(n)) for n in range(2, 9)},
    "flange": lambda: cyclic(4),  # the boss on one side removes the flips
    "hub": lambda: [np.eye(3), flip(0.0)],  # the notch (+x) leaves the flip through it
    "keyshaft": lambda: [np.eye(3)],  # the step removes the flip through the keyway
    "flatshaft": lambda: [np.eye(3), flip(0.0)],  # the flat (+x), centred on the length
    "gear": lambda: [np.eye(3), flip(0.0)],  # the missing tooth (+x): the flip through it
    "cube": lambda: _cube_group(),  # the 24 rotations of the cube
    "bracket": lambda: [np.eye(3)],
}


def _cube_group() -> list[np.ndarray]:
    """The cube's rotation group: the 24 signed permutation matrices of determinant +1."""
    import itertools

    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            S = np.zeros((3, 3))
            S[range(3), perm] = signs
            if np.linalg.det(S) > 0:
                out.append(S)
    return out


def symmetry_group(name: str) -> list[np.ndarray] | None:
    """The declared rotational symmetry group of part ``name`` (list of (3, 3)), or None."""
    f = SYMMETRY[name]
    return None if f is None else [np.asarray(S, float) for S in f()]


def _surface_samples(mesh: trimesh.Trimesh, n: int, rng: np.random.Generator) -> np.ndarray:
    area = mesh.area_faces / mesh.area_faces.sum()
    f = rng.choice(len(mesh.faces), size=n, p=area)
    a, b = rng.random((2, n))
    fl = a + b > 1.0
    a[fl], b[fl] = 1.0 - a[fl], 1.0 - b[fl]
    t = mesh.triangles[f]
    return t[:, 0] + a[:, None] * (t[:, 1] - t[:, 0]) + b[:, None] * (t[:, 2] - t[:, 0])


def _candidate_rotations() -> list[np.ndarray]:
    """Rotations a part about z might also have: turns by 2 pi k / n (n <= 24) and half turns
    about in-plane axes every 3.75 degrees; used to show a declared group is complete."""
    out = [_rot((0, 0, 1), 2.0 * math.pi * k / n) for n in range(2, 25) for k in range(1, n) if math.gcd(k, n) == 1]
    out += [flip(math.pi * j / 48) for j in range(48)]
    out += [_rot(ax, s * math.pi / 2) for ax in ((1, 0, 0), (0, 1, 0)) for s in (1, -1)]
    return out


def _farthest(P: np.ndarray, tol: float, index: Any) -> tuple[bool, float]:
    """Whether some point of ``P`` is at least ``tol`` from the mesh of ``index``, exactly, and a
    distance: the largest exact one found (a lower bound of the maximum) when so, else the
    maximum (exact above 1e-7 mm). Open3D's upper bounds are refined exactly, largest first,
    a few at a time (``index``: measure.TriangleIndex of the mesh)."""
    ub = index.distances(P)
    order = np.argsort(ub)[::-1]
    order = order[ub[order] >= min(tol, 1e-7)]
    for lo, hi in ((0, 16), (16, 256), (256, len(order))):
        idx = order[lo:hi]
        if idx.size == 0:
            break
        ex = index.refine(P[idx], ub[idx])
        if ex.max() >= tol:
            return True, float(ex.max())
        ub[idx] = ex
    return False, float(ub.max())


def check_symmetry(name: str, *, n: int = 20000, tol_mm: float = 1e-3, complete: bool = True,
                   verbose: bool = False) -> dict[str, Any]:
    """Verify part ``name``'s declared symmetry group on its mesh.

    Checks: every element is a proper rotation; the set is a group (closed under products);
    each element maps the surface onto itself (``n`` seeded surface samples and all vertices,
    moved by ``S``, lie within ``tol_mm`` of the surface: since the group holds each inverse,
    this bounds the symmetric Hausdorff distance on those samples); and the group is
    complete among :func:`_candidate_rotations` (none outside it maps the surface onto itself;
    skipped when ``complete`` is False).

    Returns
    -------
    dict
        ``order``; ``worst_mm`` (the largest distance over the group, exact above 1e-7 mm);
        ``nearest_other_mm`` (a lower bound of the smallest sampled Hausdorff distance of a
        candidate outside the group: how near the part comes to a larger symmetry) and
        ``nearest_other`` (that candidate as a rotation vector, degrees).

    Raises
    ------
    AssertionError
        Any check fails.
    """
    G = symmetry_group(name)
    if G is None:
        return {"part": name, "order": None}
    mesh = make_part(name)
    rng = np.random.default_rng(12345)
    P = np.concatenate([_surface_samples(mesh, n, rng), mesh.vertices])
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    from measure import TriangleIndex  # sibling, product-independent

    index = TriangleIndex(V, F)
    for S in G:
        assert np.allclose(S @ S.T, np.eye(3), atol=1e-12) and abs(np.linalg.det(S) - 1.0) < 1e-12, (name, S)
    for A in G:
        for B in G:
            assert min(np.abs(A @ B - C).max() for C in G) < 1e-9, f"{name}: the declared symmetries are not a group"
    worst = 0.0
    for S in G:
        off, d = _farthest(P @ S.T, tol_mm, index)
        rv = Rotation.from_matrix(S).as_rotvec(degrees=True).round(3)
        assert not off, f"{name}: declared symmetry {rv} (rotation vector, deg) moves the surface by {d:.2e} mm"
        worst = max(worst, d)
    quick = P[rng.choice(len(P), 1000, replace=False)]
    nearest, near_rot = math.inf, None
    for S in _candidate_rotations() if complete else []:
        if min(np.abs(S - C).max() for C in G) < 1e-9:
            continue
        off, d = _farthest(quick @ S.T, tol_mm, index)
        if not off:  # the subset cannot reject it: decide on every sample
            off, d = _farthest(P @ S.T, tol_mm, index)
            assert off, f"{name}: undeclared symmetry {Rotation.from_matrix(S).as_rotvec(degrees=True).round(3)}"
        if d < nearest:
            nearest, near_rot = d, Rotation.from_matrix(S).as_rotvec(degrees=True).round(2).tolist()
    out = {"part": name, "order": len(G), "worst_mm": worst, "nearest_other_mm": nearest, "nearest_other": near_rot}
    if verbose:
        print(f"symmetry {name:9s} order {len(G):2d}: worst {worst:.1e} mm" + (
            f"; complete (nearest candidate outside it: rotation vector {near_rot} deg, >= {nearest:.2f} mm off)"
            if complete else ""))
    return out


# --------------------------------------------------------------------------- pose and defects


def random_pose(rng: np.random.Generator, offset_mm: float = 3.0) -> np.ndarray:
    """Uniformly random rotation and a translation uniform in ``[-offset_mm, offset_mm]^3``.

    Returns
    -------
    (4, 4) float
        Part -> world transform, mm.
    """
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    T[:3, 3] = rng.uniform(-offset_mm, offset_mm, 3)
    return T


def _hull_surface_point(mesh: trimesh.Trimesh, rng: np.random.Generator, n: int = 4000) -> np.ndarray:
    """A random surface point on the convex hull of ``mesh`` (so a removed bump shows in silhouettes).

    Returns
    -------
    (3,) float
        Point on the surface, part frame, mm.
    """
    # Area-weighted face choice with uniform barycentric coordinates (own seeded sampler).
    area = mesh.area_faces / mesh.area_faces.sum()
    faces = rng.choice(len(mesh.faces), size=n, p=area)
    a, b = rng.random((2, n))
    flip = a + b > 1.0
    a[flip], b[flip] = 1.0 - a[flip], 1.0 - b[flip]
    tri = mesh.triangles[faces]
    pts = tri[:, 0] + a[:, None] * (tri[:, 1] - tri[:, 0]) + b[:, None] * (tri[:, 2] - tri[:, 0])
    eq = ConvexHull(mesh.vertices).equations  # (m, 4): n . x + d <= 0 inside
    on_hull = np.max(pts @ eq[:, :3].T + eq[:, 3], axis=1) > -1e-6
    cand = pts[on_hull] if on_hull.any() else pts
    return cand[rng.integers(len(cand))]


def apply_defect(
    nominal: trimesh.Trimesh, defect: str, rng: np.random.Generator, *, scale: float = 0.98, bump_radius_mm: float = 2.5
) -> tuple[trimesh.Trimesh, dict[str, Any]]:
    """The true part: ``nominal`` with ``defect`` applied, in the part frame (mm).

    Parameters
    ----------
    defect : {"none", "scale", "bump_removed", "scale_up", "bump_added"}
        ``scale``: uniform scale by ``scale`` about the part centre (the origin);
        ``bump_removed``: a sphere of ``bump_radius_mm`` centred on a random point of the
        part's convex-hull surface is subtracted (manifold boolean). The excess-material
        variants: ``scale_up`` scales by ``2 - scale`` (1.02), ``bump_added`` adds the
        sphere instead (a bump ``bump_radius_mm`` high).

    Returns
    -------
    mesh : trimesh.Trimesh
        The true part, part frame, mm.
    info : dict
        What was applied (JSON-serialisable).
    """
    mesh = nominal.copy()
    if defect == "none":
        return mesh, {"kind": "none"}
    if defect in ("scale", "scale_up"):
        k = scale if defect == "scale" else 2.0 - scale
        mesh.apply_scale(k)
        return mesh, {"kind": defect, "scale": k}
    if defect in ("bump_removed", "bump_added"):
        at = _hull_surface_point(nominal, rng)
        ball = trimesh.creation.icosphere(subdivisions=4, radius=bump_radius_mm)
        ball.apply_translation(at)
        mesh = _difference([mesh, ball]) if defect == "bump_removed" else _union([mesh, ball])
        _check_solid(mesh, defect)
        return mesh, {"kind": defect, "at_mm": at.tolist(), "radius_mm": bump_radius_mm}
    raise ValueError(f"unknown defect {defect!r} (known: {', '.join(DEFECTS)})")


# --------------------------------------------------------------------------- rig


@dataclass(frozen=True)
class Camera:
    """Pinhole camera without distortion (CONTRACT conventions).

    Attributes
    ----------
    K : (3, 3) float
        Intrinsics, px.
    R : (3, 3) float
        World -> camera rotation.
    t : (3,) float
        World -> camera translation, mm.
    """

    name: str
    width: int
    height: int
    K: np.ndarray = field(repr=False)
    R: np.ndarray = field(repr=False)
    t: np.ndarray = field(repr=False)

    @property
    def centre(self) -> np.ndarray:
        """Optical centre in the world, (3,) mm."""
        return -self.R.T @ self.t

    def project(self, X: np.ndarray) -> np.ndarray:
        """Project world points ``X`` (n, 3) mm to pixels (n, 2) ``(u, v)``."""
        xc = X @ self.R.T + self.t
        uvw = xc @ self.K.T
        return uvw[:, :2] / uvw[:, 2:3]

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "width": self.width, "height": self.height, "K": self.K.tolist(),
                "dist": [0.0] * 5, "R": self.R.tolist(), "t": self.t.tolist()}


def _look_at(centre: np.ndarray, roll: float) -> tuple[np.ndarray, np.ndarray]:
    """World -> camera ``R`` (3, 3), ``t`` (3,) mm for a camera at ``centre`` looking at the origin.

    OpenCV axes: z forward, x right, y down; ``roll`` (rad) turns the camera about z.
    """
    z = -centre / np.linalg.norm(centre)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.95 else np.array([1.0, 0.0, 0.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = math.cos(roll), math.sin(roll)
    x, y = c * x + s * y, -s * x + c * y
    R = np.stack([x, y, z])
    return R, -R @ centre


def fibonacci_rig(
    n: int = 16, *, radius_mm: float = 400.0, width: int = 1024, height: int = 1024, focal_px: float = 4000.0, seed: int = 7
) -> list[Camera]:
    """``n`` cameras on a golden-spiral sphere of ``radius_mm``, looking at the origin.

    Each camera gets a seeded random roll about its optical axis. The principal point is
    the image centre ``((width - 1) / 2, (height - 1) / 2)`` (pixel (0, 0) is a centre).
    """
    rng = np.random.default_rng(seed)
    golden = math.pi * (3.0 - math.sqrt(5.0))
    K = np.array([[focal_px, 0.0, (width - 1) / 2.0], [0.0, focal_px, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
    cams = []
    for i in range(n):
        zc = 1.0 - (2.0 * i + 1.0) / n
        r = math.sqrt(1.0 - zc * zc)
        d = np.array([r * math.cos(golden * i), r * math.sin(golden * i), zc])
        R, t = _look_at(radius_mm * d, rng.uniform(-math.pi, math.pi))
        cams.append(Camera(f"cam{i:02d}", width, height, K.copy(), R, t))
    return cams


# --------------------------------------------------------------------------- exact silhouette rendering


def silhouette(mesh: trimesh.Trimesh, cam: Camera) -> shapely.Geometry:
    """Exact silhouette of a closed mesh in the image of ``cam``: a (multi)polygon in pixels.

    The silhouette of a closed mesh is the union of the projections of its faces that
    face the camera (every ray that meets the solid enters it through such a face), so
    back faces are skipped. Holes (seeing through a bore) are kept.
    """
    tri = mesh.triangles  # (f, 3, 3) world mm
    to_cam = cam.centre - tri[:, 0]
    front = np.einsum("ij,ij->i", mesh.face_normals, to_cam) > 0.0
    tri = tri[front]
    uv = cam.project(tri.reshape(-1, 3)).reshape(-1, 3, 2)
    a = uv[:, 1] - uv[:, 0]
    b = uv[:, 2] - uv[:, 0]
    keep = np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]) > 1e-12  # edge-on faces add no area
    ring = np.concatenate([uv[keep], uv[keep][:, :1]], axis=1)  # (k, 4, 2) closed rings
    union = shapely.union_all(shapely.polygons(ring))
    # Rounding in the union leaves sliver "holes" of ~1e-15 px^2 along shared edges; they
    # are not geometry (and GEOS' rectangle clipper rejects them), real holes are >> 1 px^2.
    polys = []
    for p in shapely.get_parts(union):
        holes = [r for r in p.interiors if shapely.Polygon(r).area > HOLE_MIN_PX2]
        polys.append(shapely.Polygon(p.exterior, holes))
    return shapely.MultiPolygon(polys) if len(polys) > 1 else polys[0]


def coverage(geom: shapely.Geometry, width: int, height: int, tile: int = 16) -> np.ndarray:
    """Exact area coverage of each pixel by ``geom`` (pixel coordinates, CONTRACT convention).

    Works on the bounding box of ``geom`` only, in ``tile`` x ``tile`` blocks: blocks that
    miss the boundary are wholly in or out; in the others the area of (pixel box ∩ geom)
    is computed exactly with vectorised shapely.

    Returns
    -------
    (height, width) float64
        Fraction of each pixel's area inside ``geom``, in [0, 1].
    """
    cov = np.zeros((height, width))
    if geom.is_empty:
        return cov
    minx, miny, maxx, maxy = geom.bounds
    j0, j1 = max(math.floor(minx + 0.5), 0), min(math.floor(maxx + 0.5), width - 1)
    i0, i1 = max(math.floor(miny + 0.5), 0), min(math.floor(maxy + 0.5), height - 1)
    if j1 < j0 or i1 < i0:
        return cov
    TJ, TI = (g.ravel() for g in np.meshgrid(np.arange(j0, j1 + 1, tile), np.arange(i0, i1 + 1, tile)))
    TJe, TIe = np.minimum(TJ + tile, j1 + 1), np.minimum(TI + tile, i1 + 1)  # exclusive ends
    x0, x1, y0, y1 = TJ - 0.5, TJe - 0.5, TI - 0.5, TIe - 0.5
    boundary = geom.boundary
    shapely.prepare(boundary)
    shapely.prepare(geom)
    on_edge = shapely.intersects(boundary, shapely.box(x0, y0, x1, y1))
    full = ~on_edge & shapely.contains_xy(geom, (x0 + x1) / 2, (y0 + y1) / 2)
    for k in np.flatnonzero(full):
        cov[TI[k]:TIe[k], TJ[k]:TJe[k]] = 1.0
    pieces, jj, ii = [], [], []
    for k in np.flatnonzero(on_edge):
        # Clip to the block first so each pixel intersection works on a small polygon.
        piece = shapely.clip_by_rect(geom, x0[k], y0[k], x1[k], y1[k])
        J, I = np.meshgrid(np.arange(TJ[k], TJe[k]), np.arange(TI[k], TIe[k]))
        pieces.append(np.full(J.size, piece, dtype=object))
        jj.append(J.ravel())
        ii.append(I.ravel())
    if pieces:
        jj, ii = np.concatenate(jj), np.concatenate(ii)
        boxes = shapely.box(jj - 0.5, ii - 0.5, jj + 0.5, ii + 0.5)
        cov[ii, jj] = np.clip(shapely.area(shapely.intersection(np.concatenate(pieces), boxes)), 0.0, 1.0)
    return cov


def to_image(cov: np.ndarray, condition: str, polarity: str, rng: np.random.Generator) -> np.ndarray:
    """Image of a silhouette coverage map under an imaging ``condition``.

    Parameters
    ----------
    cov : (h, w) float
        Area coverage in [0, 1].
    condition : {"grey", "binary", "strong", "exact"}
        ``grey``: anti-aliased (linear in coverage), Gaussian noise sigma 2;
        ``binary``: hard edges (coverage >= 0.5), noise sigma 2;
        ``strong``: anti-aliased, sigma 6, and 1 % of the pixels replaced by 0 or 255;
        ``exact``: anti-aliased, no noise, 16-bit (levels x 257).
    polarity : {"dark-object", "bright-object"}

    Returns
    -------
    (h, w) uint8, or uint16 for ``exact``
    """
    bg, fg = LEVELS_DARK if polarity == "dark-object" else LEVELS_DARK[::-1]
    if condition == "exact":
        return np.rint(257.0 * (bg + (fg - bg) * cov)).astype(np.uint16)
    if condition == "binary":
        cov = (cov >= 0.5).astype(float)
    sigma = {"grey": 2.0, "binary": 2.0, "strong": 6.0}[condition]
    img = bg + (fg - bg) * cov + rng.normal(0.0, sigma, cov.shape)
    if condition == "strong":
        hit = rng.random(cov.shape) < 0.01
        img[hit] = np.where(rng.random(int(hit.sum())) < 0.5, 0.0, 255.0)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


# --------------------------------------------------------------------------- real optics (issue 26)


def vignetting(height: int, width: int, corner: float) -> np.ndarray:
    """Relative illumination (h, w) float64: 1 at the image centre, ``corner`` at the corners,
    a radial polynomial ``1 - (1 - corner) (0.6 rho^2 + 0.4 rho^4)`` (``rho``: distance from the
    centre over the corner's)."""
    y, x = np.mgrid[0:height, 0:width].astype(float)
    cy, cx = (height - 1) / 2.0, (width - 1) / 2.0
    rho2 = ((x - cx) ** 2 + (y - cy) ** 2) / (cx * cx + cy * cy)
    return 1.0 - (1.0 - corner) * (0.6 * rho2 + 0.4 * rho2 * rho2)


def dust(height: int, width: int, count: int, camera_index: int) -> np.ndarray:
    """Transmission (h, w) float64 of ``count`` dark specks on camera ``camera_index``'s optics:
    discs 1-4 px across, taking 30-90 % of the light at full cover (exact-ish pixel cover, 4x4
    sub-samples), in places fixed by :data:`DUST_SEED` and the camera (the same in every capture)."""
    rng = np.random.default_rng([DUST_SEED, camera_index])
    t = np.ones((height, width))
    sub = (np.arange(4) + 0.5) / 4.0 - 0.5
    for _ in range(count):
        cx, cy = rng.uniform(0, width - 1), rng.uniform(0, height - 1)
        r, depth = rng.uniform(0.5, 2.0), rng.uniform(0.3, 0.9)
        j0, j1 = max(int(cx - r) - 1, 0), min(int(cx + r) + 2, width)
        i0, i1 = max(int(cy - r) - 1, 0), min(int(cy + r) + 2, height)
        jj, ii = np.meshgrid(np.arange(j0, j1), np.arange(i0, i1))
        dx = jj[..., None, None] + sub[None, None, None, :] - cx
        dy = ii[..., None, None] + sub[None, None, :, None] - cy
        cover = ((dx * dx + dy * dy) <= r * r).mean(axis=(2, 3))
        t[i0:i1, j0:j1] *= 1.0 - depth * cover
    return t


def _bloom(img: np.ndarray, fraction: float, radius: float) -> np.ndarray:
    """``fraction`` of the light spread in a Gaussian halo (sigma radius / 2, cut at ``radius``)."""
    n = int(math.ceil(radius))
    y, x = np.mgrid[-n:n + 1, -n:n + 1].astype(float)
    k = np.exp(-(x * x + y * y) / (2.0 * (radius / 2.0) ** 2)) * (x * x + y * y <= radius * radius)
    halo = cv2.filter2D(img, -1, k / k.sum(), borderType=cv2.BORDER_REFLECT)
    return (1.0 - fraction) * img + fraction * halo


def _motion(img: np.ndarray, length: float, angle: float) -> np.ndarray:
    """Box blur of ``length`` px along ``angle`` (rad), centred: the part's position mid-exposure."""
    n = int(math.ceil(length / 2.0)) + 1
    k = np.zeros((2 * n + 1, 2 * n + 1))
    for s in np.linspace(-length / 2.0, length / 2.0, 401):
        x, y = n + s * math.cos(angle), n + s * math.sin(angle)
        j, i = int(math.floor(x)), int(math.floor(y))
        fx, fy = x - j, y - i
        k[i, j] += (1 - fx) * (1 - fy)
        k[i, j + 1] += fx * (1 - fy)
        k[i + 1, j] += (1 - fx) * fy
        k[i + 1, j + 1] += fx * fy
    return cv2.filter2D(img, -1, k / k.sum(), borderType=cv2.BORDER_REFLECT)


def _field(condition: str, height: int, width: int, camera_index: int) -> np.ndarray:
    """What the optics of ``condition`` multiply the image by on this camera (vignetting x dust)."""
    fx = OPTICS[condition]
    t = np.ones((height, width))
    if "vignetting" in fx:
        t *= vignetting(height, width, fx["vignetting"])
    if "dust" in fx:
        t *= dust(height, width, fx["dust"], camera_index)
    return t


def optics_image(cov: np.ndarray, condition: str, polarity: str, rng: np.random.Generator,
                 camera_index: int) -> np.ndarray:
    """Image (h, w) uint8 of a coverage map under an optics ``condition`` (:data:`OPTICS`).

    The noise-free grey image of the ``grey`` condition, then in order: motion blur (its
    direction fixed per camera), defocus, blooming, times vignetting and dust; then Gaussian
    noise sigma 2, rounded.
    """
    fx = OPTICS[condition]
    bg, fg = LEVELS_DARK if polarity == "dark-object" else LEVELS_DARK[::-1]
    img: np.ndarray = (bg + (fg - bg) * cov).astype(np.float32)
    if "motion" in fx:
        angle = np.random.default_rng([DUST_SEED + 1, camera_index]).uniform(0.0, math.pi)
        img = _motion(img, fx["motion"], angle)
    if "defocus" in fx:
        img = cv2.GaussianBlur(img, (0, 0), fx["defocus"], borderType=cv2.BORDER_REFLECT)
    if "bloom" in fx:
        img = _bloom(img, *fx["bloom"])
    h, w = cov.shape
    img = img * _field(condition, h, w, camera_index) + rng.normal(0.0, 2.0, cov.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def empty_field(condition: str, polarity: str, shape: tuple[int, int], rng: np.random.Generator,
                camera_index: int) -> np.ndarray:
    """The empty rig's image (h, w) uint8 of one camera under ``condition``: the background level
    times vignetting and dust, :data:`REFERENCE_FRAMES` noisy frames averaged."""
    bg = (LEVELS_DARK if polarity == "dark-object" else LEVELS_DARK[::-1])[0]
    clean = bg * _field(condition, shape[0], shape[1], camera_index)
    frames = [clean + rng.normal(0.0, 2.0, shape) for _ in range(REFERENCE_FRAMES)]
    return np.clip(np.rint(np.mean(frames, axis=0)), 0, 255).astype(np.uint8)


# --------------------------------------------------------------------------- capture folders


def footprint_mm(cams: list[Camera], centre: np.ndarray) -> float:
    """Mean pixel footprint at ``centre`` (3,) mm: camera distance / focal length, mm per px."""
    return float(np.mean([np.linalg.norm(c.centre - centre) / c.K[0, 0] for c in cams]))


def make_capture(
    root: str | Path,
    part: str,
    condition: str = "grey",
    defect: str = "none",
    *,
    seed: int = 0,
    polarity: str = "dark-object",
    name: str | None = None,
    rig_seed: int = 7,
    cameras: int = 16,
    scale: float = 0.98,
) -> dict[str, Any]:
    """Write one capture folder and its truth (outside the capture folder).

    Parameters
    ----------
    root : path
        Output root; ``root/captures/<name>/`` and ``root/truth/<name>/`` are written.
    part : str
        One of :data:`PARTS`.
    condition : str
        One of :data:`CONDITIONS`.
    defect : str
        One of :data:`DEFECTS`.
    seed : int
        Seeds the pose, the defect and the image noise. The pose does not depend on
        ``defect`` for the scale defects (nor on ``cameras`` or ``condition``): the same seed
        puts a nominal and a scaled part in the same pose.
    cameras : int
        Cameras of the golden-spiral rig (16, the paper's; 8 and 12 for the smaller rigs).
    scale : float
        The ``scale`` defect's factor (``scale_up``: ``2 - scale``).

    Returns
    -------
    dict
        ``capture`` (folder), ``reference`` (STL), ``true_mesh`` (PLY), ``truth`` (JSON), ``name``,
        ``render_s`` (seconds spent rendering) and ``defect_visible`` (whether the defect
        changes any camera's silhouette by more than 1 px^2).
    """
    if condition not in CONDITIONS:
        raise ValueError(f"unknown condition {condition!r} (known: {', '.join(CONDITIONS)})")
    name = name or f"{part}-{condition}-{defect}-s{seed}" + ("" if cameras == 16 else f"-c{cameras}")
    root = Path(root)
    cap, tdir = root / "captures" / name, root / "truth" / name
    (cap / "images").mkdir(parents=True, exist_ok=True)
    tdir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)

    nominal = make_part(part)
    true_part, defect_info = apply_defect(nominal, defect, rng, scale=scale)
    pose = random_pose(rng)
    world = true_part.copy()
    world.apply_transform(pose)
    cams = fibonacci_rig(cameras, seed=rig_seed)

    posed_nominal = nominal.copy()
    posed_nominal.apply_transform(pose)
    t0 = time.perf_counter()
    change = []
    for k, cam in enumerate(cams):
        sil = silhouette(world, cam)
        # How much of the defect any silhouette shows at all (px^2): a dent that no camera
        # sees on its contour is invisible to every silhouette method.
        change.append(0.0 if defect == "none" else float(sil.symmetric_difference(silhouette(posed_nominal, cam)).area))
        cov = coverage(sil, cam.width, cam.height)
        # Exactness guard: the pixel areas add up to the silhouette's area inside the image.
        inside = shapely.clip_by_rect(sil, -0.5, -0.5, cam.width - 0.5, cam.height - 0.5).area
        if abs(cov.sum() - inside) > 1e-6:
            raise AssertionError(f"{name} {cam.name}: coverage sum {cov.sum():.9f} != silhouette area {inside:.9f}")
        img = (optics_image(cov, condition, polarity, rng, k) if condition in OPTICS
               else to_image(cov, condition, polarity, rng))
        if not cv2.imwrite(str(cap / "images" / f"{cam.name}.png"), img):
            raise OSError(f"could not write {cap / 'images' / cam.name}.png")
        if condition in OPTICS and OPTICS[condition]["reference"]:
            (cap / "background").mkdir(exist_ok=True)
            ref = empty_field(condition, polarity, cov.shape, np.random.default_rng([seed, 1 + k]), k)
            if not cv2.imwrite(str(cap / "background" / f"{cam.name}.png"), ref):
                raise OSError(f"could not write {cap / 'background' / cam.name}.png")
    render_s = time.perf_counter() - t0

    (cap / "rig.json").write_text(json.dumps({"units": "mm", "cameras": [c.to_json() for c in cams]}, indent=1))
    (cap / "capture.json").write_text(json.dumps({
        "part_id": part, "timestamp": "2025-01-01T00:00:00+00:00", "polarity": polarity,
        "writer": "tests/acceptance/foreign_capture.py", "condition": condition,
    }, indent=1))
    nominal.export(tdir / "reference.stl")
    world.export(tdir / "true_world.ply")
    # Exact float64 vertices as well: the PLY is what a viewer opens, the npz what we measure on.
    np.savez(tdir / "true_world.npz", vertices=world.vertices, faces=world.faces)
    truth = {
        "part": part, "condition": condition, "defect": defect_info, "seed": seed, "polarity": polarity,
        "optics": OPTICS.get(condition),
        "pose": pose.tolist(), "footprint_mm": footprint_mm(cams, pose[:3, 3]),
        "silhouette_change_px2": change,
        "symmetry": None if SYMMETRY.get(part) is None else [S.tolist() for S in symmetry_group(part)],
        "rig": {"cameras": len(cams), "radius_mm": 400.0, "focal_px": 4000.0, "size_px": [1024, 1024], "seed": rig_seed},
    }
    (tdir / "truth.json").write_text(json.dumps(truth, indent=1))
    return {"name": name, "capture": cap, "reference": tdir / "reference.stl", "true_mesh": tdir / "true_world.npz",
            "truth": tdir / "truth.json", "render_s": render_s, "defect_visible": sum(change) > 1.0}


# --------------------------------------------------------------------------- self-check


def self_check(verbose: bool = False) -> float:
    """Check the renderer's exactness on polygons whose pixel areas are known.

    Returns the largest error found; raises ``AssertionError`` above 1e-6.
    """
    worst = 0.0
    W = H = 64
    # Unit square at a sub-pixel offset: four known partial areas, sum 1.
    sq = shapely.box(10.3, 20.7, 11.3, 21.7)
    c = coverage(sq, W, H)
    want = np.zeros((H, W))
    want[21, 10], want[21, 11], want[22, 10], want[22, 11] = 0.2 * 0.8, 0.8 * 0.8, 0.2 * 0.2, 0.8 * 0.2
    worst = max(worst, np.abs(c - want).max())
    # Triangle and a polygon with a hole: coverage sums to the area.
    tri = shapely.Polygon([(3.21, 4.87), (50.13, 9.4), (20.5, 58.02)])
    ring = shapely.Point(31.7, 30.2).buffer(20.3, 64).difference(shapely.Point(33.1, 29.9).buffer(7.7, 64))
    for g in (tri, ring):
        worst = max(worst, abs(coverage(g, W, H).sum() - g.area))
    # Half plane x <= 10.3: column 10 is 0.8 covered; slanted edge through a pixel: trapezoid.
    half = shapely.box(-5.0, -5.0, 10.3, 70.0)
    c = coverage(half, W, H)
    worst = max(worst, np.abs(c[:, 10] - 0.8).max(), np.abs(c[:, :10] - 1.0).max(), np.abs(c[:, 11:]).max())
    slant = shapely.Polygon([(-5.0, -5.0), (30.0 + 0.25 * 35, -5.0), (30.0 - 0.25 * 40, 70.0), (-5.0, 70.0)])
    c = coverage(slant, W, H)  # edge x = 30 - 0.25 (y - 30): in row 30, x spans [29.875, 30.125]
    worst = max(worst, abs(c[30, 30] - 0.5), abs(c[30, 29] - 1.0), abs(c[30, 31]))
    if verbose:
        print(f"renderer self-check: worst error {worst:.2e}")
    assert worst < 1e-6, worst
    return worst


# --------------------------------------------------------------------------- CLI


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    sc = sub.add_parser("selfcheck", help="check the renderer's exactness and every declared part symmetry")
    sc.add_argument("--parts", nargs="+", choices=sorted(PARTS), default=list(PARTS), help="parts whose symmetry to check")
    sc.add_argument("--no-symmetry", action="store_true", help="the renderer only")
    sc.add_argument("--quick", action="store_true", help="the declared groups only, not their completeness")
    w = sub.add_parser("write", help="write one capture folder + truth")
    w.add_argument("root", type=Path)
    w.add_argument("--part", choices=sorted(PARTS), required=True)
    w.add_argument("--condition", choices=CONDITIONS, default="grey")
    w.add_argument("--defect", choices=DEFECTS, default="none")
    w.add_argument("--scale", type=float, default=0.98, help="factor of the scale defect (scale_up: 2 - scale)")
    w.add_argument("--cameras", type=int, default=16, help="cameras of the golden-spiral rig (e.g. 8, 12, 16)")
    w.add_argument("--polarity", choices=("dark-object", "bright-object"), default="dark-object")
    w.add_argument("--seed", type=int, default=0)
    w.add_argument("--name")
    args = ap.parse_args(argv)
    if args.cmd == "selfcheck":
        self_check(verbose=True)
        if not args.no_symmetry:
            for p in args.parts:
                if SYMMETRY.get(p) is None:
                    print(f"symmetry {p:9s} none declared")
                else:
                    check_symmetry(p, verbose=True, complete=not args.quick)
        return 0
    res = make_capture(args.root, args.part, args.condition, args.defect, seed=args.seed,
                       polarity=args.polarity, name=args.name, cameras=args.cameras, scale=args.scale)
    print(json.dumps({k: str(v) for k, v in res.items()}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
