"""Features of a triangle mesh (issue 28): the built-in parts against the truth of their
construction, faceted cylinders and cones, stable ids."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from inspector.kernels.features import Feature, find_features
from inspector.parts import make_part


def _of(feats: list[Feature], kind: str) -> list[Feature]:
    return [f for f in feats if f.kind == kind]


def _features(name: str) -> list[Feature]:
    m = make_part(name)
    return find_features(m.vertices, m.faces)


def test_cube30_is_six_planes_30_apart():
    feats = _features("cube30")
    assert [f.id for f in feats] == ["F01", "F02", "F03", "F04", "F05", "F06"]
    assert all(f.kind == "plane" and f.area_mm2 == pytest.approx(900.0) and f.triangles == 2 for f in feats)
    normals = np.array([f.nominal["normal"] for f in feats])
    assert np.abs(normals).sum(axis=0) == pytest.approx([2, 2, 2])
    for f in feats:
        assert np.asarray(f.nominal["point"]) @ np.asarray(f.nominal["normal"]) == pytest.approx(15.0)


def test_bracket_planes_and_holes_match_its_construction():
    feats = _features("bracket")
    cyl = _of(feats, "cylinder")
    planes = _of(feats, "plane")
    assert len(planes) == 13 and len(cyl) == 4
    assert sum(f.triangles for f in feats) == len(make_part("bracket").faces)
    # two Ø8 holes along y through the flange, two Ø6 along z through the base plate; 6 mm long
    radii = sorted(f.nominal["radius"] for f in cyl)
    assert radii == pytest.approx([3.0, 3.0, 4.0, 4.0], abs=1e-6)
    for f in cyl:
        assert f.nominal["length"] == pytest.approx(6.0, abs=1e-6)
        assert f.nominal["convex"] is False  # bores
        axis = np.abs(np.asarray(f.nominal["direction"]))
        assert axis == pytest.approx([0, 1, 0] if f.nominal["radius"] > 3.5 else [0, 0, 1], abs=1e-9)
    big = [f for f in cyl if f.nominal["radius"] > 3.5]
    assert abs(big[0].nominal["point"][0] - big[1].nominal["point"][0]) == pytest.approx(30.0, abs=1e-6)
    # the base plate is 6 thick: its bottom (z = -20 in the centred frame) and top (-14)
    z = sorted(f.nominal["point"][2] for f in planes if abs(f.nominal["normal"][2]) > 0.99)
    assert z[0] == pytest.approx(-20.0) and -14.0 in [pytest.approx(v) for v in z]
    pocket = [f for f in planes if f.nominal["normal"][2] > 0.99 and f.area_mm2 == pytest.approx(240.0)]
    assert pocket and pocket[0].nominal["point"][2] == pytest.approx(-17.0)  # 3 mm deep


def test_spheres_and_rod():
    (s,) = _features("sphere30")
    assert s.kind == "sphere" and s.nominal["radius"] == pytest.approx(15.0, abs=1e-6)
    assert np.asarray(s.nominal["centre"]) == pytest.approx([0, 0, 0], abs=1e-6)
    feats = _features("cube_sphere")
    (ball,) = _of(feats, "sphere")
    (rod,) = _of(feats, "cylinder")
    assert ball.nominal["radius"] == pytest.approx(8.0, abs=1e-6) and ball.nominal["convex"]
    assert rod.nominal["radius"] == pytest.approx(3.0, abs=1e-6) and rod.nominal["convex"]
    # centred frame: cube [-10, 10] -> x - 11.5; ball centre 25 -> 13.5
    assert np.asarray(ball.nominal["centre"]) == pytest.approx([13.5, 0, 0], abs=1e-6)
    assert len(_of(feats, "plane")) == 6


def test_gauge_steps():
    planes = _of(_features("gauge"), "plane")
    tops = sorted(f.nominal["point"][2] for f in planes if f.nominal["normal"][2] > 0.99)
    assert np.diff(tops) == pytest.approx([5.0, 5.0, 5.0])


def _revolve_part() -> trimesh.Trimesh:
    """A flange-like turned part along z: Ø50 disc 8 thick, Ø26 boss 10 high, Ø14 bore, a
    45-degree chamfer cone from Ø26 to Ø20 on the boss's top, and four Ø5 holes on a Ø38 circle."""
    profile = [(0.0, 0.0), (25.0, 0.0), (25.0, 8.0), (13.0, 8.0), (13.0, 15.0), (10.0, 18.0), (0.0, 18.0)]
    body = trimesh.creation.revolve(np.array(profile), sections=128)
    bore = trimesh.creation.cylinder(radius=7.0, segment=[[0, 0, -1], [0, 0, 19]], sections=64)
    holes = [trimesh.creation.cylinder(radius=2.5, segment=[[19 * c, 19 * s, -1], [19 * c, 19 * s, 9]], sections=32)
             for c, s in ((1, 0), (0, 1), (-1, 0), (0, -1))]
    return trimesh.boolean.difference([body, bore, *holes], engine="manifold")


