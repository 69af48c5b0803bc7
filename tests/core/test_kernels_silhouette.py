from __future__ import annotations

import numpy as np
import pytest

from inspector.kernels import silhouette as sk


def disc_coverage(h, w, cx, cy, r, ss=16):
    """Exact-ish anti-aliased disc (ss x ss sub-samples per pixel)."""
    off = (np.arange(ss) + 0.5) / ss - 0.5
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    cov = np.zeros((h, w))
    for dy in off:
        for dx in off:
            cov += ((xx + dx - cx) ** 2 + (yy + dy - cy) ** 2) <= r * r
    return cov / ss**2


def test_to_grey_depths_and_colour():
    g8 = np.full((4, 5), 100, np.uint8)
    assert sk.to_grey(g8).dtype == np.float32 and np.all(sk.to_grey(g8) == 100)
    g16 = np.full((4, 5), 100 * 257, np.uint16)
    assert np.allclose(sk.to_grey(g16), 100)
    rgb = np.zeros((4, 5, 3), np.uint8)
    rgb[..., 1] = 200
    assert np.allclose(sk.to_grey(rgb), 0.587 * 200, atol=1e-3)


def test_coverage_and_contour_of_an_antialiased_disc():
    h = w = 120
    cx, cy, r = 60.3, 58.7, 30.25
    cov = disc_coverage(h, w, cx, cy, r)
    rng = np.random.default_rng(0)
    grey = 200.0 - 160.0 * cov + rng.normal(0, 2.0, cov.shape)
    signal = sk.object_signal(grey.astype(np.float32), "dark-object")
    soft, bg, fg = sk.coverage(signal, sk.otsu_level(signal))
    assert abs(bg - 55) < 1 and abs(fg - 215) < 1
    mask = sk.largest_components(soft >= 0.5, 10)
    uv = sk.subpixel_contour(soft, mask)
    radius = np.hypot(uv[:, 0] - cx, uv[:, 1] - cy)
    # Contour at the true circle to a few hundredths of a pixel, about one point per pixel.
    assert abs(radius.mean() - r) < 0.02
    assert np.abs(radius - r).max() < 0.15
    assert 0.9 * 2 * np.pi * r < len(uv) < 1.6 * 2 * np.pi * r
    assert not sk.touches_border(mask)


def test_contour_drops_the_image_border():
    cov = np.zeros((50, 50))
    cov[10:40, :25] = 1.0  # touches the left border
    mask = cov >= 0.5
    assert sk.touches_border(mask)
    uv = sk.subpixel_contour(cov.astype(np.float32), mask)
    assert len(uv) and uv[:, 0].min() >= 1.0


def test_small_components_are_removed():
    m = np.zeros((30, 30), bool)
    m[5:15, 5:15] = True
    m[25, 25] = True
    kept = sk.largest_components(m, 5)
    assert kept[10, 10] and not kept[25, 25]


def test_inside_map_sign_and_distance():
    soft = np.zeros((40, 40), np.float32)
    soft[10:30, 10:30] = 1.0
    soft[10:30, 30] = 0.25  # a ramp column: contour at u = 29.75
    g = sk.inside_map(soft)
    assert g[20, 20] == pytest.approx(0.5)
    assert g[20, 30] == pytest.approx(-0.25)
    assert g[20, 35] == pytest.approx(-5.5)  # 6 px from the last object pixel
    assert g[20, 5] == pytest.approx(-4.5)
    # Zero crossing of the bilinear interpolation at the sub-pixel contour.
    u = np.linspace(29, 30, 101)
    vals = sk.sample_bilinear(g, u, np.full_like(u, 20.0))
    assert u[np.argmin(np.abs(vals))] == pytest.approx(29 + 0.5 / 0.75, abs=0.011)


def test_sample_bilinear_outside_value():
    img = np.arange(12, dtype=float).reshape(3, 4)
    v = sk.sample_bilinear(img, np.array([1.5, -1.0]), np.array([0.5, 0.0]), outside=-7.0)
    assert v[0] == pytest.approx((1 + 2 + 5 + 6) / 4) and v[1] == -7.0


@pytest.mark.parametrize("angle_deg", [0.0, 10.0, 30.0, 45.0, 60.0, 80.0])
def test_area_refinement_is_exact_on_straight_edges(angle_deg):
    """Linear interpolation errs by up to 0.08 px; the area sum must be ~exact."""
    h = w = 60
    a = np.radians(angle_deg)
    n = np.array([np.cos(a), np.sin(a)])  # edge normal, object where n.x < c
    c = n @ np.array([30.37, 29.81])
    ss = 32
    off = (np.arange(ss) + 0.5) / ss - 0.5
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    cov = np.zeros((h, w))
    for dy in off:
        for dx in off:
            cov += (n[0] * (xx + dx) + n[1] * (yy + dy)) < c
    cov = (cov / ss**2).astype(np.float32)
    mask = cov >= 0.5
    lin = sk.subpixel_contour(cov, mask, margin=6)
    ref = sk.refine_contour_area(lin, cov)
    keep = (np.abs(ref @ n - c) < 3) & (ref[:, 0] > 8) & (ref[:, 0] < w - 8) & (ref[:, 1] > 8) & (ref[:, 1] < h - 8)
    err_area = np.abs(ref[keep] @ n - c)
    err_lin = np.abs(lin @ n - c)
    assert keep.sum() > 20
    assert err_area.max() < 0.01, err_area.max()  # the test image itself is 32x32 supersampled
    assert err_area.mean() <= err_lin[(lin[:, 0] > 8) & (lin[:, 0] < w - 8)].mean() + 1e-9
