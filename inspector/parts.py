"""Built-in procedural parts, synthetic defects and loading of reference meshes.

Every mesh returned here is a closed, consistently wound triangle mesh (positive
volume) in millimetres. The built-in parts are expressed in their *reference frame*:
the centre of their axis-aligned bounding box is the origin. Solids are built from
:mod:`trimesh.creation` primitives combined with the ``manifold`` boolean engine;
the only hand-written geometry is a twist (a per-vertex rotation).

Defects (:func:`apply_defects`) are applied in the reference frame and the result
is *not* re-centred, so the defects stay where they were asked for.
"""

from __future__ import annotations

import functools
import math
import os
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from inspector.errors import ReferenceMeshError
from inspector.limits import limit

if TYPE_CHECKING:  # pragma: no cover
    import trimesh

__all__ = [
    "BUILTIN_PARTS",
    "Bump",
    "apply_defects",
    "load_reference",
    "make_part",
    "part_names",
    "random_bumps",
]

#: Largest distance, mm, between a tessellated sphere and the true sphere.
SPHERE_TOL_MM = 0.005

#: Prefix of a reference spec that names a built-in part.
BUILTIN_PREFIX = "builtin:"

#: File suffixes :func:`load_reference` accepts.
MESH_SUFFIXES = (".stl", ".ply", ".obj")

BUILTIN_PARTS: dict[str, str] = {
    "cube30": "30 mm cube",
    "sphere30": "sphere of diameter 30 mm (facet error < 0.005 mm)",
    "cube_sphere": "20 mm cube joined to a sphere of diameter 16 mm by a cylinder of diameter 6 mm",
    "turbine_blade": "root block 24x14x10 mm with a 20x3 mm blade plate, tip rounded by a sphere, twisted 25 deg over its 45 mm span",
    "spring": "helical coil spring: 5 turns, coil diameter 20 mm, wire diameter 3 mm, pitch 6 mm",
    "gauge": "step gauge: 40x20 mm base, 4 steps of 10 mm depth and 5 mm height",
    "bracket": "L-bracket 60x40x6 mm with a 40 mm flange, 4 through holes and a 20x12x3 mm pocket",
}


# --------------------------------------------------------------------------- helpers


@functools.cache
def _unit_icosphere_error(subdivisions: int) -> float:
    """Largest distance between the unit sphere and the facets of an icosphere."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    d = np.abs(np.einsum("ij,ij->i", m.face_normals, m.triangles[:, 0]))
    return float(1.0 - d.min())


def _sphere(radius: float, centre: Sequence[float] = (0.0, 0.0, 0.0), *, tol_mm: float = SPHERE_TOL_MM,
            max_subdivisions: int = 5) -> trimesh.Trimesh:
    """Icosphere with the fewest subdivisions whose facet error is below ``tol_mm``.

    Parameters
    ----------
    radius : float
        Radius, mm. Vertices lie on the sphere (the facets are inside it).
    centre : (3,) float
        Centre, mm.
    tol_mm : float
        Largest allowed distance between a facet and the sphere, mm.
    max_subdivisions : int
        Cap on the subdivisions (5 -> 20480 faces).
    """
    import trimesh

    subdivisions = max_subdivisions
    for s in range(1, max_subdivisions + 1):
        if radius * _unit_icosphere_error(s) < tol_mm:
            subdivisions = s
            break
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=float(radius))
    m.apply_translation(np.asarray(centre, dtype=float))
    return m


def _box(extents: Sequence[float], centre: Sequence[float] = (0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    """Axis-aligned box of ``extents`` (3,) mm centred on ``centre`` (3,) mm."""
    import trimesh

    m = trimesh.creation.box(extents=np.asarray(extents, dtype=float))
    m.apply_translation(np.asarray(centre, dtype=float))
    return m


def _cylinder(radius: float, p0: Sequence[float], p1: Sequence[float], sections: int = 64) -> trimesh.Trimesh:
    """Cylinder of ``radius`` mm whose axis runs from ``p0`` to ``p1`` (3,) mm."""
    import trimesh

    return trimesh.creation.cylinder(radius=float(radius), segment=np.array([p0, p1], dtype=float), sections=sections)


def _union(meshes: Sequence[trimesh.Trimesh]) -> trimesh.Trimesh:
    import trimesh

    return trimesh.boolean.union(list(meshes), engine="manifold")


def _difference(meshes: Sequence[trimesh.Trimesh]) -> trimesh.Trimesh:
    import trimesh

    return trimesh.boolean.difference(list(meshes), engine="manifold")


def _intersection(meshes: Sequence[trimesh.Trimesh]) -> trimesh.Trimesh:
    import trimesh

    return trimesh.boolean.intersection(list(meshes), engine="manifold")


def _centre(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Move ``mesh`` in place so its bounding-box centre is the origin; return it."""
    mesh.apply_translation(-mesh.bounds.mean(axis=0))
    return mesh


