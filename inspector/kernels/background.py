"""Background kernels: the large-scale level of a backlit image's background, and specks.

Real optics do not give an even background: the lens darkens the image towards its corners
(vignetting), the backlight is uneven, dust on the lens or the diffuser leaves dark specks.
Both multiply the light, the object's and the background's alike, so the image divided by
the background's level per pixel (*flat-field*) is even again and one pair of levels
(object, background) holds everywhere.

* :func:`background_level` models the background's level of one image from the image
  itself, when there is no empty-field reference: the image is cut into blocks (32 px; on
  images under 1024 px, smaller, about 32 across); a block's level is a high quantile of
  its pixels (the background's, for a dark object) from the image reduced up to 8x by area
  averaging (noise down 8x); blocks that are not background (the
  object covers them) are rejected against the smoothed field of their neighbours and filled
  in from them (normalised convolution), and the block field is interpolated back to full
  size. Cost: one area reduction of the image plus work on ~1000 blocks.
* :func:`speck_mask` finds the specks of an empty-field reference: pixels darker than the
  reference's own large-scale level by a fraction.
* :func:`flat_field_u8` divides an 8-bit image by a gain per pixel, rounding back to 8 bits
  (one OpenCV pass), so the segmentation's 8-bit fast path keeps working.
"""

from __future__ import annotations

import numpy as np

__all__ = ["BackgroundLevel", "area_reduced", "background_level", "flat_field_u8", "speck_mask", "count_blobs"]

#: Largest reduction of the image before the block statistics (area averaging), px.
REDUCE = 8
#: Block side, in reduced pixels (4: 32 image pixels at the largest reduction).
BLOCK = 4


class BackgroundLevel:
    """Result of :func:`background_level`.

    Attributes
    ----------
    blocks_level : (bh, bw) float32
        The background's large-scale grey level at the block centres (8-bit scale).
    reference : float
        The level a flat-fielded image is brought to: the median of ``blocks_level`` (so a
        flat-fielded image keeps its grey scale).
    low, high : float
        Smallest and largest of the level's polynomial trend at the block centres, grey
        levels (the noise of single blocks averaged out).
    blocks : int
        Blocks that held background (the others were filled in).
    shape : (H, W)
        The image's size.
    """

    def __init__(self, field: _Field, good: np.ndarray, shape: tuple[int, int]) -> None:
        self._field = field
        self.blocks_level = field.blocks
        self.reference = float(np.median(field.blocks))
        self.low = float(field.trend.min())
        self.high = float(field.trend.max())
        self.blocks = int(good.sum())
        self.shape = shape
        self._level: np.ndarray | None = None

    @property
    def level(self) -> np.ndarray:
        """The level at every pixel, (H, W) float32 (computed on first use)."""
        if self._level is None:
            self._level = self._field.full(*self.shape)
        return self._level

    @property
    def spread(self) -> float:
        """``(high - low) / high``: how uneven the background is (0: even)."""
        return (self.high - self.low) / max(self.high, 1e-6)


