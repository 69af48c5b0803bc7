"""Each built-in stage on real (simulated) images and on hand-made contexts."""

from __future__ import annotations

import numpy as np
import pytest

from inspector.errors import StageError
from inspector.model import Alignment, BcpsPoints, Capture
from inspector.params import build_params
from inspector.pipeline import Band, InspectionContext, Region, Tolerance
from inspector.reference import Reference


@pytest.fixture(scope="module")
def small(small_capture):
    from inspector.capture_folder import read_capture

    return read_capture(small_capture)


def _segment(capture, **params):
    from inspector_plugins.segment import SegmentParams, run_segment

    ctx = InspectionContext(capture=capture, reference=None)
    return run_segment(ctx, build_params(SegmentParams, params, "test"))


def test_segment_all_cameras(small):
    ctx = _segment(small)
    assert len(ctx.silhouettes) == len(small.rig)
    for s in ctx.silhouettes:
        assert s.mask.any() and len(s.contour) > 50 and not s.touches_border
        # contour points lie on the 0.5 level of the coverage
        from inspector.kernels.silhouette import sample_bilinear

        assert np.median(np.abs(sample_bilinear(s.soft, s.contour[:, 0], s.contour[:, 1]) - 0.5)) < 0.1


def test_segment_bright_object_and_background(small):
    """Inverted images with a non-uniform background image: same silhouettes."""
    ramp = np.linspace(0, 60, small.rig.cameras[0].width, dtype=np.float32)[None, :]
    imgs, bgs = {}, {}
    for name, img in small.images.items():
        inv = 255.0 - img.astype(np.float32)  # bright object, dark background
        imgs[name] = np.clip(inv + ramp, 0, 255).astype(np.uint8)
        bgs[name] = np.clip(np.full_like(inv, 255.0 - 200.0) + ramp, 0, 255).astype(np.uint8)
    cap = Capture(small.name, small.rig, imgs, bgs, polarity="bright-object")
    ref = _segment(small)
    got = _segment(cap)
    for a, b in zip(ref.silhouettes, got.silhouettes):
        assert (a.mask != b.mask).mean() < 1e-3


def test_segment_reports_the_contour_uncertainty_of_hard_edged_images(small):
    from inspector_plugins.segment import SMOOTHED_EDGE_PX

    assert all(s.edge_px == 0.0 for s in _segment(small).silhouettes)  # anti-aliased
    hard = {name: np.where(img < 128, 30, 220).astype(np.uint8) for name, img in small.images.items()}
    sils = _segment(Capture(small.name, small.rig, hard)).silhouettes
    assert all(s.edge_px == SMOOTHED_EDGE_PX for s in sils)


def test_segment_empty_silhouette_names_the_camera(small):
    imgs = dict(small.images)
    imgs["cam03"] = np.full_like(imgs["cam03"], 200)
    with pytest.raises(StageError, match="camera cam03: empty silhouette"):
        _segment(Capture(small.name, small.rig, imgs))


def test_border_touching_silhouette_is_flagged_and_does_not_carve_the_part(small):
    from inspector_plugins.carve import CarveParams, run_carve

    # Crop camera 0's view: the object now runs off its left border.
    imgs = dict(small.images)
    img = imgs["cam00"].copy()
    cols = np.flatnonzero((img < 120).any(axis=0))
    cut = (cols.min() + cols.max()) // 2
    img[:, :cut] = img[:, cut : cut + 1]  # object extends beyond the image edge
    imgs["cam00"] = img
    ctx = _segment(Capture(small.name, small.rig, imgs))
    assert ctx.silhouettes[0].touches_border
    assert ctx.silhouettes[0].contour[:, 0].min() >= 1.0  # no contour on the border
    ctx = run_carve(ctx, CarveParams(voxel_mm=1.0))
    full = run_carve(_segment(small), CarveParams(voxel_mm=1.0))
    # The clipped view cannot remove material: the hull is at least as large.
    lo, hi = ctx.reconstruction.points.min(0), ctx.reconstruction.points.max(0)
    flo, fhi = full.reconstruction.points.min(0), full.reconstruction.points.max(0)
    assert np.all(lo <= flo + 1.0) and np.all(hi >= fhi - 1.0)


