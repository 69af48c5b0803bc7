"""What real optics do to a backlit image: pure functions on grey images (issue 26).

Each effect works on a noise-free grey image (float32, (H, W), grey levels on the 8-bit
scale) and returns a new one; :func:`apply_optics` chains them in the order light meets them:

1. **motion blur** (:func:`motion_blur`): the part moves ``length_px`` along a direction during
   the exposure; a centred box along that direction, so the image shows the part where it
   was at mid-exposure;
2. **defocus** (:func:`defocus`): a Gaussian point spread of ``sigma_px``;
3. **blooming** (:func:`bloom`): a fraction of the light spread in a halo of ``radius_px``
   (energy kept: the bright background loses it near the edge, the dark part gains it);
4. **vignetting** (:func:`vignetting_gain`) and **dust** (:func:`dust_transmission`): what
   the lens and the backlight let through, a factor per pixel; the dust specks are fixed
   per camera (a seed and the camera's index, not the capture's), so they are in the same
   places in every capture and in the empty-field image (:func:`empty_field`).

Sensor noise comes after all of them (the simulator's :func:`~inspector_drivers.sim.render.to_image`).
Blurs extend the image by reflection at its border, so a uniform image stays uniform.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = [
    "Optics",
    "apply_optics",
    "bloom",
    "defocus",
    "dust_transmission",
    "empty_field",
    "field_gain",
    "motion_blur",
    "motion_kernel",
    "vignetting_gain",
]


def vignetting_gain(height: int, width: int, corner: float, model: Literal["cos4", "poly"] = "cos4") -> np.ndarray:
    """Relative illumination of the image, 1 at the centre and ``corner`` at the corners.

    Parameters
    ----------
    height, width : int
        Image size, px.
    corner : float
        Level at the image corners relative to the centre, in (0, 1]; 1: no vignetting.
    model : {"cos4", "poly"}
        ``cos4``: the natural fall-off ``cos^4(theta)`` of a lens whose corner ray makes the
        angle ``theta_c = arccos(corner^(1/4))`` with the axis (``theta = atan(r / f)``, ``f``
        chosen so); ``poly``: the radial polynomial ``1 - (1 - corner) (r / r_c)^2``.

    Returns
    -------
    (height, width) float32
        Gain per pixel, distance ``r`` measured from the image centre ``((W-1)/2, (H-1)/2)``
        (``r_c``: the corners').
    """
    if not 0.0 < corner <= 1.0:
        raise ValueError("vignetting: the corner level must be in (0, 1]")
    cy, cx = (height - 1) / 2.0, (width - 1) / 2.0
    y = (np.arange(height, dtype=np.float64) - cy)[:, None]
    x = (np.arange(width, dtype=np.float64) - cx)[None, :]
    r2 = x * x + y * y
    rc2 = max(cx * cx + cy * cy, 1e-12)
    if corner == 1.0:
        return np.ones((height, width), np.float32)
    if model == "poly":
        return (1.0 - (1.0 - corner) * r2 / rc2).astype(np.float32)
    if model != "cos4":
        raise ValueError(f"vignetting: unknown model {model!r} (cos4, poly)")
    tan_c = math.tan(math.acos(corner**0.25))
    f2 = rc2 / (tan_c * tan_c)
    cos2 = f2 / (f2 + r2)  # cos^2(atan(r / f))
    return (cos2 * cos2).astype(np.float32)


def dust_transmission(
    height: int,
    width: int,
    count: int,
    rng: np.random.Generator,
    *,
    size_px: tuple[float, float] = (1.0, 4.0),
    depth: tuple[float, float] = (0.3, 0.8),
) -> np.ndarray:
    """The light ``count`` dark specks let through, per pixel.

    Each speck is a disc of diameter uniform in ``size_px`` and a depth (the fraction of the
    light it takes where it covers a pixel fully) uniform in ``depth``, its centre uniform
    over the image; the pixel's covered fraction is exact to 1/64 (8 x 8 sub-samples), so
    the specks are anti-aliased as the part is. Overlapping specks multiply.

    Parameters
    ----------
    height, width, count : int
    rng : numpy.random.Generator
        Draws the specks (seed it per camera, not per capture, to keep them in place).
    size_px, depth : (float, float)
        Ranges of the diameter (px) and of the depth (0-1).

    Returns
    -------
    (height, width) float32
        Transmission in (0, 1]; 1 where no speck is.
    """
    t = np.ones((height, width), np.float32)
    sub = (np.arange(8) + 0.5) / 8.0 - 0.5
    for _ in range(int(count)):
        cx, cy = rng.uniform(0.0, width - 1.0), rng.uniform(0.0, height - 1.0)
        r = 0.5 * rng.uniform(*size_px)
        d = rng.uniform(*depth)
        j0, j1 = max(int(math.floor(cx - r)) - 1, 0), min(int(math.ceil(cx + r)) + 2, width)
        i0, i1 = max(int(math.floor(cy - r)) - 1, 0), min(int(math.ceil(cy + r)) + 2, height)
        dx = (np.arange(j0, j1)[:, None] + sub[None, :] - cx) ** 2  # (nj, 8)
        dy = (np.arange(i0, i1)[:, None] + sub[None, :] - cy) ** 2  # (ni, 8)
        inside = dy[:, None, :, None] + dx[None, :, None, :] <= r * r  # (ni, nj, 8, 8)
        cover = inside.mean(axis=(2, 3))
        t[i0:i1, j0:j1] *= (1.0 - d * cover).astype(np.float32)
    return t


def motion_kernel(length_px: float, angle_deg: float) -> np.ndarray:
    """Normalised kernel of a motion of ``length_px`` along ``angle_deg`` (from the image's u
    axis towards v), centred on the motion's midpoint: (2n+1, 2n+1) float32."""
    n = int(math.ceil(length_px / 2.0)) + 1
    k = np.zeros((2 * n + 1, 2 * n + 1), np.float64)
    a = math.radians(angle_deg)
    s = np.linspace(-length_px / 2.0, length_px / 2.0, max(int(64 * length_px), 2))
    x, y = n + s * math.cos(a), n + s * math.sin(a)
    j, i = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - j, y - i
    for di, dj, w in ((0, 0, (1 - fx) * (1 - fy)), (0, 1, fx * (1 - fy)), (1, 0, (1 - fx) * fy), (1, 1, fx * fy)):
        np.add.at(k, (i + di, j + dj), w)
    return (k / k.sum()).astype(np.float32)


def motion_blur(image: np.ndarray, length_px: float, angle_deg: float = 0.0) -> np.ndarray:
    """``image`` (H, W) float32 blurred by a motion of ``length_px`` along ``angle_deg``."""
    import cv2

    if length_px <= 0:
        return image
    return cv2.filter2D(image, -1, motion_kernel(length_px, angle_deg), borderType=cv2.BORDER_REFLECT)


def defocus(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """``image`` (H, W) float32 blurred by a Gaussian point spread of ``sigma_px``."""
    import cv2

    if sigma_px <= 0:
        return image
    return cv2.GaussianBlur(image, (0, 0), sigma_px, borderType=cv2.BORDER_REFLECT)


def bloom(image: np.ndarray, fraction: float, radius_px: float) -> np.ndarray:
    """``fraction`` of the light of ``image`` (H, W) float32 spread in a halo of ``radius_px``.

    ``(1 - fraction) * image + fraction * (halo * image)``, the halo a cone ``1 - r / radius``
    (normalised): a uniform image is unchanged, next to an edge the bright side loses light
    to the dark side, up to ``radius_px`` into it.
    """
    import cv2

    if fraction <= 0 or radius_px <= 0:
        return image
    n = int(math.ceil(radius_px))
    yy, xx = np.mgrid[-n : n + 1, -n : n + 1].astype(np.float64)
    k = np.clip(1.0 - np.hypot(xx, yy) / radius_px, 0.0, None)
    halo = cv2.filter2D(image, -1, (k / k.sum()).astype(np.float32), borderType=cv2.BORDER_REFLECT)
    return ((1.0 - fraction) * image + fraction * halo).astype(np.float32)


@dataclass(frozen=True)
class Optics:
    """The effects of one camera's optics (all off by default).

    Attributes
    ----------
    vignetting : float
        Background level at the image corners relative to the centre (1: none).
    vignetting_model : {"cos4", "poly"}
    dust : int
        Dark specks on this camera's optics.
    dust_size_px, dust_depth : (float, float)
        Ranges of their diameter (px) and depth (0-1).
    dust_seed : int
        With the camera index: the specks' places (the same in every capture).
    bloom_fraction, bloom_radius_px : float
    defocus_px : float
        Gaussian sigma of the defocus, px.
    motion_px, motion_deg : float
        Motion blur length (px) and direction (degrees from u towards v).
    """

    vignetting: float = 1.0
    vignetting_model: Literal["cos4", "poly"] = "cos4"
    dust: int = 0
    dust_size_px: tuple[float, float] = (1.0, 4.0)
    dust_depth: tuple[float, float] = (0.3, 0.8)
    dust_seed: int = 0
    bloom_fraction: float = 0.0
    bloom_radius_px: float = 6.0
    defocus_px: float = 0.0
    motion_px: float = 0.0
    motion_deg: float = 0.0

    @property
    def active(self) -> bool:
        """Whether any effect is on."""
        return (self.vignetting < 1.0 or self.dust > 0 or self.bloom_fraction > 0 or self.defocus_px > 0
                or self.motion_px > 0)

    @property
    def on_background(self) -> bool:
        """Whether an effect shows on the empty field (vignetting or dust)."""
        return self.vignetting < 1.0 or self.dust > 0


def field_gain(optics: Optics, height: int, width: int, camera_index: int) -> np.ndarray:
    """Vignetting x dust of camera ``camera_index``: (height, width) float32 (all 1 when off)."""
    g = vignetting_gain(height, width, optics.vignetting, optics.vignetting_model)
    if optics.dust > 0:
        rng = np.random.default_rng([optics.dust_seed, camera_index])
        g = g * dust_transmission(height, width, optics.dust, rng, size_px=optics.dust_size_px, depth=optics.dust_depth)
    return g


def apply_optics(image: np.ndarray, optics: Optics, camera_index: int = 0, gain: np.ndarray | None = None) -> np.ndarray:
    """The noise-free grey image (H, W) as camera ``camera_index``'s optics deliver it.

    Motion blur, defocus, blooming, then times vignetting and dust (:func:`field_gain`, or
    ``gain`` when given, to reuse it). Returns (H, W) float32, grey levels.
    """
    img = np.asarray(image, np.float32)
    img = motion_blur(img, optics.motion_px, optics.motion_deg)
    img = defocus(img, optics.defocus_px)
    img = bloom(img, optics.bloom_fraction, optics.bloom_radius_px)
    if optics.on_background:
        h, w = img.shape
        img = img * (gain if gain is not None else field_gain(optics, h, w, camera_index))
    return img.astype(np.float32, copy=False)


def empty_field(level: float, optics: Optics, height: int, width: int, camera_index: int = 0,
                gain: np.ndarray | None = None) -> np.ndarray:
    """The noise-free image of the empty rig: the background ``level`` times vignetting and
    dust (blurs leave a uniform field as it is). (height, width) float32."""
    g = gain if gain is not None else field_gain(optics, height, width, camera_index)
    return (np.float32(level) * g).astype(np.float32)
