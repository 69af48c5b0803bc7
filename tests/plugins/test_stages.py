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
    from inspector_drivers.replay.folder import read_capture

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


def test_align_from_a_random_orientation(small):
    from inspector_plugins.align import AlignParams, run_align
    from inspector_plugins.carve import CarveParams, run_carve
    import json

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


def _eval_ctx(dev, points):
    from inspector.model import Rig

    n = len(dev)
    bc = BcpsPoints(points, np.asarray(dev, float), np.zeros(n, int), np.zeros((n, 2)), np.ones(n), "ray")
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