def _check_solid(mesh: trimesh.Trimesh, what: str) -> trimesh.Trimesh:
    """Raise ``RuntimeError`` unless ``mesh`` is a closed, positively wound solid."""
    if len(mesh.faces) == 0 or not mesh.is_watertight or not mesh.is_winding_consistent or mesh.volume <= 0:
        raise RuntimeError(
            f"{what}: not a closed solid (faces={len(mesh.faces)}, watertight={mesh.is_watertight}, "
            f"winding={mesh.is_winding_consistent}, volume={mesh.volume:.3f})"
        )
    return mesh


def _twist_z(mesh: trimesh.Trimesh, degrees: float, z0: float, z1: float) -> trimesh.Trimesh:
    """Rotate vertices about the z axis by an angle growing linearly from ``z0`` to ``z1``.

    Vertices below ``z0`` are not moved, vertices above ``z1`` turn by ``degrees``.
    Connectivity is unchanged, so a closed mesh stays closed.
    """
    import trimesh

    v = mesh.vertices.copy()
    a = np.radians(degrees) * np.clip((v[:, 2] - z0) / (z1 - z0), 0.0, 1.0)
    c, s = np.cos(a), np.sin(a)
    x, y = v[:, 0].copy(), v[:, 1].copy()
    v[:, 0] = c * x - s * y
    v[:, 1] = s * x + c * y
    return trimesh.Trimesh(vertices=v, faces=mesh.faces.copy(), process=False)


def _subdivide(mesh: trimesh.Trimesh, times: int) -> trimesh.Trimesh:
    """Split every triangle into four, ``times`` times (keeps a closed mesh closed)."""
    for _ in range(times):
        mesh = mesh.subdivide()
    return mesh


# --------------------------------------------------------------------------- parts


def _cube30() -> trimesh.Trimesh:
    return _box((30.0, 30.0, 30.0))


def _sphere30() -> trimesh.Trimesh:
    return _sphere(15.0)


def _cube_sphere() -> trimesh.Trimesh:
    # Along x: cube [-10, 10], rod x in [5, 20], sphere centred at x = 25 (r = 8).
    cube = _box((20.0, 20.0, 20.0))
    rod = _cylinder(3.0, (5.0, 0.0, 0.0), (20.0, 0.0, 0.0), sections=64)
    ball = _sphere(8.0, (25.0, 0.0, 0.0))
    return _union([cube, rod, ball])


def _turbine_blade() -> trimesh.Trimesh:
    # Root block z in [0, 10]; blade plate (chord 20 along x, thickness 3 along y)
    # z in [8, 58], sunk 2 mm into the root. The blade is twisted by 25 deg from the
    # root top (z = 10) to its tip (z = 55), then rounded by the sphere of radius 25
    # centred at z = 30 on the twist axis: the tip is cut to z = 55 on the axis and
    # z = 52.9 at the leading and trailing edges.
    # A sphere centred on the axis is invariant under the twist, so
    # twist(plate) & sphere == twist(plate & sphere): doing the twist first keeps the
    # sphere facets exact and lets the twist act on a regular grid.
    root = _box((24.0, 14.0, 10.0), (0.0, 0.0, 5.0))
    plate = _box((20.0, 3.0, 50.0), (0.0, 0.0, 33.0))
    plate = _subdivide(plate, 4)  # 16 segments per edge: ~3 mm along the span
    plate = _twist_z(plate, 25.0, 10.0, 55.0)
    _check_solid(plate, "turbine_blade plate")
    cutter = _sphere(25.0, (0.0, 0.0, 30.0))
    blade = _intersection([plate, cutter])
    return _union([root, blade])


