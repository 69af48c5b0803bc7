"""Built-in parts, defects and reference loading (inspector.parts)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from inspector import parts
from inspector.errors import ReferenceMeshError
from inspector.parts import Bump, apply_defects, load_reference, make_part, part_names, random_bumps


def winding_number(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Generalised winding number of ``points`` (N, 3): ~1 inside, ~0 outside."""
    tri = mesh.triangles[None, :, :, :] - np.asarray(points, float)[:, None, None, :]  # (N, F, 3, 3)
    a, b, c = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
    det = np.einsum("...i,...i->...", a, np.cross(b, c))
    den = (la * lb * lc + np.einsum("...i,...i->...", a, b) * lc
           + np.einsum("...i,...i->...", b, c) * la + np.einsum("...i,...i->...", c, a) * lb)
    return (2.0 * np.arctan2(det, den)).sum(axis=1) / (4.0 * np.pi)


# --------------------------------------------------------------------------- built-ins

EXPECTED = {"cube30", "sphere30", "cube_sphere", "turbine_blade", "spring", "gauge", "bracket"}


def test_names():
    assert set(parts.BUILTIN_PARTS) == EXPECTED
    assert part_names() == sorted(EXPECTED)
    assert all(isinstance(d, str) and d and "\n" not in d for d in parts.BUILTIN_PARTS.values())


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_builtin_is_closed_centred_solid(name):
    m = make_part(name)
    assert isinstance(m, trimesh.Trimesh)
    assert m.is_watertight
    assert m.is_winding_consistent
    assert m.volume > 0
    assert m.body_count == 1
    np.testing.assert_allclose(m.bounds.mean(axis=0), 0.0, atol=1e-9)
    assert 0 < len(m.faces) < 60_000
    # plausible size: a few cm, and the volume a fair fraction of the box
    assert 10.0 < m.extents.max() < 100.0
    assert 0.02 * np.prod(m.extents) < m.volume <= np.prod(m.extents) * (1 + 1e-9)


def test_make_part_returns_fresh_copies():
    a = make_part("cube30")
    a.apply_translation([5.0, 0.0, 0.0])
    b = make_part("cube30")
    np.testing.assert_allclose(b.bounds.mean(axis=0), 0.0)
    assert a is not b


def test_make_part_unknown():
    with pytest.raises(ValueError, match="cube30"):
        make_part("nope")


def test_cube30_volume():
    m = make_part("cube30")
    assert m.volume == pytest.approx(27000.0, rel=1e-3)
    np.testing.assert_allclose(m.extents, 30.0)


def test_sphere30_volume_and_facet_error():
    m = make_part("sphere30")
    assert m.volume == pytest.approx(4.0 / 3.0 * math.pi * 15.0**3, rel=5e-3)
    np.testing.assert_allclose(np.linalg.norm(m.vertices, axis=1), 15.0, atol=1e-9)
    # distance of each facet plane to the centre: facet error = 15 - that
    d = np.abs(np.einsum("ij,ij->i", m.face_normals, m.triangles[:, 0]))
    assert 15.0 - d.min() < 0.005


def test_expected_volumes():
    # analytic volumes, allowing for the polygonal approximation of round features
    assert make_part("gauge").volume == pytest.approx(10 * 20 * (5 + 10 + 15 + 20), rel=1e-6)
    bracket = 60 * 40 * 6 + 60 * 6 * 40 - 60 * 6 * 6 - 2 * math.pi * 9 * 6 - 2 * math.pi * 16 * 6 - 20 * 12 * 3
    assert make_part("bracket").volume == pytest.approx(bracket, rel=2e-3)
    helix = 5 * math.hypot(2 * math.pi * 10, 6)
    assert make_part("spring").volume == pytest.approx(math.pi * 1.5**2 * helix, rel=1e-2)
    np.testing.assert_allclose(make_part("spring").extents[:2], 23.0, atol=0.05)


def test_turbine_blade_is_twisted():
    m = make_part("turbine_blade")
    z0 = m.bounds[0, 2]
    # near the tip (original z ~ 45 mm), the blade's chord direction is turned ~20 deg
    v = m.vertices[np.abs(m.vertices[:, 2] - (z0 + 45.0)) < 1.6]
    xy = v[:, :2] - v[:, :2].mean(axis=0)
    chord = np.linalg.svd(xy, full_matrices=False)[2][0]
    angle = abs(math.degrees(math.atan2(chord[1], chord[0])))
    angle = min(angle, 180 - angle)
    assert 15.0 < angle < 25.0


# --------------------------------------------------------------------------- defects


