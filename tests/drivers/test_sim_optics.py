"""The simulator's real-optics effects (inspector_drivers/sim/optics.py) and their SimParams (issue 26)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from inspector_drivers.sim import optics as op

SMALL = dict(part="cube30", cameras=3, width=128, height=128, mm_per_px=0.8, supersample=2)


def _sim(index: int = 0, **params):
    from inspector.params import build_params
    from inspector_drivers.sim.simulate import SimParams, simulate

    return simulate(build_params(SimParams, {**SMALL, **params}, "test"), index)


@pytest.mark.parametrize("model", ["cos4", "poly"])
def test_vignetting_is_1_at_the_centre_and_the_level_asked_for_at_the_corners(model):
    g = op.vignetting_gain(101, 141, 0.6, model)
    assert g.shape == (101, 141) and g.dtype == np.float32
    assert g[50, 70] == pytest.approx(1.0, abs=1e-6)
    for corner in (g[0, 0], g[0, -1], g[-1, 0], g[-1, -1]):
        assert corner == pytest.approx(0.6, abs=1e-5)
    row = g[50, 70:]
    assert np.all(np.diff(row) < 0)  # falls steadily from the centre
    assert np.array_equal(op.vignetting_gain(8, 8, 1.0, model), np.ones((8, 8), np.float32))
    with pytest.raises(ValueError):
        op.vignetting_gain(8, 8, 0.0)


def test_dust_specks_have_the_sizes_and_depths_asked_for():
    t = op.dust_transmission(200, 200, 12, np.random.default_rng(3), size_px=(2.0, 4.0), depth=(0.5, 0.5))
    assert t.dtype == np.float32 and t.max() == 1.0
    import cv2

    n, labels, stats, _ = cv2.connectedComponentsWithStats((t < 1.0).astype(np.uint8), connectivity=8)
    assert 1 <= n - 1 <= 12  # overlapping specks merge
    # Each speck covers at most pi (4 / 2 + 1)^2 px (its anti-aliased rim included), the
    # darkest pixel loses no more than the depth.
    assert stats[1:, cv2.CC_STAT_AREA].max() <= np.pi * 9 * 12
    assert t.min() >= 0.5 - 1e-6 or n - 1 < 12  # only overlaps go deeper
    # the light taken is what the specks' areas say: depth x sum of the disc areas
    taken = float((1.0 - t).sum())
    assert 0.5 * 12 * np.pi * 1.0**2 <= taken <= 0.5 * 12 * np.pi * 2.0**2 + 1e-3


def test_blurs_and_blooming_leave_a_uniform_field_uniform_and_keep_the_light():
    flat = np.full((40, 50), 180.0, np.float32)
    for img in (op.defocus(flat, 1.5), op.motion_blur(flat, 3.0, 30.0), op.bloom(flat, 0.15, 6.0)):
        np.testing.assert_allclose(img, 180.0, rtol=1e-5)
    edge = np.full((60, 60), 200.0, np.float32)
    edge[:, 30:] = 40.0
    b = op.bloom(edge, 0.15, 6.0)
    assert b.sum() == pytest.approx(edge.sum(), rel=1e-5)  # reflected borders: the light is kept
    assert b[30, 31] > 40.0 + 4.0 and b[30, 28] < 200.0 - 4.0  # the dark side gains, the bright side loses
    np.testing.assert_allclose(b[:, 45:], 40.0, atol=1e-3)  # nothing beyond the halo's radius
    # Symmetric point spreads: the 50 % crossing stays between columns 29 and 30.
    for img in (b, op.defocus(edge, 1.5), op.motion_blur(edge, 3.0, 0.0)):
        mid = 0.5 * (200.0 + 40.0)
        assert img[30, 29] > mid > img[30, 30]
        assert img[30, 29] - mid == pytest.approx(mid - img[30, 30], abs=0.5)


def test_the_motion_kernel_is_a_centred_line_of_the_length_asked_for():
    k = op.motion_kernel(3.0, 0.0)
    assert k.sum() == pytest.approx(1.0, abs=1e-6)
    c = k.shape[0] // 2
    ys, xs = np.mgrid[: k.shape[0], : k.shape[1]]
    assert (k * (xs - c)).sum() == pytest.approx(0.0, abs=1e-6)  # centred: mid-exposure
    spread = np.sqrt((k * (xs - c) ** 2).sum())
    assert spread == pytest.approx(3.0 / np.sqrt(12.0), abs=0.1)  # a box 3 px long (+ bilinear spread)
    assert np.abs(k * (ys - c)).sum() < 1e-9  # along u only
    k45 = op.motion_kernel(4.0, 90.0)
    assert np.abs(k45 * (xs[: k45.shape[0], : k45.shape[1]] - k45.shape[0] // 2)).sum() < 1e-6


def test_optics_off_leave_the_simulated_images_as_they_were():
    from inspector_drivers.sim.simulate import SimParams

    p = SimParams()
    assert not p.optics.active and not p.optics.on_background
    a = _sim()
    b = _sim(vignetting=1.0, dust=0, bloom_fraction=0.0, defocus_px=0.0, motion_blur_px=0.0)
    assert all(np.array_equal(a.images[n], b.images[n]) for n in a.images) and not a.backgrounds


def test_vignetting_and_dust_render_and_the_specks_stay_in_place_across_captures():
    cap0 = _sim(0, vignetting=0.6, dust=30, dust_depth=0.8, noise_sigma=0.0, background_frames=4)
    cap1 = _sim(1, vignetting=0.6, dust=30, dust_depth=0.8, noise_sigma=0.0, background_frames=4)
    for cam in ("cam00", "cam01"):
        bg0, bg1 = cap0.backgrounds[cam], cap1.backgrounds[cam]
        # the empty field: 200 at the centre, 60 % of it at the corners, the specks darker
        assert abs(int(bg0[64, 64]) - 200) <= 1 or bg0[64, 64] < 190  # (a speck may sit there)
        assert abs(float(np.median([bg0[0, 0], bg0[0, -1], bg0[-1, 0], bg0[-1, -1]])) - 120.0) <= 2.0
        # the same specks in every capture (dust is the rig's, not the capture's)
        assert np.array_equal(bg0, bg1)
        expect = op.empty_field(200.0, _sim_params(vignetting=0.6, dust=30, dust_depth=0.8).optics, 128, 128,
                                ["cam00", "cam01", "cam02"].index(cam))
        assert np.abs(bg0.astype(float) - expect).max() <= 0.5 + 1e-3
        # and in the images, where the part is not
        img = cap0.images[cam].astype(float)
        import cv2

        far = cv2.erode((img > 100).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)  # the part is 40 x gain
        assert np.abs(img[far] - expect[far]).max() <= 0.5 + 1e-3
    # different cameras carry different dust
    assert not np.array_equal(cap0.backgrounds["cam00"], cap0.backgrounds["cam01"])


def _sim_params(**params):
    from inspector.params import build_params
    from inspector_drivers.sim.simulate import SimParams

    return build_params(SimParams, {**SMALL, **params}, "test")


def test_background_frames_average_the_noise_and_travel_with_the_capture(tmp_path):
    from inspector.capture_folder import read_capture, save_capture

    cap = _sim(vignetting=0.8, noise_sigma=4.0, background_frames=4)
    bg = cap.backgrounds["cam00"].astype(float)
    flat = op.empty_field(200.0, _sim_params(vignetting=0.8).optics, 128, 128)
    assert np.std(bg - flat) == pytest.approx(2.0, rel=0.15)  # sigma 4 / sqrt(4)
    assert cap.truth.info["optics"]["vignetting"] == 0.8
    back = read_capture(save_capture(cap, tmp_path / "c"))
    assert set(back.backgrounds) == set(cap.images)
    assert np.array_equal(back.backgrounds["cam02"], cap.backgrounds["cam02"])


def test_the_effects_are_options_of_inspector_simulate():
    from inspector_drivers.sim.simulate import SimParams

    names = {f.name for f in dataclasses.fields(SimParams)}
    assert {"vignetting", "dust", "bloom_fraction", "bloom_radius_px", "defocus_px", "motion_blur_px", "motion_deg",
            "background_frames"} <= names
    from inspector.errors import RecipeError

    with pytest.raises((ValueError, RecipeError), match="contrast"):
        _sim_params(vignetting=0.5, foreground=200.0, background=200.0)


def test_inspector_simulate_takes_the_effects_and_writes_the_empty_field(tmp_path):
    import argparse

    from inspector.capture_folder import read_capture
    from inspector_drivers.sim.commands import add_simulate_parser, simulate_command

    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="cmd")
    add_simulate_parser(sub)
    help_text = sub.choices["simulate"].format_help()  # (a '%' in a parameter's doc would break it)
    assert "--vignetting" in help_text and "--background-frames" in help_text and "--motion-blur-px" in help_text
    args = ap.parse_args(["simulate", "--out", str(tmp_path), "--cameras", "3", "--width", "96", "--height", "96",
                          "--mm-per-px", "0.8", "--supersample", "2", "--vignetting", "0.7", "--dust", "5",
                          "--defocus-px", "1.0", "--background-frames", "2"])
    assert simulate_command(args) == 0
    (folder,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    cap = read_capture(folder)
    assert set(cap.backgrounds) == set(cap.images)
    corner = float(np.median([cap.backgrounds["cam00"][i, j] for i in (0, -1) for j in (0, -1)]))
    assert corner == pytest.approx(0.7 * 200.0, abs=4.0)
