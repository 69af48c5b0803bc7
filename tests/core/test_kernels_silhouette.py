from __future__ import annotations

import os

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


# --------------------------------------------------------------------------- fast paths
# Each fast path (8-bit tables, crop, point-wise gradient, components on a box) must give
# exactly what the plain whole-image float computation gives.


def noisy_disc_u8(h=90, w=110, seed=0, impulses=0.02):
    rng = np.random.default_rng(seed)
    cov = disc_coverage(h, w, 52.3, 44.6, 27.4, ss=8)
    grey = 200.0 - 160.0 * cov + rng.normal(0, 3.0, cov.shape)
    hit = rng.random(cov.shape) < impulses
    grey[hit] = rng.choice([0.0, 255.0], hit.sum())
    return np.clip(np.rint(grey), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("mode", ["off", "impulse", "full"])
@pytest.mark.parametrize("threshold", [1.0, 20.5, 60.0, 254.9, 300.0])
@pytest.mark.parametrize("band_rows", [None, 7])
def test_median_denoise_u8_equals_float(mode, threshold, band_rows, monkeypatch):
    """The 8-bit path (in bands of rows: 7 leaves a remainder of 6 on 90 rows) is the float one."""
    g = noisy_disc_u8()
    if band_rows:
        monkeypatch.setattr(sk, "DENOISE_BAND_BYTES", band_rows * g.shape[1])
    got = sk.median_denoise(g, mode, threshold)
    want = sk.median_denoise(g.astype(np.float32), mode, threshold)
    assert got.dtype == np.uint8 and np.array_equal(got.astype(np.float32), want)


@pytest.mark.parametrize("polarity", ["dark-object", "bright-object"])
def test_u8_tables_equal_the_float_signal(polarity):
    g = noisy_disc_u8(seed=1)
    counts = sk.histogram_u8(g)
    assert np.array_equal(counts, np.bincount(g.ravel(), minlength=256))
    table = sk.object_signal(np.arange(256, dtype=np.float32), polarity)
    signal = sk.object_signal(g.astype(np.float32), polarity)
    assert np.array_equal(table[g], signal)
    level = sk.otsu_level_from_histogram(table, counts)
    assert level == sk.otsu_level(signal)
    for lv in (level, 0.0, 37.5, 255.0, 300.0):
        assert sk.levels_from_histogram(table, counts, lv) == sk.coverage_levels(signal, lv)
    _, bg, fg = sk.coverage(signal, level)
    assert (bg, fg) == sk.levels_from_histogram(table, counts, level)
    # Even pixel counts (the median is the mean of the two middle values) and odd ones.
    vals = np.array([200.0, 3.0, 7.0, 7.5, 150.0], np.float32)  # any order
    for c in ([2, 3, 3, 0, 2], [3, 3, 4, 0, 2], [1, 1, 0, 0, 0], [0, 0, 0, 0, 5], [7, 2, 5, 1, 7]):
        c = np.array(c, np.int64)
        assert sk.levels_from_histogram(vals, c, 100.0) == sk.coverage_levels(np.repeat(vals, c), 100.0)
    assert sk.levels_from_histogram(vals, np.array([2, 3, 3, 0, 2]), 100.0) == (5.0, 175.0)


def test_otsu_from_histogram_equals_opencv():
    """OpenCV's Otsu replayed on the histogram: the same threshold, ties included."""
    import cv2

    rng = np.random.default_rng(8)
    for t in range(600):
        h, w = rng.integers(1, 60, 2)
        kind = t % 5
        if kind == 0:
            img = rng.integers(0, 256, (h, w))
        elif kind in (1, 2):  # two or three levels: many equal between-class variances
            img = rng.choice(rng.integers(0, 256, kind + 1), (h, w))
        elif kind == 3:
            img = np.clip(rng.normal(rng.integers(0, 256), rng.uniform(0.1, 40), (h, w)), 0, 255)
        else:
            img = np.full((h, w), rng.integers(0, 256))
        img = img.astype(np.uint8)
        want, _ = cv2.threshold(img, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        assert sk._otsu_threshold(np.bincount(img.ravel(), minlength=256)) == want
    img = noisy_disc_u8(seed=9)
    table = sk.object_signal(np.arange(256, dtype=np.float32), "dark-object")
    assert sk.otsu_level_from_histogram(table, sk.histogram_u8(img)) == sk.otsu_level(table[img])
    flat = np.full((5, 5), 77, np.uint8)
    assert sk.otsu_level_from_histogram(table, sk.histogram_u8(flat)) == sk.otsu_level(table[flat]) == 178.0


def test_mask_from_table_runs_and_lookups():
    g = noisy_disc_u8(seed=2)
    tables = [np.arange(256) <= 97, np.arange(256) >= 131, np.zeros(256, bool), np.ones(256, bool), (np.arange(256) % 3) == 0]
    for t in tables:
        got = sk.mask_from_table(g, t)
        assert got.dtype == np.uint8 and np.array_equal(got, t[g].astype(np.uint8))


def test_edge_pixel_count_equals_the_rolled_formula():
    rng = np.random.default_rng(3)
    for m in [
        rng.random((40, 50)) < 0.3,  # everywhere, touching every border (wrap-round)
        np.pad(rng.random((10, 12)) < 0.5, ((7, 9), (5, 4))),  # inside: counted on its box
        np.zeros((20, 20), bool),
        np.ones((20, 20), bool),
    ]:
        want = np.count_nonzero(m ^ np.roll(m, 1, axis=0) | m ^ np.roll(m, 1, axis=1))
        assert sk.edge_pixel_count(m) == want
        assert sk.edge_pixel_count(m.view(np.uint8)) == want


def _labelled_reference(m, min_area):
    import cv2

    n, labels, stats, _ = cv2.connectedComponentsWithStats(m.astype(np.uint8), connectivity=8)
    keep = np.zeros(n, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_area
    return keep[labels], m & ~keep[labels]


@pytest.mark.parametrize("shape", [(60, 70), (700, 600)])  # 16-bit and 32-bit labels
def test_kept_components_equal_whole_image_labelling(shape):
    rng = np.random.default_rng(4)
    m = np.zeros(shape, bool)
    m[10:30, 12:40] = True
    m[5:8, 50:53] = True  # 9 px: dropped with min_area 10
    m[rng.integers(0, shape[0], 40), rng.integers(0, shape[1], 40)] = True
    if shape[0] > 100:
        m[100:600:2, 100:500:2] = True  # isolated pixels: ~50,000 components
    comps = sk.kept_components(m, 10)
    want, removed = _labelled_reference(m, 10)
    assert np.array_equal(comps.mask, want) and np.array_equal(comps.removed, removed)
    ys, xs = np.nonzero(want)
    assert comps.box == (ys.min(), ys.max() + 1, xs.min(), xs.max() + 1)
    assert np.array_equal(sk.largest_components(m, 10), want)
    # Nothing dropped: no removed image; nothing kept: no box.
    clean = sk.kept_components(want, 10)
    assert clean.removed is None and np.array_equal(clean.mask, want)
    none = sk.kept_components(m, 10**7)
    assert none.box is None and not none.mask.any()
    empty = sk.kept_components(np.zeros((5, 5), bool), 1)
    assert empty.box is None and empty.removed is None and not empty.mask.any()


def test_grow_box_clips_to_the_image():
    assert sk.grow_box((2, 10, 5, 20), (30, 40), 4) == (0, 14, 1, 24)
    assert sk.grow_box((20, 30, 30, 40), (30, 40), 4) == (16, 30, 26, 40)


def _refine_reference(uv, raw, half_window=2):
    """The whole-image numpy implementation that the compiled crop one replaces."""
    h, w = raw.shape
    gy, gx = np.gradient(np.clip(raw, 0.0, 1.0))
    gxs = sk.sample_bilinear(gx, uv[:, 0], uv[:, 1])
    gys = sk.sample_bilinear(gy, uv[:, 0], uv[:, 1])
    on_row = np.abs(uv[:, 1] - np.rint(uv[:, 1])) < 1e-9
    on_col = np.abs(uv[:, 0] - np.rint(uv[:, 0])) < 1e-9
    steep = np.abs(gxs) >= np.abs(gys)
    out = []
    offs = np.arange(-half_window, half_window + 1)
    for along_u, keep in ((True, steep & on_row), (False, ~steep & on_col)):
        pts = uv[keep]
        if len(pts) == 0:
            continue
        g = gxs[keep] if along_u else gys[keep]
        line = np.rint(pts[:, 1] if along_u else pts[:, 0]).astype(np.intp)
        pos = pts[:, 0] if along_u else pts[:, 1]
        centre = np.rint(pos).astype(np.intp)
        idx = centre[:, None] + offs[None, :]
        n = w if along_u else h
        inside_img = (idx.min(axis=1) >= 0) & (idx.max(axis=1) < n)
        idx = np.clip(idx, 0, n - 1)
        vals = raw[line[:, None], idx] if along_u else raw[idx, line[:, None]]
        cl = np.clip(vals, 0.0, 1.0)
        obj_low = g < 0
        first = np.where(obj_low, cl[:, 0], cl[:, -1])
        last = np.where(obj_low, cl[:, -1], cl[:, 0])
        d = np.diff(cl, axis=1) * np.where(obj_low, 1.0, -1.0)[:, None]
        clean = inside_img & (first > 0.85) & (last < 0.15) & np.all(d < 0.1, axis=1)
        total = vals.sum(axis=1)
        edge = np.where(obj_low, centre - half_window - 0.5 + total, centre + half_window + 0.5 - total)
        edge = np.where(clean, edge, pos)
        out.append(np.stack([edge, line.astype(float)], axis=1) if along_u else np.stack([line.astype(float), edge], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 2))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_refinement_equals_the_numpy_reference(dtype):
    """Random coverage and points anywhere in the image (on rows, columns, the border):
    the compiled refinement gives the numpy implementation's points exactly."""
    rng = np.random.default_rng(5)
    for _ in range(20):
        h, w = rng.integers(2, 40, 2)
        raw = (rng.random((h, w)) * 1.4 - 0.2).astype(dtype)
        raw[rng.random((h, w)) < 0.3] = rng.choice([0.0, 1.0, 0.85, 0.15, -0.0])
        n = 300
        u = rng.uniform(0, w - 1, n)
        v = rng.uniform(0, h - 1, n)
        u[::3] = np.rint(u[::3])  # on columns
        v[1::3] = np.rint(v[1::3])  # on rows
        u[2::9], v[5::9] = 0.0, h - 1.0  # on the border
        uv = np.stack([u, v], axis=1)
        for hw in (1, 2, 3):
            assert np.array_equal(sk.refine_contour_area(uv, raw, half_window=hw), _refine_reference(uv, raw, hw))


def _polygon_coverage(h, w, ss=8):
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    off = (np.arange(ss) + 0.5) / ss - 0.5
    cov = np.zeros((h, w))
    for dy in off:
        for dx in off:
            x, y = xx + dx, yy + dy
            cov += (0.8 * x + 0.3 * y < 70.3) & (-0.2 * x + 0.9 * y < 44.1) & (x + y > 25.7) & (y > 6.2)
    return (cov / ss**2).astype(np.float32)


@pytest.mark.parametrize("where", ["inside", "left-border", "corner"])
def test_contour_and_refinement_on_a_crop_equal_the_whole_image(where):
    soft = _polygon_coverage(70, 90)
    if where == "left-border":
        soft = np.ascontiguousarray(soft[:, 12:])
    elif where == "corner":
        soft = np.ascontiguousarray(soft[5:, 12:])
    rng = np.random.default_rng(6)
    raw = soft + rng.normal(0, 0.02, soft.shape).astype(np.float32)
    mask = soft >= 0.5
    full = sk.subpixel_contour(soft, mask)
    ref_full = sk.refine_contour_area(full, raw)
    ys, xs = np.nonzero(mask)
    y0, y1, x0, x1 = sk.grow_box((ys.min(), ys.max() + 1, xs.min(), xs.max() + 1), mask.shape, 4)
    crop = dict(origin=(x0, y0), image_shape=mask.shape)
    uv = sk.subpixel_contour(soft[y0:y1, x0:x1], mask[y0:y1, x0:x1], **crop)
    assert len(full) > 50 and np.array_equal(uv, full)  # identical floats, same order
    ref = sk.refine_contour_area(uv, raw[y0:y1, x0:x1], **crop)
    assert np.array_equal(ref, ref_full)
    # The numpy whole-image implementation gives the same refinement.
    assert np.array_equal(ref, _refine_reference(full, raw))


def test_crop_arguments_are_checked():
    soft = _polygon_coverage(70, 90)
    mask = soft >= 0.5
    uv = sk.subpixel_contour(soft, mask)
    with pytest.raises(ValueError, match="image_shape"):
        sk.subpixel_contour(soft[5:, 5:], mask[5:, 5:], origin=(5, 5))
    with pytest.raises(ValueError, match="crop too small"):
        sk.refine_contour_area(uv, soft[20:40, 20:40], origin=(20, 20), image_shape=soft.shape)


@pytest.mark.parametrize("kind", ["uniform", "halves", "binary", "quarters", "float32", "nan", "ints"])
def test_marching_squares_equals_skimage_find_contours(kind):
    """Same contours, point for point and in the same order, as skimage's (the reference)."""
    from skimage.measure import find_contours

    rng = np.random.default_rng(abs(hash(kind)) % 1000)
    for _ in range(40):
        h, w = rng.integers(2, 30, 2)
        a = rng.random((h, w))
        if kind == "halves":
            a = rng.integers(0, 3, (h, w)) / 2.0  # pixels exactly at the level, saddles
        elif kind == "binary":
            a = (a > 0.5).astype(float)
        elif kind == "quarters":
            a = np.round(a * 4) / 4
        elif kind == "float32":
            a = a.astype(np.float32)
        elif kind == "nan":
            a[rng.random((h, w)) < 0.1] = np.nan
        elif kind == "ints":
            a = rng.integers(0, 2, (h, w))
        want = find_contours(a, 0.5)
        got = sk.marching_squares(a, 0.5)
        assert len(got) == len(want)
        for g, x in zip(got, want):
            assert g.dtype == np.float64 and np.array_equal(g, x)
    # A real silhouette: one closed contour of ~300 points.
    cov = disc_coverage(120, 130, 60.3, 58.7, 40.25, ss=4).astype(np.float32)
    (want,) = find_contours(cov, 0.5)
    (got,) = sk.marching_squares(cov, 0.5)
    assert len(got) > 250 and np.array_equal(got, want)
    with pytest.raises(ValueError, match="2x2"):
        sk.marching_squares(np.zeros((1, 5)), 0.5)


# --------------------------------------------------------------------------- real optics (issue 26)


def _half_plane(h=80, w=80, edge=40.3, sigma=0.0):
    """Coverage of the half plane u <= ``edge`` (exact per column), optionally Gaussian-blurred."""
    import cv2

    cov = np.clip(edge + 0.5 - np.arange(w, dtype=np.float32), 0.0, 1.0)[None, :].repeat(h, axis=0)
    return cv2.GaussianBlur(cov, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE) if sigma > 0 else cov


def test_the_edge_profile_measures_how_wide_an_edge_is():
    sharp = _half_plane(edge=40.5)  # (a pixel edge: the interpolated coverage is 0.5 on it)
    uv = np.stack([np.full(30, 40.5), np.arange(25.0, 55.0)], axis=1)
    offsets, prof = sk.edge_profile(sharp, uv)
    assert prof[np.searchsorted(offsets, 0.0)] == pytest.approx(0.5, abs=1e-6)
    # positive offsets: towards the object (smaller u here)
    assert prof[offsets < -1.0].max() < 1e-6 and prof[offsets > 1.0].min() > 1 - 1e-6
    assert sk.edge_half_width(offsets, prof) <= 1.5
    blurred = _half_plane(sigma=1.5)
    w = sk.edge_half_width(*sk.edge_profile(blurred, uv))
    assert 3.0 <= w <= 4.5  # a Gaussian of sigma 1.5 px is within 2 % of its levels at ~3.3 px
    # a crop at an origin gives the same profile
    o2, p2 = sk.edge_profile(blurred[10:70, 20:75], uv, origin=(20, 10))
    np.testing.assert_allclose(p2, sk.edge_profile(blurred, uv)[1])


def test_a_wide_window_finds_a_blurred_edge_where_the_narrow_one_cannot():
    """Area refinement over a window that holds the whole blurred profile is exact for a
    straight edge; the standard +-2 px window is not clean there and keeps the
    marching-squares position."""
    for edge in (40.3, 40.5, 40.8):
        raw = _half_plane(edge=edge, sigma=1.5)
        mask = raw >= 0.5
        uv = sk.subpixel_contour(np.clip(raw, 0, 1), mask)
        wide = sk.refine_contour_area(uv, raw, half_window=6)
        rows = wide[np.abs(wide[:, 1] - np.rint(wide[:, 1])) < 1e-9]
        inner = rows[(rows[:, 1] > 10) & (rows[:, 1] < 70)]
        np.testing.assert_allclose(inner[:, 0], edge, atol=2e-3)


def test_contour_bumps_find_a_speck_on_a_straight_edge_not_corners_or_curves():
    # A square (corners), a disc (a convex curve), a hole in a plate (a concave one).
    h = w = 200
    square = np.zeros((h, w), np.float32)
    square[50:150, 50:150] = 1.0
    disc = disc_coverage(h, w, 100.3, 99.6, 60.2).astype(np.float32)
    plate = (1.0 - disc_coverage(h, w, 100.3, 99.6, 45.2)).astype(np.float32)
    plate[:, :5] = plate[:, -5:] = plate[:5, :] = plate[-5:, :] = 0.0  # the plate inside the view
    for cov in (square, disc, plate):
        pieces = []
        sk.subpixel_contour(cov, cov >= 0.5, pieces=pieces)
        assert all(closed for _, closed in pieces)
        assert len(sk.contour_bumps(pieces, cov)) == 0
    # A speck of radius 2 px just outside the square's right edge joins it: a bump.
    speck = disc_coverage(h, w, 151.5, 100.0, 2.0).astype(np.float32)
    cov = np.maximum(square, speck)
    pieces = []
    sk.subpixel_contour(cov, cov >= 0.5, pieces=pieces)
    bumps = sk.contour_bumps(pieces, cov)
    assert len(bumps) >= 1
    assert np.all(np.hypot(bumps[:, 0] - 151.5, bumps[:, 1] - 100.0) < 4.0)


def test_near_mask_reads_the_pixel_holding_each_point():
    m = np.zeros((10, 10), bool)
    m[3, 4] = True
    got = sk.near_mask(np.array([[4.2, 2.6], [4.6, 3.0], [-3.0, 3.0], [4.0, 3.4]]), m)
    assert got.tolist() == [True, False, False, True]


def test_the_background_level_of_an_uneven_field_and_its_specks():
    from inspector.kernels import background as bk

    h, w = 256, 320
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    shade = 1.0 - 0.35 * (((xx - 160) / 200) ** 2 + ((yy - 128) / 160) ** 2)  # 35 % down at the sides
    part = disc_coverage(h, w, 150.2, 120.7, 50.0)
    rng = np.random.default_rng(1)
    img = (shade * (200.0 - 160.0 * part) + rng.normal(0, 2.0, (h, w))).astype(np.float32)
    f = bk.background_level(img, "dark-object")
    assert f.spread > 0.2 and f.blocks < f.blocks_level.size
    rel = (f.level / shade) / np.median(f.level / shade)
    near = (part == 0) & (disc_coverage(h, w, 150.2, 120.7, 60.0) > 0)
    assert np.abs(rel - 1.0)[near].max() < 0.01  # next to the part, where its edge is judged
    flat = bk.flat_field_u8(np.clip(np.rint(img), 0, 255).astype(np.uint8), (f.reference / f.level).astype(np.float32))
    assert flat.dtype == np.uint8 and abs(float(np.median(flat[part == 0])) - f.reference) < 2.0  # (+0.67 sigma: q75)
    # an even field is seen as even
    assert bk.background_level(rng.normal(200, 2, (h, w)).astype(np.float32), "dark-object").spread < 0.02
    # specks of an empty field: darker than its large-scale level
    empty = (200.0 * shade).astype(np.float32)
    empty[40:43, 60:63] *= 0.5
    empty[200, 300] *= 0.7
    g = bk.background_level(empty, "dark-object")
    specks = bk.speck_mask(empty, g.level, "dark-object", 0.08)
    assert bk.count_blobs(specks) == 2 and specks[41, 61] and specks[200, 300] and specks.sum() == 10


def test_interpolated_levels_are_not_rounded_to_a_grey_level():
    rng = np.random.default_rng(4)
    grey = np.concatenate([rng.normal(173.3, 2.0, 200_000), rng.normal(34.6, 2.0, 50_000)])
    grey = np.clip(np.rint(grey), 0, 255).astype(np.uint8)
    counts = sk.histogram_u8(grey[None, :])
    table = sk.object_signal(np.arange(256, dtype=np.float32), "dark-object")
    level = sk.otsu_level_from_histogram(table, counts)
    bg, fg = sk.levels_from_histogram(table, counts, level)
    assert bg == float(round(bg)) and fg == float(round(fg))  # plain medians: grey levels
    bgi, fgi = sk.levels_from_histogram(table, counts, level, interpolate=True)
    assert bgi == pytest.approx(255 - 173.3, abs=0.03) and fgi == pytest.approx(255 - 34.6, abs=0.05)


def test_border_fraction_within_a_box_equals_the_whole_mask():
    """Given the box outside which the mask is False, only the border within it is read: the
    same fraction, for boxes on every side, corners, inside, and a one-row box."""
    rng = np.random.default_rng(5)
    h, w = 23, 31
    for y0, y1, x0, x1 in [(0, 23, 0, 31), (0, 5, 3, 9), (20, 23, 28, 31), (4, 9, 0, 7), (6, 18, 25, 31),
                           (3, 20, 4, 27), (0, 1, 0, 31), (22, 23, 2, 5), (0, 23, 30, 31)]:
        mask = np.zeros((h, w), bool)
        mask[y0:y1, x0:x1] = rng.random((y1 - y0, x1 - x0)) < 0.6
        assert sk.border_fraction(mask, (y0, y1, x0, x1)) == sk.border_fraction(mask)
    assert sk.border_fraction(np.ones((h, w), bool), (0, h, 0, w)) == 1.0


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


@pytest.mark.skipif(not os.path.exists("/proc/self/statm"), reason="needs Linux /proc")
def test_lazy_zeros_are_zeros_whose_untouched_pages_cost_no_memory(monkeypatch):
    """A 256 MB lazy array with 1 MB written adds far less than 256 MB to the resident set;
    it reads as zeros, writes like any array, pickles; small ones and a failed map give
    numpy's zeros."""
    import mmap
    import pickle

    before = _rss_bytes()
    a = sk.lazy_zeros((8192, 8192), np.float32)
    a[100:110, :] = 1.5  # 320 KB of rows
    assert _rss_bytes() - before < 64 << 20
    assert a.shape == (8192, 8192) and a.dtype == np.float32 and a.flags.writeable
    assert a[100, 5] == 1.5 and a[0, 0] == 0.0 and float(a[5000:5010].sum()) == 0.0
    b = pickle.loads(pickle.dumps(a[95:115]))
    assert b.sum() == 1.5 * 10 * 8192
    del a, b
    small = sk.lazy_zeros((10, 10), bool)
    assert small.base is None and not small.any()  # numpy's own

    def no_map(*args, **kwargs):
        raise OSError(12, "Cannot allocate memory")

    monkeypatch.setattr(mmap, "mmap", no_map)
    c = sk.lazy_zeros((2048, 2448), np.float32)
    assert c.shape == (2048, 2448) and not c.any()