def test_scale_defect():
    m = make_part("bracket")
    s = apply_defects(m, scale=0.98)
    assert s.volume == pytest.approx(m.volume * 0.98**3, rel=1e-9)
    assert s.is_watertight
    np.testing.assert_allclose(s.extents, m.extents * 0.98)
    # the input is untouched
    assert make_part("bracket").volume == pytest.approx(m.volume)


def test_bump_remove_on_cube_edge():
    m = make_part("cube30")
    centre = (15.0, 15.0, 0.0)  # midpoint of an edge
    out = apply_defects(m, bumps=[Bump(centre, 3.0, "remove")])
    assert out.is_watertight and out.is_winding_consistent
    quarter_ball = math.pi * 3.0**3 / 3.0
    assert m.volume - out.volume == pytest.approx(quarter_ball, rel=1e-2)
    w = winding_number(out, np.array([centre, [14.0, 14.0, 0.0], [0.0, 0.0, 0.0]]))
    assert abs(w[0]) < 1e-6  # bump centre: outside the new mesh
    assert abs(w[1]) < 1e-6  # inside the removed ball
    assert abs(w[2] - 1.0) < 1e-6  # the cube centre is still inside
    # reference frame kept: the defect is not re-centred away
    np.testing.assert_allclose(out.bounds, m.bounds)


def test_bump_add_increases_volume():
    m = make_part("sphere30")
    out = apply_defects(m, bumps=[Bump((0.0, 0.0, 15.0), 2.0, "add")])
    assert out.is_watertight and out.body_count == 1
    assert out.volume > m.volume + 0.4 * (4 / 3) * math.pi * 8  # about half a ball
    assert out.bounds[1, 2] == pytest.approx(17.0, abs=1e-6)
    w = winding_number(out, np.array([[0.0, 0.0, 16.5]]))
    assert abs(w[0] - 1.0) < 1e-6


def test_scale_then_bumps_in_reference_frame():
    m = make_part("cube30")
    # after scaling by 0.9 the +x face is at 13.5; a bump centred there cuts a half ball
    out = apply_defects(m, scale=0.9, bumps=[Bump((13.5, 0.0, 0.0), 2.0, "remove")])
    half_ball = 2.0 / 3.0 * math.pi * 8.0
    assert 27000 * 0.9**3 - out.volume == pytest.approx(half_ball, rel=1e-2)


def test_bump_validation():
    with pytest.raises(ValueError):
        Bump((0, 0, 0), 0.0, "add")
    with pytest.raises(ValueError):
        Bump((0, 0, 0), 1.0, "grow")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        Bump((0, 0), 1.0, "add")  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        apply_defects(make_part("cube30"), scale=0.0)
    b = Bump(np.array([1, 2, 3]), 1, "add")  # type: ignore[arg-type]
    assert b.centre == (1.0, 2.0, 3.0) and isinstance(b.radius_mm, float)
    hash(b)


def test_random_bumps_reproducible():
    m = make_part("cube_sphere")
    a = random_bumps(m, 6, rng=np.random.default_rng(7))
    b = random_bumps(m, 6, rng=np.random.default_rng(7))
    c = random_bumps(m, 6, rng=np.random.default_rng(8))
    assert a == b
    assert a != c
    assert len(a) == 6
    for bump in a:
        assert 0.5 <= bump.radius_mm <= 3.0
        assert bump.kind in ("add", "remove")
    # centres lie on the surface
    _, dist, _ = trimesh.proximity.closest_point_naive(m, np.array([bp.centre for bp in a]))
    assert np.all(dist < 1e-6)
    only = random_bumps(m, 5, kind="remove", max_radius_mm=1.0, min_radius_mm=1.0, rng=np.random.default_rng(1))
    assert all(bp.kind == "remove" and bp.radius_mm == 1.0 for bp in only)
    assert random_bumps(m, 0, rng=np.random.default_rng(1)) == ()


def test_random_bumps_applied_to_gauge():
    m = make_part("gauge")
    bumps = random_bumps(m, 3, rng=np.random.default_rng(3))
    out = apply_defects(m, scale=1.01, bumps=bumps)
    assert out.is_watertight and out.is_winding_consistent and out.volume > 0


# --------------------------------------------------------------------------- loading


def test_load_builtin():
    m = load_reference("builtin:gauge")
    assert m.volume == pytest.approx(make_part("gauge").volume)