def _spring() -> trimesh.Trimesh:
    import shapely.geometry
    import trimesh

    turns, coil_r, wire_r, pitch = 5, 10.0, 1.5, 6.0
    per_turn = 72  # 5 deg steps: chord error 10 * (1 - cos 2.5 deg) = 0.01 mm
    t = np.linspace(0.0, 2.0 * np.pi * turns, turns * per_turn + 1)
    helix = np.column_stack([coil_r * np.cos(t), coil_r * np.sin(t), pitch * t / (2.0 * np.pi)])
    profile = shapely.geometry.Point(0.0, 0.0).buffer(wire_r, quad_segs=8)  # 32-gon
    mesh = trimesh.creation.sweep_polygon(profile, helix, engine="manifold")
    mesh.merge_vertices()
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def _gauge() -> trimesh.Trimesh:
    # Step i covers x in [10 i, 10 i + 10] and is 5 (i + 1) mm high; base 40 x 20.
    steps = [_box((10.0, 20.0, 5.0 * (i + 1)), (10.0 * i + 5.0, 0.0, 2.5 * (i + 1))) for i in range(4)]
    return _union(steps)


def _bracket() -> trimesh.Trimesh:
    # Base plate 60 (x) x 40 (y) x 6 (z); flange 60 x 6 x 40 standing on the y = 0 edge.
    base = _box((60.0, 40.0, 6.0), (30.0, 20.0, 3.0))
    flange = _box((60.0, 6.0, 40.0), (30.0, 3.0, 20.0))
    body = _union([base, flange])
    cutters = [
        # two vertical holes through the base plate, diameter 6
        _cylinder(3.0, (10.0, 28.0, -1.0), (10.0, 28.0, 7.0)),
        _cylinder(3.0, (50.0, 28.0, -1.0), (50.0, 28.0, 7.0)),
        # two horizontal holes through the flange, diameter 8
        _cylinder(4.0, (15.0, -1.0, 28.0), (15.0, 7.0, 28.0)),
        _cylinder(4.0, (45.0, -1.0, 28.0), (45.0, 7.0, 28.0)),
        # a 20 x 12 x 3 pocket in the top of the base plate
        _box((20.0, 12.0, 4.0), (30.0, 26.0, 5.0)),
    ]
    return _difference([body, *cutters])


_BUILDERS: dict[str, Callable[[], trimesh.Trimesh]] = {
    "cube30": _cube30,
    "sphere30": _sphere30,
    "cube_sphere": _cube_sphere,
    "turbine_blade": _turbine_blade,
    "spring": _spring,
    "gauge": _gauge,
    "bracket": _bracket,
}


def part_names() -> list[str]:
    """Names of the built-in parts, sorted."""
    return sorted(BUILTIN_PARTS)


@functools.cache
def _build(name: str) -> trimesh.Trimesh:
    mesh = _BUILDERS[name]()
    _centre(mesh)
    return _check_solid(mesh, f"built-in part {name!r}")


def make_part(name: str) -> trimesh.Trimesh:
    """Build a built-in part in its reference frame.

    Parameters
    ----------
    name : str
        One of :data:`BUILTIN_PARTS`.

    Returns
    -------
    trimesh.Trimesh
        A fresh copy (safe to modify): closed, positive volume, mm, bounding-box
        centre at the origin.

    Raises
    ------
    ValueError
        If ``name`` is not a built-in part.
    """
    if name not in _BUILDERS:
        raise ValueError(f"unknown built-in part {name!r} (known: {', '.join(part_names())})")
    return _build(name).copy()


# --------------------------------------------------------------------------- defects


@dataclass(frozen=True)
class Bump:
    """A spherical defect.

    Attributes
    ----------
    centre : (3,) tuple of float
        Sphere centre, mm, in the reference frame (normally a point on the surface).
    radius_mm : float
        Sphere radius, mm, > 0.
    kind : {"add", "remove"}
        ``"add"``: material added (union with the sphere); ``"remove"``: material
        missing (difference with the sphere).
    """

    centre: tuple[float, float, float]
    radius_mm: float
    kind: Literal["add", "remove"]

    def __post_init__(self) -> None:
        c = tuple(float(x) for x in np.ravel(np.asarray(self.centre, dtype=float)))
        if len(c) != 3 or not all(math.isfinite(x) for x in c):
            raise ValueError(f"bump centre must be 3 finite numbers, got {self.centre!r}")
        r = float(self.radius_mm)
        if not (math.isfinite(r) and r > 0):
            raise ValueError(f"bump radius must be > 0 mm, got {self.radius_mm!r}")
        if self.kind not in ("add", "remove"):
            raise ValueError(f"bump kind must be 'add' or 'remove', got {self.kind!r}")
        object.__setattr__(self, "centre", c)
        object.__setattr__(self, "radius_mm", r)