def test_turned_part_cylinders_and_cone():
    m = _revolve_part()
    feats = find_features(m.vertices, m.faces)
    cyl = _of(feats, "cylinder")
    radii = sorted(round(f.nominal["radius"], 6) for f in cyl)
    assert radii == pytest.approx([2.5, 2.5, 2.5, 2.5, 7.0, 13.0, 25.0], abs=1e-6)
    by_r = {round(f.nominal["radius"], 3): f for f in cyl}
    assert by_r[7.0].nominal["convex"] is False and by_r[25.0].nominal["convex"] is True
    assert by_r[25.0].nominal["length"] == pytest.approx(8.0, abs=1e-6)
    (cone,) = _of(feats, "cone")
    assert cone.nominal["half_angle_deg"] == pytest.approx(45.0, abs=1e-4)
    # the chamfer from r 13 at z 15 to r 10 at z 18 meets the axis at z 28
    assert np.asarray(cone.nominal["apex"]) == pytest.approx([0, 0, 28.0], abs=1e-4)
    assert np.asarray(cone.nominal["axis"]) == pytest.approx([0, 0, -1.0], abs=1e-9)
    assert len(_of(feats, "plane")) == 3  # bottom, disc top, boss top


def test_ids_are_stable():
    m = make_part("bracket")
    a = find_features(m.vertices, m.faces)
    b = find_features(m.vertices.copy(), m.faces.copy())
    assert [(f.id, f.kind, f.triangles, round(f.area_mm2, 6)) for f in a] == [
        (f.id, f.kind, f.triangles, round(f.area_mm2, 6)) for f in b]
    # the same geometry with its triangles in another order and the vertices renumbered
    rng = np.random.default_rng(0)
    order = rng.permutation(len(m.faces))
    vperm = rng.permutation(len(m.vertices))
    inv = np.argsort(vperm)
    c = find_features(m.vertices[vperm], inv[m.faces[order]])
    assert [(f.id, f.kind, round(f.area_mm2, 6)) for f in a] == [(f.id, f.kind, round(f.area_mm2, 6)) for f in c]
    for fa, fc in zip(a, c):
        assert sorted(order[fc.faces]) == sorted(fa.faces)
    js = a[13].to_json()
    assert set(js) == {"id", "kind", "nominal", "area_mm2", "triangles"}
    assert js["kind"] == "cylinder" and isinstance(js["nominal"]["point"], list)


def test_bad_input():
    with pytest.raises(ValueError):
        find_features(np.zeros((3, 2)), np.zeros((1, 3), int))
    with pytest.raises(ValueError):
        find_features(np.zeros((3, 3)), np.array([[0, 1, 5]]))
    with pytest.raises(ValueError):
        find_features(np.zeros((3, 3)), np.array([[0, 1, 2]]), angle_tol_deg=30.0)
    assert find_features(np.zeros((0, 3)), np.zeros((0, 3), int)) == []
