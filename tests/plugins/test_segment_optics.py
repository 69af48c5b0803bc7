"""Segmentation that expects real optics (issue 26): flat-field, a background model, specks,
wide edges; clean images segment as before."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from inspector.model import Capture
from inspector.params import build_params

SMALL = dict(part="cube30", seed=5, cameras=8, width=256, height=256, mm_per_px=0.4)


@pytest.fixture(scope="module")
def small():
    from inspector_drivers.sim.simulate import SimParams, simulate

    return simulate(build_params(SimParams, SMALL, "test"), 0)


@pytest.fixture(scope="module")
def vignetted(tmp_path_factory):
    """The small capture with the background at 60 % in the corners (cos^4), with its empty field."""
    from inspector.capture_folder import save_capture
    from inspector_drivers.sim.simulate import SimParams, simulate

    cap = simulate(build_params(SimParams, {**SMALL, "vignetting": 0.6, "background_frames": 4}, "test"), 0)
    return save_capture(cap, tmp_path_factory.mktemp("optics") / "vignetted")


def _params(**kw):
    from inspector_plugins.segment import SegmentParams

    return build_params(SegmentParams, kw, "test")


def _segment(capture, **params):
    from inspector.pipeline import InspectionContext
    from inspector_plugins.segment import run_segment

    return run_segment(InspectionContext(capture=capture, reference=None), _params(**params))


def test_clean_images_segment_exactly_as_without_the_optics_steps(small):
    """On a clean capture the default recipe's silhouettes are those of the plain path (no
    background model, the +-2 px edge window, no speck search): bit for bit, and nothing is
    reported."""
    got = _segment(small)
    plain = _segment(small, background_model="off", edge_window_px=2, speck_margin_px=0.0)
    for a, b in zip(got.silhouettes, plain.silhouettes):
        assert np.array_equal(a.mask, b.mask) and np.array_equal(a.soft, b.soft)
        assert np.array_equal(a.contour, b.contour)
    assert "segment.optics" not in got.extras


def test_the_background_model_follows_vignetting_and_ignores_the_part(small):
    from inspector.kernels.background import background_level
    from inspector_drivers.sim.optics import vignetting_gain

    img = small.images["cam00"].astype(np.float32)
    gain = vignetting_gain(256, 256, 0.6)
    even = background_level(img, "dark-object")
    assert even.spread < 0.02  # noise only: not modelled
    field = background_level(img * gain, "dark-object")
    assert 0.25 < field.spread <= 0.42  # (at the block centres: less than at the very corners)
    # Up to a constant the model is the vignetting: next to the part, where the edge is
    # judged, within 1.5 %, and under the part (filled in) within 2.5 %.
    import cv2

    rel = field.level / gain
    rel /= np.median(rel)
    part = img < 120
    ring = cv2.dilate(part.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool) & ~part
    assert np.abs(rel - 1.0)[ring].max() < 0.015
    assert np.abs(rel - 1.0)[part].max() < 0.025


def _edge_shift_px(sil, ref) -> float:
    """Median shift of a silhouette's contour against a reference silhouette, px (positive:
    larger): its points sampled in the reference's inside map (coverage - 0.5 near the edge)."""
    from inspector.kernels.silhouette import inside_map, sample_bilinear

    m = sample_bilinear(inside_map(ref.soft), sil.contour[:, 0], sil.contour[:, 1], np.nan)
    return -float(np.nanmedian(m))


def test_flat_field_and_the_background_model_remove_the_size_bias_of_vignetting(vignetted, small):
    from inspector.capture_folder import read_capture

    cap = read_capture(vignetted)
    ref = _segment(small).silhouettes
    with_image = _segment(cap)  # background images: flat-field by ratio
    modelled = _segment(cap, background="off")  # the image's own background model
    global_ = _segment(cap, background="off", background_model="off")  # a global threshold, as before
    shift = {name: np.mean([_edge_shift_px(s, r) for s, r in zip(ctx.silhouettes, ref)])
             for name, ctx in (("image", with_image), ("model", modelled), ("global", global_))}
    assert shift["global"] < -0.1  # the part looked smaller
    assert abs(shift["image"]) < 0.02 and abs(shift["model"]) < 0.02
    rep = with_image.extras["segment.optics"]["cam00"]
    assert rep["background"] == "image" and rep["flat_field"] == "ratio"
    assert rep["background_range"][0] < 0.7 * rep["background_range"][1]
    assert modelled.extras["segment.optics"]["cam00"]["background"] == "model"