def apply_defects(mesh: trimesh.Trimesh, *, scale: float = 1.0, bumps: Sequence[Bump] = ()) -> trimesh.Trimesh:
    """Return a defective copy of ``mesh``.

    The scale is applied first, about the origin of the reference frame; then the
    bumps, one after the other in the given order. Bump centres are in the
    reference frame, i.e. in the *scaled* mesh's coordinates (they are not scaled).
    The result is not re-centred.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Closed mesh, mm, in its reference frame. Not modified.
    scale : float
        Uniform scale factor (> 0); e.g. 0.98 for a part 2 % too small.
    bumps : sequence of Bump

    Returns
    -------
    trimesh.Trimesh
        Closed, positive volume, mm.

    Raises
    ------
    ValueError
        If ``scale`` is not positive, or the bumps leave no solid.
    """
    scale = float(scale)
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be > 0, got {scale!r}")
    out = mesh.copy()
    if scale != 1.0:
        out.apply_scale(scale)
    for bump in bumps:
        if not isinstance(bump, Bump):
            raise TypeError(f"expected a Bump, got {type(bump).__name__}")
        ball = _sphere(bump.radius_mm, bump.centre)
        out = _union([out, ball]) if bump.kind == "add" else _difference([out, ball])
        if len(out.faces) == 0:
            raise ValueError(f"{bump} leaves nothing of the part")
    if len(out.faces) == 0 or not out.is_watertight or out.volume <= 0:
        raise ValueError("defects produced an invalid mesh")
    return out


def random_bumps(
    mesh: trimesh.Trimesh,
    n: int,
    *,
    max_radius_mm: float = 3.0,
    min_radius_mm: float = 0.5,
    kind: str | None = None,
    rng: np.random.Generator,
) -> tuple[Bump, ...]:
    """Draw ``n`` bumps centred on the surface of ``mesh``.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Surface to sample (area-weighted), mm.
    n : int
        Number of bumps, >= 0.
    max_radius_mm, min_radius_mm : float
        Radii are uniform in ``[min_radius_mm, max_radius_mm]``, mm.
    kind : {"add", "remove"} or None
        Kind of every bump; ``None`` draws each one at random.
    rng : numpy.random.Generator
        Source of randomness: the same seed gives the same bumps.

    Returns
    -------
    tuple of Bump
    """
    import trimesh

    n = int(n)
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    if not (0 < min_radius_mm <= max_radius_mm):
        raise ValueError(f"need 0 < min_radius_mm <= max_radius_mm, got {min_radius_mm}, {max_radius_mm}")
    if kind not in (None, "add", "remove"):
        raise ValueError(f"kind must be 'add', 'remove' or None, got {kind!r}")
    if n == 0:
        return ()
    points, _ = trimesh.sample.sample_surface(mesh, n, seed=rng)
    radii = rng.uniform(min_radius_mm, max_radius_mm, size=n)
    kinds = [kind] * n if kind is not None else [("add", "remove")[i] for i in rng.integers(0, 2, size=n)]
    return tuple(Bump(tuple(p), float(r), k) for p, r, k in zip(points, radii, kinds))  # type: ignore[arg-type]


# --------------------------------------------------------------------------- loading


def _short(exc: BaseException, limit: int = 160) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= limit else text[: limit - 3] + "..."


