"""Background kernels at real image sizes (issue 26): the block statistics of a 5 MP image."""

from __future__ import annotations

import numpy as np
import pytest

from inspector.kernels import background as bk


def _per_block(small: np.ndarray, ys: np.ndarray, xs: np.ndarray, qs: tuple[float, float]):
    """The reference: one numpy.quantile per block."""
    vals = np.empty((len(ys) - 1, len(xs) - 1), np.float32)
    far = np.empty_like(vals)
    for i in range(len(ys) - 1):
        for j in range(len(xs) - 1):
            vals[i, j], far[i, j] = np.quantile(small[ys[i]:ys[i + 1], xs[j]:xs[j + 1]], list(qs))
    return vals, far


@pytest.mark.parametrize("shape", [(256, 306), (257, 311), (130, 97), (33, 40), (5, 9)])
def test_block_quantiles_equal_one_quantile_per_block(shape):
    """Blocks of unequal sizes (a 2448 x 2048 image reduced 8x: 306 x 256 px in 76 x 64
    blocks) give exactly the numbers of one numpy.quantile per block."""
    rng = np.random.default_rng(7)
    small = (rng.random(shape) * 255).astype(np.float32)
    h, w = shape
    bh, bw = max(h // bk.BLOCK, 1), max(w // bk.BLOCK, 1)
    ys = np.linspace(0, h, bh + 1).astype(int)
    xs = np.linspace(0, w, bw + 1).astype(int)
    assert len(set(np.diff(ys))) > 1 or len(set(np.diff(xs))) > 1 or shape == (5, 9)
    vals = np.empty((bh, bw), np.float32)
    far = np.empty_like(vals)
    bk._block_quantiles(small, ys, xs, (0.75, 0.05), vals, far)
    ref_vals, ref_far = _per_block(small, ys, xs, (0.75, 0.05))
    np.testing.assert_array_equal(vals, ref_vals)
    np.testing.assert_array_equal(far, ref_far)


def test_background_level_of_a_5mp_image_finds_the_vignetting():
    """A dark square on a vignetted background of 2448 x 2048 px: the modelled level follows
    the background (within 2 grey levels away from the part) and its range is the vignetting's."""
    h, w = 2048, 2448
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((x - w / 2) / (w / 2)) ** 2 + ((y - h / 2) / (h / 2)) ** 2
    field = 200.0 * (1.0 - 0.15 * r2)
    img = field.copy()
    img[800:1200, 1000:1400] = 40.0
    rng = np.random.default_rng(0)
    grey = np.clip(img + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8)
    lv = bk.background_level(grey, "dark-object")
    away = np.ones((h, w), bool)
    away[700:1300, 900:1500] = False
    err = np.abs(lv.level - field)[away]
    assert np.percentile(err, 99) < 2.0
    assert lv.high == pytest.approx(float(field.max()), abs=2.0)
    assert lv.low == pytest.approx(float(field[16::32, 16::32].min()), abs=4.0)


@pytest.mark.parametrize(("shape", "reduce"), [((2048, 2448), 8), ((1024, 1024), 8), ((200, 130), 3), ((100, 70), 5),
                                               ((101, 80), 4)])
def test_area_reduced_equals_reducing_a_float_copy_of_the_whole_image(shape, reduce):
    """Reducing band by band (no float copy of the whole image) gives exactly the numbers of
    OpenCV's area reduction of a float32 copy, also where the reduction does not divide the
    band height (3, 5) and where it does not divide the image (101 rows: the whole-image path)."""
    import cv2

    rng = np.random.default_rng(3)
    grey = rng.integers(0, 256, shape, dtype=np.uint8)
    h, w = shape
    ref = cv2.resize(grey.astype(np.float32), (w // reduce, h // reduce), interpolation=cv2.INTER_AREA)
    out = bk.area_reduced(grey, reduce)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, ref)


@pytest.mark.parametrize("n", [4, 15, 16, 20, 25])
def test_quantiles_from_one_sort_equal_numpy_quantile(n):
    """The block statistics' quantiles from one sort: numpy.quantile's numbers and dtype,
    for quantiles below and above the halfway interpolation, at the ends, and with ties."""
    rng = np.random.default_rng(n)
    for trial in range(6):
        blocks = (rng.random((7, 9, n)) * 255).astype(np.float32)
        if trial % 2:
            blocks = np.round(blocks / 8)  # many ties
        for qs in ((0.75, 0.05), (0.25, 0.95), (0.5, 0.0), (1.0, 0.333)):
            got = bk._quantiles_last_axis(blocks, qs)
            want = np.quantile(blocks, list(qs), axis=2)
            for g, w in zip(got, want):
                assert g.dtype == w.dtype
                np.testing.assert_array_equal(g, w)
