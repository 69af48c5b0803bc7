"""Accuracy on captures written by another program, on parts the product has never seen.

Requirement (issue): with the default recipe, anti-aliased 8-bit images and noise sigma 2,
BCPS mean distance to the true surface <= 0.1 pixel footprint and p99 <= 0.5 px, also with
missing material (scale 0.98, bump removed); hard-edged images: mean <= 0.25 px; sigma 6
+ 1 % impulses: mean <= 0.3 px. "The accuracy figures above hold on captures written by
another program in the CONTRACT format."

The writer (``foreign_capture.py``) and the measurement (``measure.py``) import nothing
from the product; the slow tests drive the real ``inspector run`` in a subprocess.
"""

from __future__ import annotations

import ast
import json
from pathlib import Path

import foreign_capture as fc
import measure as ms
import numpy as np
import pytest
import run_matrix as rm
import shapely
import trimesh

HERE = Path(__file__).resolve().parent


# --------------------------------------------------------------------------- fast: independence, renderer


@pytest.mark.parametrize("module", ["foreign_capture.py", "measure.py", "run_matrix.py", "pose_sweep.py"])
def test_the_foreign_program_does_not_import_the_product(module):
    tree = ast.parse((HERE / module).read_text())
    names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    names += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    assert not [n for n in names if n.split(".")[0] in {"inspector", "inspector_plugins", "inspector_drivers"}]


def test_renderer_self_check():
    assert fc.self_check() < 1e-6


@pytest.mark.parametrize("geom", [
    shapely.Polygon([(3.21, 4.87), (50.13, 9.4), (20.5, 58.02)]),
    shapely.Point(31.7, 30.2).buffer(20.3, 64).difference(shapely.Point(33.1, 29.9).buffer(7.7, 64)),
    shapely.box(10.3, 20.7, 11.3, 21.7),
], ids=["triangle", "ring-with-hole", "unit-square"])
def test_coverage_sums_to_the_polygon_area(geom):
    cov = fc.coverage(geom, 64, 64)
    assert abs(cov.sum() - geom.area) < 1e-6
    assert cov.min() >= 0.0 and cov.max() <= 1.0


def test_a_straight_edge_gives_the_exact_partial_areas():
    # Vertical edge at x = 10.3: pixel column 10 spans [9.5, 10.5], so it is 0.8 covered.
    cov = fc.coverage(shapely.box(-5.0, -5.0, 10.3, 70.0), 64, 64)
    np.testing.assert_allclose(cov[:, :10], 1.0, atol=1e-12)
    np.testing.assert_allclose(cov[:, 10], 0.8, atol=1e-12)
    np.testing.assert_allclose(cov[:, 11:], 0.0, atol=1e-12)
    # Slanted edge x = 30 - (y - 30) / 4, object on its left. Row 30: the edge crosses pixel 30
    # symmetrically about its centre, so half of it is covered.
    slant = shapely.Polygon([(-5.0, -5.0), (38.75, -5.0), (20.0, 70.0), (-5.0, 70.0)])
    cov = fc.coverage(slant, 64, 64)
    assert abs(cov[30, 30] - 0.5) < 1e-12 and cov[30, 29] == 1.0 and cov[30, 31] == 0.0
    # Row 20 (y in [19.5, 20.5]): the edge runs from x = 32.625 down to 32.375 and crosses the
    # pixel border x = 32.5 at mid-row, cutting a corner triangle of legs 0.5 (in y) x 0.125 (in x)
    # from pixel 32 and adding the same triangle to pixel 33.
    corner = 0.5 * 0.5 * 0.125
    want_32, want_33 = 1.0 - corner, corner
    assert abs(cov[20, 32] - want_32) < 1e-12 and abs(cov[20, 33] - want_33) < 1e-12


def test_pixel_zero_is_the_centre_of_the_top_left_pixel():
    # A 1-pixel box centred on (0, 0) covers exactly pixel (0, 0).
    cov = fc.coverage(shapely.box(-0.5, -0.5, 0.5, 0.5), 8, 8)
    assert cov[0, 0] == pytest.approx(1.0, abs=1e-12) and cov.sum() == pytest.approx(1.0, abs=1e-12)
    # The optical axis goes through the image centre ((w - 1) / 2, (h - 1) / 2).
    cam = fc.fibonacci_rig()[3]
    np.testing.assert_allclose(cam.project(np.zeros((1, 3)))[0], [511.5, 511.5], atol=1e-9)


def test_silhouette_of_a_plate_facing_the_camera_is_its_projected_square():
    cam = fc.fibonacci_rig()[0]
    plate = trimesh.creation.box(extents=(20.0, 20.0, 0.01))
    # Put the plate 400 mm in front of the camera, parallel to its image plane.
    T = np.eye(4)
    T[:3, :3] = cam.R.T
    plate.apply_transform(T)
    sil = fc.silhouette(plate, cam)
    # Front face at depth 400 - 0.005 mm: side 20 * f / z px.
    side = 20.0 * 4000.0 / (400.0 - 0.005)
    assert sil.area == pytest.approx(side * side, rel=1e-9)