def load_reference(spec: str | os.PathLike, *, recentre: bool = True) -> trimesh.Trimesh:
    """Load the reference mesh of a recipe.

    Parameters
    ----------
    spec : str or path-like
        ``"builtin:NAME"`` for :func:`make_part` ``(NAME)``, otherwise the path of an
        STL, PLY or OBJ file whose units are mm.
    recentre : bool
        Translate a loaded file so its bounding-box centre is the origin (the
        reference frame). The translation applied, (3,) mm, is stored in
        ``mesh.metadata["reference_offset_mm"]``. Built-in parts are always centred.

    Returns
    -------
    trimesh.Trimesh
        Closed, consistently wound mesh with positive volume, mm.

    Raises
    ------
    ReferenceMeshError
        With a one-line message naming the file: the file is missing, unreadable or
        of an unsupported format, larger than the input bounds (:mod:`inspector.limits`:
        ``INSPECTOR_MAX_REFERENCE_BYTES``, ``INSPECTOR_MAX_REFERENCE_TRIANGLES``, checked
        before any file is parsed: a binary STL's or a PLY's header, an ASCII STL's or an
        OBJ's lines counted in bounded memory), holds no triangles, is
        not watertight or not consistently wound; or the built-in name is unknown.
    """
    if isinstance(spec, str) and spec.startswith(BUILTIN_PREFIX):
        name = spec[len(BUILTIN_PREFIX):].strip()
        if name not in _BUILDERS:
            raise ReferenceMeshError(
                f"reference {spec!r}: unknown built-in part {name!r} (known: {', '.join(part_names())})"
            )
        mesh = make_part(name)
        mesh.metadata["reference_offset_mm"] = [0.0, 0.0, 0.0]
        return mesh

    try:
        path = Path(os.fspath(spec))
    except TypeError as exc:
        raise ReferenceMeshError(f"reference mesh {spec!r}: not a path ({_short(exc)})") from None
    where = f"reference mesh {path}"
    if not path.exists():
        raise ReferenceMeshError(f"{where}: file not found")
    if not path.is_file():
        raise ReferenceMeshError(f"{where}: not a file")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ReferenceMeshError(f"{where}: unsupported format {path.suffix!r} (use STL, PLY or OBJ)")

    _check_mesh_size(path, where)
    # Garbage input makes the parsers emit numeric warnings (overflow, NaN casts):
    # the errors below already say what is wrong with the file.
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        mesh = _read_mesh(path, where)
        _check_triangles(len(mesh.faces), where)
        return _validate_mesh(mesh, path, where, recentre)


def _check_triangles(n: int, where: str) -> None:
    most = limit("MAX_REFERENCE_TRIANGLES")
    if n > most:
        raise ReferenceMeshError(
            f"{where}: {n} triangles, more than the {most} a reference mesh may have "
            "(INSPECTOR_MAX_REFERENCE_TRIANGLES; decimate the mesh, or raise the bound)"
        )


def _count_lines(path: Path, starts: tuple[bytes, ...], most: int) -> int:
    """Lines of ``path`` that begin (after blanks) with one of ``starts``, read in 16 MiB
    chunks (bounded memory), stopping once more than ``most`` are counted."""
    import re

    pattern = re.compile(rb"^[ \t]*(?:" + b"|".join(re.escape(s) for s in starts) + rb")", re.M)
    n = 0
    tail = b""
    with open(path, "rb") as f:
        while n <= most:
            chunk = f.read(16 * 2**20)
            if not chunk:
                break
            cut = chunk.rfind(b"\n") + 1  # whole lines only; the rest goes with the next chunk
            if cut == 0:
                tail += chunk
                continue
            n += len(pattern.findall(tail + chunk[:cut]))
            tail = chunk[cut:]
    if tail and n <= most:
        n += len(pattern.findall(tail))
    return n


def _declared_triangles(path: Path, size: int, where: str, most: int) -> int | None:
    """The triangles a file holds, counted before it is parsed, or None when unknown: a
    binary STL's count (its size must match it), a PLY header's ``element face`` (polygons
    count once), an ASCII STL's ``facet`` lines and an OBJ's ``f`` lines (polygons count
    once; streamed, stopping past ``most``). A binary STL whose size does not match its
    count is refused: parsed as ASCII it took 1.8 GB to say "no triangles"."""
    import re
    import struct

    with open(path, "rb") as f:
        head = f.read(65536)
    suffix = path.suffix.lower()
    if head[:3] == b"ply":
        end = head.find(b"end_header")
        m = re.search(rb"^element\s+face\s+(\d+)\s*$", head[: end if end >= 0 else None], re.M)
        return int(m.group(1)) if m else None
    if suffix == ".stl":
        ascii_stl = head.lstrip()[:5].lower() == b"solid" and b"\0" not in head[:1024] and (
            b"facet" in head or len(head) < 84)
        if ascii_stl:
            return _count_lines(path, (b"facet",), most)
        if len(head) < 84:
            raise ReferenceMeshError(f"{where}: {size} bytes, too short for a binary STL (84-byte header)")
        n = struct.unpack("<I", head[80:84])[0]
        if 84 + 50 * n != size:
            raise ReferenceMeshError(
                f"{where}: a binary STL declaring {n} triangles ({84 + 50 * n} bytes) but the file has {size} bytes "
                "(truncated or padded: export it again)")
        return n
    if suffix == ".obj":
        return _count_lines(path, (b"f ", b"f\t"), most)
    return None