def _impulse_and_binary_variants(small):
    """The small capture as is, with salt-and-pepper noise, and hard-edged (binary)."""
    rng = np.random.default_rng(7)
    noisy, binary = {}, {}
    for name, img in small.images.items():
        a = img.copy()
        hit = rng.random(a.shape) < 0.01
        a[hit] = rng.choice(np.array([0, 255], np.uint8), hit.sum())
        noisy[name] = a
        binary[name] = np.where(img < 120, 40, 200).astype(np.uint8)
    return {"plain": small, "impulse": Capture(small.name, small.rig, noisy), "binary": Capture(small.name, small.rig, binary)}


def _same_silhouettes(a, b):
    """Same masks and contours, and the same coverage on the first one's support: outside it
    the coverage is below 0.5 in both (computed in one, zero in the other, never read)."""
    for x, y in zip(a.silhouettes, b.silhouettes):
        assert np.array_equal(x.mask, y.mask)
        y0, y1, x0, x1 = x.support
        assert np.array_equal(x.soft[y0:y1, x0:x1], y.soft[y0:y1, x0:x1])
        for sil in (x, y):
            outside = sil.soft.copy()
            outside[y0:y1, x0:x1] = 0.0
            assert outside.max() < 0.5 and not sil.mask.sum() - sil.mask[y0:y1, x0:x1].sum()
        assert np.array_equal(x.contour, y.contour) and x.touches_border == y.touches_border


@pytest.mark.parametrize(
    "params", [{}, {"median": "full"}, {"median": "off", "min_area_px": 1}, {"threshold": "fixed", "level": 90.0}, {"smooth_px": 1.5}, {"subpixel": "linear"}]
)
def test_segment_8bit_tables_equal_the_float_path(small, monkeypatch, params):
    """8-bit grey images take uint8/table shortcuts: the silhouettes are the float path's, bit for bit."""
    from inspector.kernels import silhouette as sk

    for cap in _impulse_and_binary_variants(small).values():
        fast = _segment(cap, **params)
        with monkeypatch.context() as m:
            m.setattr(sk, "grey_u8", lambda image: None)  # every image through to_grey (float32)
            slow = _segment(cap, **params)
        _same_silhouettes(fast, slow)