def test_parts_are_closed_and_30_to_50_mm():
    for name in fc.PARTS:
        m = fc.make_part(name)
        assert m.is_watertight and m.volume > 0, name
        # 30-36 mm for the matrix's four parts, up to 50 mm for the near-symmetric ones (issue 14):
        # at the rig's ~0.1 mm pixel footprint every part stays well inside the 1024 px images.
        assert 25.0 <= m.extents.max() <= 50.0, (name, m.extents)
        np.testing.assert_allclose(m.bounds.mean(axis=0), 0.0, atol=1e-9)


def test_point_triangle_distance_matches_trimesh():
    rng = np.random.default_rng(0)
    T = rng.normal(size=(5000, 3, 3))
    P = rng.normal(size=(5000, 3)) * 2.0
    got = ms.closest_on_triangles(P, T[:, 0], T[:, 1], T[:, 2])
    np.testing.assert_allclose(got, trimesh.triangles.closest_point(T, P), atol=1e-12)


def test_capture_folder_follows_the_contract(tmp_path):
    made = fc.make_capture(tmp_path, "housing", "grey", seed=3)
    cap = made["capture"]
    rig = json.loads((cap / "rig.json").read_text())
    assert rig["units"] == "mm" and len(rig["cameras"]) == 16
    for c in rig["cameras"]:
        assert set(c) >= {"name", "width", "height", "K", "R", "t"}
        R = np.asarray(c["R"])
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        assert (cap / "images" / f"{c['name']}.png").is_file()
    assert json.loads((cap / "capture.json").read_text())["polarity"] == "dark-object"
    assert not (cap / "truth").exists()  # the truth stays outside the capture
    assert made["reference"].is_file() and made["true_mesh"].is_file()


def test_the_exact_condition_is_the_noise_free_coverage_in_16_bit():
    cov = np.random.default_rng(0).random((8, 8))
    img = fc.to_image(cov, "exact", "dark-object", np.random.default_rng(1))
    bg, fg = fc.LEVELS_DARK
    assert img.dtype == np.uint16
    np.testing.assert_allclose((img / 257.0 - bg) / (fg - bg), cov, atol=1e-4)


# --------------------------------------------------------------------------- dent rows: observable vs dent


def _dent_truth(at=(10.0, 0.0, 0.0), radius=2.5):
    pose = np.eye(4)
    pose[:3, 3] = (1.0, 2.0, 3.0)
    return {"defect": {"kind": "bump_removed", "at_mm": list(at), "radius_mm": radius}, "pose": pose.tolist()}