def test_no_size_bias_through_the_whole_inspection(vignetted, tmp_path):
    """A real rendered capture, inspected end to end: the deviation mean of the nominal cube
    is near 0 with the empty field and with the model, and clearly negative with a global
    threshold."""
    from inspector_tools.testing import SMALL_RECIPE, run_recipe

    def dev(**seg):
        doc = {**SMALL_RECIPE, "stages": [{"use": "segment.threshold", "params": seg}, *SMALL_RECIPE["stages"][1:]]}
        run = run_recipe(doc, [vignetted], tmp_path / f"out{len(list(tmp_path.iterdir()))}")
        (res,) = run.captures
        assert res.json["verdict"] in ("pass", "fail"), res.json.get("error")
        return res.json["verdict"], res.json["stats"]["deviation_mm"]["mean"]

    flat, model, global_ = dev(), dev(background="off"), dev(background="off", background_model="off")
    print(flat, model, global_)
    assert global_[1] < -0.03  # 0.4 mm/px: the global threshold's bias is ~0.2 px (and it may fail the cube)
    assert flat[0] == model[0] == "pass"
    assert abs(flat[1]) < 0.012 and abs(model[1]) < 0.012


def _with_speck(cap: Capture, cam: str, du: float, radius: float, depth: float, background: bool):
    """``cap`` with one dark speck centred ``du`` px outside camera ``cam``'s silhouette, on a
    straight stretch of its edge, and two more in the corners of the view, as dust comes
    (all in an empty field of 200 when ``background``)."""
    from inspector_plugins.segment import segment_image

    sil = segment_image(cap.images[cam], None, "dark-object", _params(), cam)
    c = sil.contour
    centre = np.array([128.0, 128.0])
    # A point of the contour with the part on its left/right along u: the edge is crossed by its row.
    rows = np.round(c[:, 1]).astype(int)
    row = int(np.median(rows))
    on_row = c[np.abs(c[:, 1] - row) < 1e-9]
    u_edge = float(on_row[np.argmax(on_row[:, 0])][0])  # the rightmost crossing of the row
    assert u_edge > centre[0]
    cu, cv = u_edge + du, float(row)
    yy, xx = np.mgrid[0:256, 0:256]
    sub = (np.arange(8) + 0.5) / 8 - 0.5
    t = np.ones((256, 256))
    for su, sv in ((cu, cv), (20.3, 24.6), (231.0, 228.2)):
        cover = np.zeros((256, 256))
        for a in sub:
            for b in sub:
                cover += (xx + a - su) ** 2 + (yy + b - sv) ** 2 <= radius**2
        t *= 1.0 - depth * cover / 64.0
    imgs = dict(cap.images)
    imgs[cam] = np.clip(np.rint(imgs[cam] * t), 0, 255).astype(np.uint8)
    bgs = {}
    if background:
        bgs = {name: np.full((256, 256), 200, np.uint8) for name in cap.images}
        bgs[cam] = np.clip(np.rint(200.0 * t), 0, 255).astype(np.uint8)
    return dataclasses.replace(cap, images=imgs, backgrounds=bgs), sil, (cu, cv)