@pytest.mark.parametrize("suffix", ["stl", "ply", "obj"])
@pytest.mark.parametrize("name", ["turbine_blade", "bracket"])
def test_round_trip(tmp_path, suffix, name):
    m = make_part(name)
    path = tmp_path / f"{name}.{suffix}"
    m.export(path)
    loaded = load_reference(path)
    assert loaded.is_watertight and loaded.volume > 0
    assert loaded.volume == pytest.approx(m.volume, rel=1e-5)
    np.testing.assert_allclose(loaded.bounds, m.bounds, atol=1e-4)
    assert len(loaded.faces) == len(m.faces)
    # str paths work too
    assert load_reference(str(path)).volume == pytest.approx(loaded.volume)


def test_load_recentres_and_fixes_inverted(tmp_path):
    m = make_part("gauge")
    m.apply_translation([100.0, -5.0, 2.0])
    m.invert()
    path = tmp_path / "offset.stl"
    m.export(path)
    loaded = load_reference(path)
    assert loaded.volume == pytest.approx(10000.0)
    np.testing.assert_allclose(loaded.bounds.mean(axis=0), 0.0, atol=1e-6)
    np.testing.assert_allclose(loaded.metadata["reference_offset_mm"], [-100.0, 5.0, -2.0], atol=1e-4)
    kept = load_reference(path, recentre=False)
    np.testing.assert_allclose(kept.bounds.mean(axis=0), [100.0, -5.0, 2.0], atol=1e-4)


def _check_error(excinfo, *needles):
    msg = str(excinfo.value)
    assert "\n" not in msg and msg.strip() == msg
    for needle in needles:
        assert needle in msg, msg


def test_error_missing(tmp_path):
    with pytest.raises(ReferenceMeshError) as ei:
        load_reference(tmp_path / "absent_part.stl")
    _check_error(ei, "absent_part.stl", "not found")


@pytest.mark.parametrize("suffix", ["stl", "ply", "obj"])
def test_error_corrupt(tmp_path, suffix):
    path = tmp_path / f"corrupt_part.{suffix}"
    path.write_bytes(b"\x00\xff\x13garbage\nnot a mesh\n\x89\x00" * 7)
    with pytest.raises(ReferenceMeshError) as ei:
        load_reference(path)
    _check_error(ei, "corrupt_part." + suffix)


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_error_random_binary_stl(tmp_path):
    # a binary STL whose triangle count matches its size but whose content is noise
    rng = np.random.default_rng(0)
    path = tmp_path / "noise_part.stl"
    path.write_bytes(b"x" * 80 + (5).to_bytes(4, "little") + rng.bytes(50 * 5))
    with pytest.raises(ReferenceMeshError) as ei:
        load_reference(path)
    _check_error(ei, "noise_part.stl")


def test_error_non_manifold_and_winding(tmp_path):
    a = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    b = a.copy()
    b.apply_translation([1.0, 1.0, 0.0])  # shares one edge with a
    path = tmp_path / "edge_touch.stl"
    trimesh.util.concatenate([a, b]).export(path)
    with pytest.raises(ReferenceMeshError) as ei:
        load_reference(path)
    _check_error(ei, "edge_touch.stl", "not watertight", "non-manifold")
    faces = a.faces.copy()
    faces[0] = faces[0][::-1]
    path = tmp_path / "flipped_face.obj"
    trimesh.Trimesh(a.vertices, faces, process=False).export(path)
    with pytest.raises(ReferenceMeshError) as ei:
        load_reference(path)
    _check_error(ei, "flipped_face.obj", "wound")


def test_error_empty_file(tmp_path):
    path = tmp_path / "empty_part.stl"
    path.write_bytes(b"")
    with pytest.raises(ReferenceMeshError) as ei:
        load_reference(path)
    _check_error(ei, "empty_part.stl")


def test_error_not_watertight(tmp_path):
    box = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-1], process=False)
    path = tmp_path / "open_box.stl"
    open_box.export(path)
    with pytest.raises(ReferenceMeshError) as ei:
        load_reference(path)
    _check_error(ei, "open_box.stl", "is not watertight (3 open edges)")


def test_error_unsupported_and_directory(tmp_path):
    path = tmp_path / "part.step"
    path.write_text("ISO-10303-21;\n")
    with pytest.raises(ReferenceMeshError) as ei:
        load_reference(path)
    _check_error(ei, "part.step", "STL")
    with pytest.raises(ReferenceMeshError) as ei:
        load_reference(tmp_path)
    _check_error(ei, str(tmp_path))


def test_error_unknown_builtin():
    with pytest.raises(ReferenceMeshError) as ei:
        load_reference("builtin:widget")
    _check_error(ei, "builtin:widget", "cube30", "turbine_blade")