def _check_mesh_size(path: Path, where: str) -> None:
    """The input bounds of a reference mesh (:mod:`inspector.limits`), before it is parsed:
    the file's size, and the triangles a binary STL or a PLY header declares or an ASCII STL
    or OBJ holds (counted by streaming the file). ReferenceMeshError in one line."""
    try:
        size = path.stat().st_size
        most = limit("MAX_REFERENCE_BYTES")
        if size > most:
            raise ReferenceMeshError(
                f"{where}: {size} bytes, more than the {most} a reference mesh may have "
                "(INSPECTOR_MAX_REFERENCE_BYTES; decimate the mesh, or raise the bound)"
            )
        n = _declared_triangles(path, size, where, limit("MAX_REFERENCE_TRIANGLES"))
    except OSError as exc:
        raise ReferenceMeshError(f"{where}: cannot be read ({exc.strerror or exc})") from None
    if n is not None:
        _check_triangles(n, where)


def _read_mesh(path: Path, where: str) -> trimesh.Trimesh:
    suffix = path.suffix.lower()
    try:
        import trimesh

        loaded = trimesh.load_mesh(str(path), file_type=suffix[1:], process=True)
        if isinstance(loaded, trimesh.Scene):
            loaded = loaded.to_mesh() if len(loaded.geometry) else trimesh.Trimesh()
        if not isinstance(loaded, trimesh.Trimesh):
            raise ValueError(f"got a {type(loaded).__name__}, not a triangle mesh")
        return loaded
    except Exception as exc:  # noqa: BLE001 - any parser failure is the file's fault
        raise ReferenceMeshError(f"{where}: cannot read ({type(exc).__name__}: {_short(exc)})") from None


def _validate_mesh(mesh: trimesh.Trimesh, path: Path, where: str, recentre: bool) -> trimesh.Trimesh:
    """Clean ``mesh`` (merge vertices, drop degenerate faces) and check it is a closed solid."""
    try:
        faces = np.asarray(mesh.faces)
        vertices = np.asarray(mesh.vertices, dtype=float)
        if faces.ndim != 2 or len(faces) == 0:
            raise ReferenceMeshError(f"{where}: no triangles")
        if not np.all(np.isfinite(vertices)):
            raise ReferenceMeshError(f"{where}: vertices are not finite")
        mesh.merge_vertices()
        mesh.update_faces(mesh.nondegenerate_faces())
        mesh.remove_unreferenced_vertices()
        if len(mesh.faces) == 0:
            raise ReferenceMeshError(f"{where}: no triangles (all degenerate)")
        edges = np.sort(mesh.edges, axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        n_open = int(np.count_nonzero(counts == 1))
        n_multi = int(np.count_nonzero(counts > 2))
        if n_open or n_multi:
            detail = f"{n_open} open edges" + (f", {n_multi} non-manifold edges" if n_multi else "")
            raise ReferenceMeshError(f"{where} is not watertight ({detail})")
        if not mesh.is_winding_consistent:
            raise ReferenceMeshError(f"{where}: faces are not consistently wound")
        volume = float(mesh.volume)
        if not math.isfinite(volume) or volume == 0.0:
            raise ReferenceMeshError(f"{where}: encloses no volume")
        if volume < 0:
            mesh.invert()
        offset = -mesh.bounds.mean(axis=0) if recentre else np.zeros(3)
        if recentre:
            mesh.apply_translation(offset)
        mesh.metadata["reference_offset_mm"] = [float(x) for x in offset]
        mesh.metadata["file_name"] = path.name
        return mesh
    except ReferenceMeshError:
        raise
    except Exception as exc:  # noqa: BLE001 - trimesh's checks raise what they raise: the mesh's fault
        raise ReferenceMeshError(f"{where}: invalid mesh ({type(exc).__name__}: {_short(exc)})") from None