@pytest.mark.parametrize("background", [True, False], ids=["empty field", "no empty field"])
def test_a_speck_on_the_edge_gives_no_point_off_the_edge(small, background):
    from inspector_plugins.segment import segment_image

    cam = "cam00"
    cap, clean, (cu, cv) = _with_speck(small, cam, du=1.5, radius=2.0, depth=0.85, background=background)
    plain = segment_image(cap.images[cam], None, "dark-object", _params(speck_margin_px=0.0), cam)

    def off(contour):
        """Distance of each point to the clean contour's nearest point, px."""
        d = np.linalg.norm(contour[:, None, :] - clean.contour[None, :, :], axis=2)
        return d.min(axis=1)

    near = np.hypot(plain.contour[:, 0] - cu, plain.contour[:, 1] - cv) < 6
    assert off(plain.contour[near]).max() > 1.0  # taken as it is, the speck moves the edge a pixel and more
    got = _segment(cap)
    sil = got.silhouettes[[c.name for c in cap.rig.cameras].index(cam)]
    rep = got.extras["segment.optics"][cam]
    assert rep["points_dropped"] >= 2
    if background:
        assert rep["specks"] == 3  # all of them, in the empty field
    else:
        assert rep["specks_ignored"] == 2 and rep["edge_specks"] == 1
    assert off(sil.contour).max() < 0.35  # nothing left on the speck (clean contour: same points +- noise)
    # The other cameras are untouched.
    assert all(not r.get("points_dropped") for name, r in got.extras["segment.optics"].items() if name != cam)


def test_dust_on_the_edges_puts_no_point_far_off_and_no_false_defect(tmp_path):
    """A dusty rig without an empty field (100 specks up to 4 px, up to 90 % deep, per
    camera): taken as they are, specks on the silhouettes' edges put BCPS points 1.5 mm
    off the nominal cube; with their contour points dropped, none is 0.4 mm off and the
    cube passes with no defect."""
    from inspector.capture_folder import save_capture
    from inspector_drivers.sim.simulate import SimParams, simulate
    from inspector_tools.testing import SMALL_RECIPE, run_recipe

    cap = simulate(build_params(SimParams, {**SMALL, "dust": 100, "dust_depth": 0.9}, "test"), 0)
    folder = save_capture(cap, tmp_path / "dusty")

    def run(**seg):
        doc = {**SMALL_RECIPE, "stages": [{"use": "segment.threshold", "params": seg}, *SMALL_RECIPE["stages"][1:]]}
        (res,) = run_recipe(doc, [folder], tmp_path / f"out{len(seg)}").captures
        return res.json

    plain, handled = run(speck_margin_px=0.0), run()
    assert plain["stats"]["deviation_mm"]["max"] > 1.0
    assert handled["stats"]["deviation_mm"]["max"] < 0.4
    assert handled["verdict"] == "pass" and not handled["defects"]
    reps = handled["extras"]["segment.optics"]
    assert sum(r.get("edge_specks", 0) for r in reps.values()) >= 1
    assert all(r["specks_ignored"] > 10 for r in reps.values())


def test_isolated_specks_are_ignored_and_counted(small):
    cap = small
    img = cap.images["cam01"].copy()
    for u, v in ((20, 20), (230, 40), (30, 220)):
        img[v - 1 : v + 2, u - 1 : u + 2] = 60  # 3 x 3 specks far from the part
    got = _segment(dataclasses.replace(cap, images={**cap.images, "cam01": img}))
    ref = _segment(cap)
    i = [c.name for c in cap.rig.cameras].index("cam01")
    assert np.array_equal(got.silhouettes[i].contour, ref.silhouettes[i].contour)
    assert got.extras["segment.optics"]["cam01"]["specks_ignored"] == 3


def test_defocus_and_blooming_widen_the_edge_window_and_keep_the_edge_in_place(small):
    """Edges blurred (Gaussian sigma 1.5 px) or with a halo (15 % of the light in 6 px): the
    measured edge profile is wider, the edge is integrated over it, and the silhouettes keep
    their size (coverage sum) within a few hundredths of a pixel of the clean ones."""
    from inspector_drivers.sim.optics import bloom, defocus

    ref = _segment(small).silhouettes
    for effect in (lambda g: defocus(g, 1.5), lambda g: bloom(g, 0.15, 6.0)):
        imgs = {n: np.clip(np.rint(effect(im.astype(np.float32))), 0, 255).astype(np.uint8)
                for n, im in small.images.items()}
        got = _segment(dataclasses.replace(small, images=imgs))
        reps = got.extras["segment.optics"]
        assert all(r["window_px"] >= 4 and r["edge_px"] > 2.0 for r in reps.values())
        shift = [_edge_shift_px(s, r) for s, r in zip(got.silhouettes, ref)]
        assert abs(float(np.mean(shift))) < 0.05