def _fill(values: np.ndarray, good: np.ndarray) -> np.ndarray:
    """Blocks ``values`` (h, w) float32 where ``good`` (h, w) bool, the others filled in by
    normalised convolution at growing scales, then smoothed lightly (sigma 0.7 block)."""
    import cv2

    w = good.astype(np.float32)
    v = np.where(good, values, 0.0).astype(np.float32)
    out = v.copy()
    todo = ~good
    for sigma in (1.0, 2.0, 4.0, 8.0, 16.0, 32.0):
        if not todo.any():
            break
        num = cv2.GaussianBlur(v, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
        den = cv2.GaussianBlur(w, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
        ok = todo & (den > 0.05)
        out[ok] = num[ok] / den[ok]
        todo &= ~ok
    if todo.any():  # nothing anywhere near: the mean of the good blocks
        out[todo] = float(values[good].mean()) if good.any() else float(values.mean())
    return cv2.GaussianBlur(out, (0, 0), 0.7, borderType=cv2.BORDER_REFLECT)


#: Degree of the polynomial trend of the background (2D, all terms x^i y^j with i + j <= it).
DEGREE = 4


def _powers(t: np.ndarray, degree: int) -> np.ndarray:
    """``t^0 .. t^degree`` of coordinates (n,) in [-1, 1]: (n, degree + 1) float64."""
    return np.asarray(t, np.float64)[:, None] ** np.arange(degree + 1)[None, :]


class _Field:
    """The background's level on the block grid: a polynomial trend (all ``x^i y^j``,
    ``i + j <= degree``) fitted to the good blocks plus their residual, filled in
    (normalised convolution) where the object hides it."""

    def __init__(self, vals: np.ndarray, good: np.ndarray) -> None:
        import cv2

        bh, bw = vals.shape
        degree = DEGREE
        while degree > 0 and good.sum() < 3 * (degree + 1) * (degree + 2) // 2:
            degree -= 1
        self.degree = degree
        px = _powers((np.arange(bw) + 0.5) / bw * 2.0 - 1.0, degree)  # (bw, d+1)
        py = _powers((np.arange(bh) + 0.5) / bh * 2.0 - 1.0, degree)  # (bh, d+1)
        ii, jj = np.nonzero(good)
        terms = [(i, j) for i in range(degree + 1) for j in range(degree + 1 - i)]
        A = np.stack([px[jj, i] * py[ii, j] for i, j in terms], axis=1)
        coef = np.zeros((degree + 1, degree + 1))
        if len(ii) >= len(terms):
            # Normal equations, solved by OpenCV (single-threaded; a BLAS least squares can
            # spin up threads for a 1000 x 15 system).
            _, sol = cv2.solve(A.T @ A, (A.T @ vals[ii, jj].astype(np.float64)).reshape(-1, 1), flags=cv2.DECOMP_SVD)
            for (i, j), c in zip(terms, sol.ravel()):
                coef[i, j] = c
        elif len(ii):
            coef[0, 0] = float(vals[ii, jj].mean())
        self.coef = coef  # value = sum coef[i, j] x^i y^j
        trend = (py @ coef.T @ px.T).astype(np.float32)  # (bh, bw)
        self.trend = trend
        self.residual = _fill((vals - trend).astype(np.float32), good)
        self.blocks = trend + self.residual

    def full(self, height: int, width: int, step: int = 8) -> np.ndarray:
        """The field at every pixel (height, width) float32: the trend evaluated every ``step``
        px and the residual resized to that grid, then bilinear to full size."""
        import cv2

        gh, gw = max(-(-height // step), 2), max(-(-width // step), 2)
        px = _powers((np.arange(gw) + 0.5) / gw * 2.0 - 1.0, self.degree)
        py = _powers((np.arange(gh) + 0.5) / gh * 2.0 - 1.0, self.degree)
        fine = (py @ self.coef.T @ px.T).astype(np.float32)
        fine += cv2.resize(self.residual, (gw, gh), interpolation=cv2.INTER_LINEAR)
        return cv2.resize(fine, (width, height), interpolation=cv2.INTER_LINEAR)


def _quantiles_last_axis(blocks: np.ndarray, qs: tuple[float, ...]) -> list[np.ndarray]:
    """``numpy.quantile(blocks, qs, axis=-1)`` (linear interpolation), the same numbers, from
    one sort of the last axis: numpy's quantile partitions the rows one by one, ten times
    slower than a sort on the many short rows of the block statistics (16-25 values).

    Parameters
    ----------
    blocks : (..., n) float32
    qs : quantiles in [0, 1]

    Returns
    -------
    list of (...) float64
        As numpy computes them: between the sorted neighbours ``a``, ``b`` of the virtual
        index ``q (n - 1)``, ``a + (b - a) t``, or ``b - (b - a)(1 - t)`` from ``t >= 0.5``.
    """
    s = np.sort(blocks, axis=-1)
    n = s.shape[-1]
    out = []
    for q in qs:
        v = np.float64(n - 1) * np.float64(q)
        i = int(np.floor(v))
        t = v - np.float64(i)
        a, b = s[..., i], s[..., min(i + 1, n - 1)]
        diff = b - a
        out.append(b - diff * (np.float64(1.0) - t) if t >= 0.5 else a + diff * t)
    return out


def _block_quantiles(small: np.ndarray, ys: np.ndarray, xs: np.ndarray, qs: tuple[float, float], vals: np.ndarray,
                     far: np.ndarray) -> None:
    """Two quantiles (linear interpolation, as :func:`numpy.quantile`) of every block
    ``small[ys[i]:ys[i + 1], xs[j]:xs[j + 1]]``, written to ``vals[i, j]`` and ``far[i, j]``.

    The blocks take at most two heights and two widths: each of those (at most four) groups
    of equal-sized blocks is gathered into one (n_rows, n_cols, h * w) array and reduced
    along its last axis, the same numbers as one :func:`numpy.quantile` per block (4864
    calls on a 2448 x 2048 image: 0.5 s of Python overhead, now about 10 ms).
    """
    hs, ws = np.diff(ys), np.diff(xs)
    for hsz in np.unique(hs):
        rows = np.flatnonzero(hs == hsz)
        iy = ys[rows][:, None] + np.arange(hsz)[None, :]  # (nr, hsz)
        for wsz in np.unique(ws):
            cols = np.flatnonzero(ws == wsz)
            ix = xs[cols][:, None] + np.arange(wsz)[None, :]  # (nc, wsz)
            blocks = small[iy[:, None, :, None], ix[None, :, None, :]].reshape(len(rows), len(cols), -1)
            a, b = _quantiles_last_axis(blocks, qs)
            vals[np.ix_(rows, cols)] = a
            far[np.ix_(rows, cols)] = b


#: Rows of the image converted to float32 at a time by :func:`area_reduced` (rounded down
#: to whole blocks).
BAND_ROWS = 64


def area_reduced(grey: np.ndarray, reduce: int) -> np.ndarray:
    """Grey levels (H, W) averaged over ``reduce`` x ``reduce`` blocks (OpenCV's area
    interpolation to (H // reduce, W // reduce)): (H // reduce, W // reduce) float32.

    When ``reduce`` divides both sides (every block whole) the image is converted to float32
    :data:`BAND_ROWS` rows at a time into one small buffer and each band reduced on its own:
    the same numbers as reducing a float32 copy of the whole image, without that copy (20 MB
    at 5 MP, whose fresh pages cost more than the reduction itself). Otherwise the blocks
    straddle the bands (fractional area weights) and the whole image is converted.
    """
    import cv2

    h, w = grey.shape
    size = (max(w // reduce, 1), max(h // reduce, 1))
    if h % reduce or w % reduce or grey.dtype == np.float32:
        return cv2.resize(grey.astype(np.float32, copy=False), size, interpolation=cv2.INTER_AREA)
    rows = reduce * max(BAND_ROWS // reduce, 1)  # whole blocks per band
    out = np.empty((h // reduce, w // reduce), np.float32)
    buf = np.empty((min(rows, h), w), np.float32)
    for y in range(0, h, rows):
        n = min(rows, h - y)
        band = buf[:n]
        band[:] = grey[y:y + n]
        cv2.resize(band, (w // reduce, n // reduce), dst=out[y // reduce:(y + n) // reduce], interpolation=cv2.INTER_AREA)
    return out


def background_level(grey: np.ndarray, polarity: str, *, quantile: float = 0.75, reject: float = 0.015,
                     iterations: int = 4) -> BackgroundLevel:
    """The large-scale grey level of the background of one image.

    Parameters
    ----------
    grey : (H, W) uint8 or float32
        Grey levels, 8-bit scale.
    polarity : {"dark-object", "bright-object"}
        A dark object: the background is the bright side, a block's level the ``quantile``
        of its (reduced) pixels; a bright object: the ``1 - quantile`` one.
    quantile : float
        So a block that is at least ``1 - quantile`` background gives the background's level.
    reject : float
        A block whose level is beyond the field of the others by more than this fraction,
        on the object's side, is not background (rejected, filled in); ``iterations`` rounds.

    Returns
    -------
    BackgroundLevel
        ``level`` is (H, W) float32: a polynomial trend (degree :data:`DEGREE`) fitted to
        the background's blocks plus their residual, filled in under the object.
    """
    import cv2

    g = np.asarray(grey)
    h, w = g.shape
    # Blocks of REDUCE * BLOCK px (32) on large images; smaller ones (down to BLOCK px, no
    # reduction) on small images, so about 32 blocks span the shorter side.
    reduce = int(np.clip(min(h, w) // (32 * BLOCK), 1, REDUCE))
    small = g.astype(np.float32, copy=False) if reduce == 1 else area_reduced(g, reduce)
    sh, sw = small.shape
    bh, bw = max(sh // BLOCK, 1), max(sw // BLOCK, 1)
    dark = polarity == "dark-object"
    q = quantile if dark else 1.0 - quantile
    vals = np.empty((bh, bw), np.float32)
    far = np.empty((bh, bw), np.float32)  # the other end of the block: does it hold object?
    q_far = 0.05 if dark else 0.95
    if sh % bh == 0 and sw % bw == 0:
        blocks = small.reshape(bh, sh // bh, bw, sw // bw).transpose(0, 2, 1, 3).reshape(bh, bw, -1)
        kth = int(round(q * (blocks.shape[2] - 1)))  # the nearest rank: no interpolation needed
        kfar = int(round(q_far * (blocks.shape[2] - 1)))
        part = np.sort(blocks, axis=2)  # (short rows: a sort is cheaper than numpy's partition)
        vals[:], far[:] = part[..., kth], part[..., kfar]
    else:  # blocks of BLOCK x BLOCK reduced pixels, the last ones take the remainder's share
        ys = np.linspace(0, sh, bh + 1).astype(int)
        xs = np.linspace(0, sw, bw + 1).astype(int)
        _block_quantiles(small, ys, xs, (q, q_far), vals, far)
    # A block holding some of the object (or its edge's halo of blooming or defocus) is not
    # trusted even when its quantile reads as background: its far end is much darker
    # (brighter, for a bright object) than that quantile.
    mixed = far < 0.7 * vals if dark else far > vals / 0.7
    # A first guess: the blocks on the background's side of the Otsu level of the block levels
    # (object and background differ far more than vignetting makes the background vary).
    lo, hi = float(vals.min()), float(vals.max())
    if hi - lo > 1e-6:
        t, _ = cv2.threshold(np.clip((vals - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8), 0, 255,
                             cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        cut = lo + (t + 0.5) * (hi - lo) / 255.0
        good = vals > cut if dark else vals < cut
    else:
        good = np.ones(vals.shape, bool)
    if (good & ~mixed).sum() >= max(good.sum() // 4, 1):
        good &= ~mixed
    else:
        mixed[:] = False  # (nearly every block mixed: an image full of edges; keep them)
    field = _Field(vals, good)
    for _ in range(iterations):
        off = (field.blocks - vals) / np.maximum(field.blocks, 1e-6)  # > 0: darker than the field
        new = ((off <= reject) if dark else (off >= -reject)) & ~mixed
        if np.array_equal(new, good) or not new.any():
            break
        good = new
        field = _Field(vals, good)
    return BackgroundLevel(field, good, (h, w))


def flat_field_u8(grey: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """``round(grey * gain)`` saturated to 0..255: (H, W) uint8 from (H, W) uint8 and float32."""
    import cv2

    return cv2.multiply(grey, gain, dtype=cv2.CV_8U) if gain.dtype == np.float32 else cv2.multiply(
        grey.astype(np.float32), gain.astype(np.float32), dtype=cv2.CV_8U)


def speck_mask(reference: np.ndarray, level: np.ndarray, polarity: str, depth: float = 0.08) -> np.ndarray:
    """Specks of an empty-field reference image: pixels darker than its large-scale level.

    Parameters
    ----------
    reference : (H, W) float32 or uint8
        The empty field's grey levels (8-bit scale).
    level : (H, W) float32
        Its large-scale level (:func:`background_level` of the reference).
    polarity : str
        For a bright object on a dark background a speck is still darker (less light), so
        the test is the same; the argument is kept for symmetry with the other kernels.
    depth : float
        Fraction of the light a pixel must lack to be part of a speck.

    Returns
    -------
    (H, W) bool
    """
    del polarity
    return np.asarray(reference, np.float32) < (1.0 - depth) * level


def count_blobs(mask: np.ndarray) -> int:
    """8-connected components of a (H, W) bool mask."""
    import cv2

    if not mask.any():
        return 0
    n, _ = cv2.connectedComponents(mask.view(np.uint8) if mask.dtype == bool else mask.astype(np.uint8), connectivity=8)
    return int(n) - 1