def test_segment_on_a_crop_equals_the_whole_image(small, monkeypatch):
    """Contouring on the crop around the kept components gives the whole image's points."""
    import inspector_plugins.segment as seg

    caps = _impulse_and_binary_variants(small)
    # An object cut by the image border, too.
    imgs = dict(small.images)
    img = imgs["cam01"].copy()
    cols = np.flatnonzero((img < 120).any(axis=0))
    img[:, : (cols.min() + cols.max()) // 2] = 40
    imgs["cam01"] = img
    caps["border"] = Capture(small.name, small.rig, imgs)
    for cap in caps.values():
        cropped = _segment(cap)
        with monkeypatch.context() as m:
            m.setattr(seg, "CROP_MARGIN", 10**6)  # the crop is the whole image
            whole = _segment(cap)
        _same_silhouettes(cropped, whole)


def test_mesh_outputs_read_back_with_plyfile_and_open3d(small, tmp_path):
    """The PLY files (CONTRACT) are what plyfile writes, byte for byte, and Open3D reads them."""
    import io

    from plyfile import PlyData, PlyElement

    from inspector.model import InspectionResult
    from inspector.outputs import RECON_MESH_PLY, RECON_PLY, read_ply, write_result
    from inspector_plugins.carve import CarveParams, run_carve

    rec = run_carve(_segment(small), CarveParams(voxel_mm=1.0, mesh=True)).reconstruction
    assert len(rec.faces) > 100
    res = InspectionResult(capture="c", recipe="r", verdict="pass", error=None, timings_s={}, reconstruction=rec)
    folder = write_result(res, tmp_path)

    data = (folder / RECON_MESH_PLY).read_bytes()
    mesh = PlyData.read(io.BytesIO(data))
    assert [e.name for e in mesh.elements] == ["vertex", "face"]
    assert [(p.name, p.val_dtype) for p in mesh["vertex"].properties] == [("x", "f4"), ("y", "f4"), ("z", "f4")]
    (prop,) = mesh["face"].properties
    assert (prop.name, prop.len_dtype, prop.val_dtype) == ("vertex_indices", "u1", "i4")
    v = mesh["vertex"].data
    assert np.array_equal(np.stack([v["x"], v["y"], v["z"]], axis=1), rec.vertices.astype(np.float32))
    assert np.array_equal(np.stack(mesh["face"].data["vertex_indices"]), rec.faces)
    # Byte for byte what plyfile itself writes for the same arrays.
    vert = np.empty(len(rec.vertices), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    for i, k in enumerate("xyz"):
        vert[k] = rec.vertices[:, i]
    face = np.empty(len(rec.faces), dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = rec.faces
    buf = io.BytesIO()
    PlyData([PlyElement.describe(vert, "vertex"), PlyElement.describe(face, "face")], text=False).write(buf)
    assert data == buf.getvalue()

    cols = read_ply(folder / RECON_PLY)
    assert list(cols) == ["x", "y", "z", "nx", "ny", "nz"]
    assert np.array_equal(np.stack([cols[k] for k in ("nx", "ny", "nz")], axis=1), rec.normals.astype(np.float32))

    o3d = pytest.importorskip("open3d")
    m = o3d.io.read_triangle_mesh(str(folder / RECON_MESH_PLY))
    assert np.array_equal(np.asarray(m.triangles), rec.faces)
    assert np.allclose(np.asarray(m.vertices), rec.vertices.astype(np.float32))
    pc = o3d.io.read_point_cloud(str(folder / RECON_PLY))
    assert np.allclose(np.asarray(pc.points), rec.points.astype(np.float32))


def test_carve_makes_the_display_mesh_only_when_asked(small, tmp_path):
    """The display mesh is opt-in (nothing in an inspection reads it): without it the same
    points and normals, no faces, and no reconstruction_mesh.ply in the result folder."""
    from inspector.model import InspectionResult
    from inspector.outputs import RECON_MESH_PLY, RECON_PLY, write_result
    from inspector_plugins.carve import CarveParams, run_carve

    sils = _segment(small)
    plain = run_carve(sils, build_params(CarveParams, {"voxel_mm": 1.0}, "test")).reconstruction
    meshed = run_carve(sils, build_params(CarveParams, {"voxel_mm": 1.0, "mesh": True}, "test")).reconstruction
    assert len(plain.faces) == 0 and len(plain.vertices) == 0 and len(meshed.faces) > 100
    assert np.array_equal(plain.points, meshed.points) and np.array_equal(plain.normals, meshed.normals)
    for name, rec in (("plain", plain), ("meshed", meshed)):
        res = InspectionResult(capture=name, recipe="r", verdict="pass", error=None, timings_s={}, reconstruction=rec)
        folder = write_result(res, tmp_path)
        assert (folder / RECON_PLY).is_file()
        assert (folder / RECON_MESH_PLY).is_file() == (name == "meshed")


@pytest.mark.parametrize(
    "dtypes",
    [
        {"x": np.float32, "flag": np.bool_, "c": np.int8, "u": np.uint8, "s": np.int16, "us": np.uint16, "i": np.int32, "ui": np.uint32, "d": np.float64},
        {"x": ">f4", "camera": ">i2"},  # big-endian arrays are written little-endian
    ],
)
@pytest.mark.parametrize("n", [0, 1, 257])
def test_write_ply_equals_plyfile_for_every_type(tmp_path, dtypes, n):
    import io

    from plyfile import PlyData, PlyElement

    from inspector.outputs import read_ply, write_ply

    rng = np.random.default_rng(n)
    cols = {k: (rng.random(n) * 100 - 20).astype(t) for k, t in dtypes.items()}
    faces = rng.integers(0, max(n, 1), (2 * n, 3))
    for f in (None, faces):
        write_ply(tmp_path / "t.ply", cols, faces=f)
        vert = np.empty(n, dtype=[(k, v.dtype.str) for k, v in cols.items()])
        for k, v in cols.items():
            vert[k] = v
        elements = [PlyElement.describe(vert, "vertex")]
        if f is not None:
            fa = np.empty(len(f), dtype=[("vertex_indices", "i4", (3,))])
            fa["vertex_indices"] = f
            elements.append(PlyElement.describe(fa, "face"))
        buf = io.BytesIO()
        PlyData(elements, text=False).write(buf)
        assert (tmp_path / "t.ply").read_bytes() == buf.getvalue()
        back = read_ply(tmp_path / "t.ply")
        assert list(back) == list(cols) and all(np.array_equal(back[k], cols[k]) for k in cols)
    with pytest.raises(ValueError, match="column 'bad': dtype int64 has no PLY type"):
        write_ply(tmp_path / "bad.ply", {"x": np.zeros(2, np.float32), "bad": np.zeros(2, np.int64)})


def test_align_from_a_random_orientation(small):
    from inspector_plugins.align import AlignParams, run_align
    from inspector_plugins.carve import CarveParams, run_carve

    ctx = run_carve(_segment(small), CarveParams(voxel_mm=0.8))
    ctx = ctx.evolve(reference=Reference.load("builtin:cube30"))
    ctx = run_align(ctx, AlignParams())
    truth = np.array(small.truth.info["pose"])
    # The cube is symmetric: compare where the posed reference's corners land.
    corners = np.array([[x, y, z] for x in (-15, 15) for y in (-15, 15) for z in (-15, 15)], float)
    est = corners @ ctx.alignment.pose[:3, :3].T + ctx.alignment.pose[:3, 3]
    tru = corners @ truth[:3, :3].T + truth[:3, 3]
    d = np.min(np.linalg.norm(est[:, None] - tru[None], axis=2), axis=1)
    assert d.max() < 0.5  # 0.4 mm/px rig, visual-hull bulges: within about a pixel


@pytest.mark.parametrize("scale, hint", [(1e-3, "a mesh in metres?"), (1 / 25.4, "a mesh in inches?"),
                                         (0.3, "wrong reference or part?")])
def test_a_reference_of_the_wrong_size_is_refused_with_both_sizes(small, scale, hint):
    from inspector_plugins.align import AlignParams, run_align
    from inspector_plugins.carve import CarveParams, run_carve

    cube = Reference.load("builtin:cube30")
    ctx = run_carve(_segment(small), CarveParams(voxel_mm=0.8))
    ctx = ctx.evolve(reference=Reference("small", cube.vertices * scale, cube.faces))
    with pytest.raises(StageError, match=r"^the reference does not match the reconstruction \(fitness 0\.\d\d < 0\.30\): "
                       rf"the reference is [\d.]+ mm across, the part [\d.]+ mm: {hint.replace('?', '[?]')}$"):
        run_align(ctx, AlignParams())


def test_bcps_surface_method_runs_and_is_signed_argmin(small):
    from inspector_plugins.align import AlignParams, run_align
    from inspector_plugins.bcps import SurfaceParams, _run, select_surface
    from inspector_plugins.carve import CarveParams, run_carve

    ctx = run_carve(_segment(small), CarveParams(voxel_mm=0.4))
    ctx = run_align(ctx.evolve(reference=Reference.load("builtin:cube30")), AlignParams())
    out = _run(select_surface)(ctx, SurfaceParams(refine_pose=False))
    b = out.bcps
    assert b.method == "surface" and len(b.points) > 100
    sd = ctx.reference.signed_distance(ctx.reconstruction.points, ctx.alignment.pose)
    assert b.deviation.min() >= sd.min() - 1e-9
    assert np.all(np.bincount(b.camera, minlength=len(small.rig)) > 0)


def _eval_ctx(dev, points, cameras=None):
    from inspector.model import Rig

    n = len(dev)
    cameras = np.arange(n) % 4 if cameras is None else np.asarray(cameras)  # neighbours from different cameras
    bc = BcpsPoints(points, np.asarray(dev, float), cameras, np.zeros((n, 2)), np.ones(n), "ray")
    cube = Reference.load("builtin:cube30")
    tol = Tolerance(Band(-0.1, 0.1), (Region("top", (-20, -20, 10), (20, 20, 20), Band(-0.5, 0.5)),))
    return InspectionContext(
        capture=Capture("x", Rig(()), {}), reference=cube, tolerance=tol, bcps=bc, alignment=Alignment(np.eye(4), 1.0, 0.0)
    )


def test_evaluate_clusters_regions_and_verdict():
    from inspector_plugins.evaluate import EvaluateParams, evaluate

    rng = np.random.default_rng(0)
    pts = rng.uniform(-15, 15, size=(400, 3))
    pts[:, 2] = np.where(np.arange(400) < 200, 15.0, -15.0)  # half on the top face, half at the bottom
    dev = rng.normal(0, 0.01, 400)
    # a missing-material defect at the bottom (6 close points), an isolated outlier, and a
    # 0.3 mm excess on the top face, allowed there by the region's band
    bottom = np.flatnonzero(np.arange(400) >= 200)
    pts[bottom[:6], :2] = [[5 + 0.1 * i, 5] for i in range(6)]
    dev[bottom[:6]] = -0.4
    dev[bottom[50]] = 0.3
    dev[:10] = 0.3
    out = evaluate(_eval_ctx(dev, pts), EvaluateParams(cluster_radius_mm=1.0, min_points=3)).evaluation
    assert out.verdict == "fail"
    assert len(out.defects) == 1
    d = out.defects[0]
    assert d.kind == "missing" and d.n_points == 6 and d.worst_mm == pytest.approx(-0.4)
    assert np.allclose(d.position, [5.25, 5, -15], atol=1e-6) and d.region == "default"
    assert out.stats["isolated_out_of_tolerance"] == 1
    assert out.stats["regions"]["top"]["n_points"] == 200
    ok = evaluate(_eval_ctx(np.where(np.abs(dev) > 0.2, 0.0, dev), pts), EvaluateParams()).evaluation
    assert ok.verdict == "pass" and ok.defects == ()


def test_evaluate_a_defect_seen_by_one_camera_only_does_not_reject():
    """Image noise moves one camera's contour: its points alone are not a defect."""
    from inspector_plugins.evaluate import EvaluateParams, evaluate

    pts = np.array([[5.0 + 0.1 * i, 5.0, -15.0] for i in range(6)])
    dev = np.full(6, -0.4)
    one = evaluate(_eval_ctx(dev, pts, cameras=np.full(6, 3)), EvaluateParams()).evaluation
    assert one.verdict == "pass" and one.stats["isolated_out_of_tolerance"] == 6
    two = evaluate(_eval_ctx(dev, pts, cameras=[3, 3, 3, 3, 3, 7]), EvaluateParams()).evaluation
    assert two.verdict == "fail" and two.defects[0].n_points == 6
    assert evaluate(_eval_ctx(dev, pts, cameras=np.full(6, 3)), EvaluateParams(min_cameras=1)).evaluation.verdict == "fail"


def test_defects_on_an_ambiguous_turn_are_unconfirmed_not_reported():
    """When another turn about the part's axis fits the silhouettes about as well, the defects
    could be the part turned: verdict error with the reason, the clusters kept aside."""
    import dataclasses

    from inspector.model import PoseConfidence
    from inspector_plugins.evaluate import EvaluateParams, evaluate

    pts = np.array([[5.0 + 0.1 * i, 5.0, -15.0] for i in range(6)])
    dev = np.full(6, -0.4)
    ctx = _eval_ctx(dev, pts)
    firm = PoseConfidence(axis=(0.0, 0.0, 1.0), runner_up_deg=90.0, margin=0.2, margin_points=900, cutoff_mm=1.0)
    loose = dataclasses.replace(firm, margin=0.001, margin_points=4, ambiguous=True)
    sure = evaluate(ctx.evolve(alignment=dataclasses.replace(ctx.alignment, confidence=firm)), EvaluateParams())
    assert sure.evaluation.verdict == "fail" and len(sure.evaluation.defects) == 1
    unsure = evaluate(ctx.evolve(alignment=dataclasses.replace(ctx.alignment, confidence=loose)), EvaluateParams())
    ev = unsure.evaluation
    assert ev.verdict == "error" and ev.defects == ()
    assert "pose uncertain" in ev.error and "+90 deg" in ev.error and "4 contour points" in ev.error
    assert ev.stats["unconfirmed_defects"][0]["n_points"] == 6
    # a part with no defect passes whatever the turn
    ok = evaluate(_eval_ctx(np.zeros(6), pts).evolve(alignment=Alignment(np.eye(4), 1.0, 0.0, confidence=loose)),
                  EvaluateParams())
    assert ok.evaluation.verdict == "pass" and ok.evaluation.error is None


def test_an_inverted_polarity_is_named_instead_of_carving_the_background(small):
    # A dark part declared bright: the background became the object, the carve then asked
    # for a 24 GiB display grid. The segment stage now says what is wrong, per camera.
    cap = Capture(small.name, small.rig, dict(small.images), polarity="bright-object")
    with pytest.raises(StageError, match=r"camera cam00: the object covers 100% of the image border, so it is the "
                       r"background: the polarity looks inverted: bright-object, from capture\.json"):
        _segment(cap)


def test_a_part_running_off_one_side_is_not_taken_for_an_inverted_polarity(small):
    from inspector.kernels.silhouette import border_fraction

    imgs = dict(small.images)
    img = imgs["cam00"].copy()
    img[:, : img.shape[1] // 2 + 2] = 30  # a dark object over the left half of the view
    imgs["cam00"] = img
    sil = _segment(Capture(small.name, small.rig, imgs)).silhouettes[0]
    assert sil.touches_border and 0.5 < border_fraction(sil.mask) < 0.75


@pytest.mark.parametrize("footprint, default, region, expected", [
    (0.1, Band(-0.1, 0.1), None, None),                 # the designed rig: 1 px
    (0.2, Band(-0.1, 0.1), None, None),                 # 0.5 px: no false reject measured
    (0.25, Band(-0.1, 0.1), None, "tolerance [-0.1, +0.1] mm is 0.40 px at this rig's 0.25 mm pixel footprint"),
    (0.1, Band(-0.1, 0.1), Band(-0.02, 0.5), "tolerance of region 'seat' [-0.02, +0.5] mm is 0.20 px"),
    (0.1, Band(0.0, 0.2), None, "tolerance [+0, +0.2] mm is 0.00 px"),
])
def test_a_tolerance_narrower_than_half_a_pixel_is_warned_about(footprint, default, region, expected):
    from inspector_plugins.evaluate import capability_warning

    regions = () if region is None else (Region("seat", (-1, -1, -1), (1, 1, 1), region),)
    got = capability_warning(Tolerance(default, regions), footprint)
    if expected is None:
        assert got is None
    else:
        assert got.startswith(expected) and got.endswith("widen it or use a finer rig")


def test_evaluate_records_the_footprint_and_the_capability_warning(small):
    from inspector_plugins.evaluate import EvaluateParams, evaluate

    rng = np.random.default_rng(1)
    ctx = _eval_ctx(rng.normal(0, 0.01, 50), rng.uniform(-15, 15, (50, 3)))
    ctx = ctx.evolve(capture=small, tolerance=Tolerance(Band(-0.05, 0.05)))
    stats = evaluate(ctx, EvaluateParams()).evaluation.stats
    fp = small.rig.footprint_mm()
    assert stats["footprint_mm"] == fp and fp > 0.1  # the small test rig: 0.4 mm/px
    assert stats["warnings"] == [
        f"tolerance [-0.05, +0.05] mm is {0.05 / fp:.2f} px at this rig's {fp:.3g} mm pixel footprint: below 0.5 px "
        "image noise alone can reject good parts; widen it or use a finer rig"]