def test_the_dent_footprint_is_the_removed_sphere_plus_a_margin_in_the_world():
    truth = _dent_truth()
    xyz = np.array([[11.0, 2.0, 3.0], [11.0 + 2.9, 2.0, 3.0], [11.0 + 3.1, 2.0, 3.0], [0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(ms.dent_footprint(truth, xyz, 0.5), [True, True, False, False])
    assert ms.dent_footprint({"defect": {"kind": "scale"}, "pose": truth["pose"]}, xyz) is None
    st = ms.stats_px(np.array([0.0, 0.2, 0.4]), 0.1)
    assert st["n"] == 3 and st["mean_px"] == pytest.approx(2.0) and st["max_px"] == pytest.approx(4.0)
    assert ms.stats_px(np.zeros(0), 0.1) == {"n": 0, "mean_px": None, "p99_px": None, "max_px": None}


def test_a_dent_row_is_judged_on_the_observable_surface():
    case = rm.CASES[2]
    row = {"n_points": 1000, "mean_px": 0.3, "p99_px": 9.0,
           "observable": {"n": 950, "mean_px": 0.03, "p99_px": 0.2}}
    ok, bar = rm.judge(case, row)
    assert ok and bar.startswith("observable:")
    assert not rm.judge(case, {**row, "observable": {"n": 950, "mean_px": 0.03, "p99_px": 0.6}})[0]
    assert not rm.judge(case, {k: v for k, v in row.items() if k != "observable"})[0]  # no split: all points


def test_best_case_gap_is_the_distance_to_the_visual_hull_in_the_images(tmp_path):
    box = trimesh.creation.box(extents=(20.0, 20.0, 20.0))
    np.savez(tmp_path / "true_world.npz", vertices=box.vertices, faces=box.faces)
    cams = fc.fibonacci_rig(4)
    (tmp_path / "rig.json").write_text(json.dumps({"units": "mm", "cameras": [c.to_json() for c in cams]}))
    # A corner is on every silhouette's outline or inside; it lies on the hull (gap 0). The
    # centre is deep inside every silhouette: ~10 mm from the nearest outline, ~100 px.
    gap = rm.best_case_gap(tmp_path, tmp_path, np.array([[10.0, 10.0, 10.0], [0.0, 0.0, 0.0], [10.05, 10.0, 10.0]]))
    assert gap[0] < 1e-6 and gap[1] > 50.0 and 0.05 < gap[2] < 2.0


def _row(part, cond, mean, ok=True, dent=False):
    r = {"part": part, "condition": cond, "seed": 1, "exit": 1, "expected": "fail", "defect_visible": True,
         "verdict": "fail", "n_points": 100, "mean_px": mean, "p99_px": 0.2, "max_px": 1.0, "pose": {"mean_mm": 0.001},
         "run_failed": False, "ok": ok, "bar": "mean <= 0.1, p99 <= 0.5"}
    if dent:
        r["observable"] = {"n": 90, "mean_px": 0.02, "p99_px": 0.1, "max_px": 0.3}
        r["dent"] = {"n": 10, "mean_px": 5.0, "p99_px": 9.0, "max_px": 9.5, "best_case_n": 9, "depth_mm": 2.5,
                     "shown_mm": 0.8}
    return r


def test_merging_re_run_rows_replaces_only_them_and_keeps_the_other_sections():
    old = rm.to_markdown([_row("torus", "grey, scale 1.00", 0.02), _row("torus", "grey, bump removed", 0.3, ok=False)],
                         100.0)
    old += "\n## Excess material\n\nkept\n\n<!-- pose-sweep:begin -->\nsweep\n<!-- pose-sweep:end -->\n"
    assert "1/2 rows meet their bar" in old
    new = rm.merge_markdown(old, [_row("torus", "grey, bump removed", 0.3, dent=True)], 12.0)
    cells = rm.parse_main_table(new)
    assert [c["condition"] for c in cells] == ["grey, scale 1.00", "grey, bump removed"]
    assert cells[0]["mean px"] == "0.020" and cells[0]["dent n / mean / p99 px"] == "-"
    assert cells[1]["observable n / mean / p99 px"] == "90 / 0.020 / 0.100"
    assert cells[1]["dent n / mean / p99 px"] == "10 / 5.000 / 9.000" and cells[1]["dent depth shown"] == "0.80 of 2.5 mm"
    assert "2/2 rows meet their bar. Matrix wall time 100 s" in new and "(1 rows, 12 s" in new
    assert new.endswith("## Excess material\n\nkept\n\n<!-- pose-sweep:begin -->\nsweep\n<!-- pose-sweep:end -->\n")
    # A second merge replaces the note of the first instead of adding another.
    again = rm.merge_markdown(new, [_row("torus", "grey, bump removed", 0.3, dent=True)], 13.0)
    assert again.count("Re-run since") == 1 and "(1 rows, 13 s" in again


def test_a_full_rewrite_keeps_the_blocks_of_other_generators():
    old = "# old\n\n<!-- pose-sweep:begin -->\nsweep\n<!-- pose-sweep:end -->\n"
    assert rm.keep_blocks(old, "# new\n") == "# new\n\n<!-- pose-sweep:begin -->\nsweep\n<!-- pose-sweep:end -->\n"
    assert rm.keep_blocks(old, old) == old


# --------------------------------------------------------------------------- slow: the real product


@pytest.mark.slow
@pytest.mark.parametrize("part, case_index, seed", [
    ("hexnut", 1, 1101),  # grey, scale 0.98: bore and countersinks shrink too (excess there)
    ("hexnut", 1, 11),    # the same, seed 11: 0.6 degrees off before the size fit corrected the pose
    ("torus", 3, 12),    # binary
    ("housing", 2, 13),  # grey, bump removed
    ("shaft", 4, 14),    # strong noise + impulses (bright object)
    ("shaft", 0, 1200),  # grey, nominal: was turned 3 degrees about its axis (false reject)
    ("shaft", 3, 2203),  # binary: falsely rejected before rays were also refined from their deepest sample
], ids=["hexnut-grey-scale098", "hexnut-grey-scale098-seed11", "torus-binary", "housing-grey-bump", "shaft-strong",
        "shaft-grey-nominal", "shaft-binary"])
def test_bcps_accuracy_on_a_foreign_capture(tmp_path, part, case_index, seed):
    case = rm.CASES[case_index]
    row = rm.run_case(tmp_path, part, case, seed)
    assert not row["run_failed"], row
    summary = {k: row.get(k) for k in ("verdict", "n_points", "mean_px", "p99_px", "max_px", "pose")}
    assert row["n_points"] > 1000, summary
    assert row["mean_px"] <= case.mean_px, summary
    if case.p99_px is not None:
        assert row["p99_px"] <= case.p99_px, summary
    # A nominal part is never rejected; a defect that shows in some silhouette always is.
    assert row["verdict"] == row["expected"], summary
