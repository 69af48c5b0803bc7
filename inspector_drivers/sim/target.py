"""Simulated captures of a calibration target: a ChArUco board or cube seen by the rig.

:func:`render_target` draws what one camera (its own ``K`` and ``dist``) sees of a
:class:`~inspector.calibration.target.Target` at a body -> world pose: printed boards,
paper margins, lens distortion, optical blur and sensor noise. :func:`target_poses` draws
random poses and :func:`simulate_target` yields one :class:`~inspector.model.Capture` per pose
with the true pose in its :class:`~inspector.model.Truth`, so the calibration can be tested
end to end (``inspector simulate --target TARGET.toml --poses N --out DIR``).

Rendering (per camera)
----------------------
1. **Surfaces.** Each board ``b`` is a rectangle in its own plane (OpenCV's board frame:
   origin at the top-left outer corner, x along the first row, y down, print facing -z):
   for ``charuco_cube`` the face's ``side_mm`` square centred on the board (the margin is
   blank paper); for ``charuco`` the board itself, printed on its -z side only, its back
   plain grey. A cube face whose print faces away from the camera lies inside the closed
   cube and is skipped (always hidden by a face in front of it).
2. **Region.** The rectangle's outline, sampled densely, is projected with
   :meth:`~inspector.model.Camera.project` (distortion included); its pixel bounding box
   plus a margin is the only part of the image rendered for that board.
3. **Rays.** Every pixel is sampled at ``s x s`` points (``s = supersample``) on a rotated
   grid centred on the pixel (:func:`sample_offsets`: unbiased, and ``s^2`` distinct
   positions along each image axis, so an edge parallel to an axis is resolved to ``1/s^2``
   px, not the ``1/s`` of a square grid). Their undistorted normalized coordinates are
   interpolated bilinearly from a per-camera-model lattice (every ``4`` px, computed exactly
   with :func:`inspector.kernels.camera.undistort_pixels`, OpenCV's iterative
   ``undistortPoints``; cached, and shared by cameras with the same ``K``, ``dist`` and size).
   The interpolation error is ~``(4 px)^2 / 8`` times the second derivative of the
   undistortion map: ~1e-4 px for ``k1 = 0.1`` at f = 4000 px, and exactly zero without
   distortion (the map is then affine).
4. **Hits.** A board plane maps normalized coordinates to board coordinates by a homography
   ``(X, Y, 1) ~ [e_x e_y o]^-1 (x, y, 1)`` (camera-frame axes and origin of the board),
   whose third component is the inverse depth: a sample hits the board when it is positive and
   ``(X, Y)`` falls in the rectangle; the nearest hit of all boards wins.
5. **Print.** The pattern is looked up (nearest texel, no bias: ``px_per_mm`` is rounded to
   a whole number of texels per square, so OpenCV draws the squares' edges on texel
   boundaries) in ``target.board_image(px_per_mm, b)`` (about 20 texels per mm by default:
   0.05 mm, half a pixel of the default rig). White is ``paper``, black ``ink``.
6. **Image.** Sub-pixels are averaged (box filter: the pixel's area, so edges are
   anti-aliased without a position bias), the image is blurred by a Gaussian of
   ``blur_px`` and Gaussian noise of ``noise_sigma`` grey levels is added; rounded and
   clipped to uint8.

Measured (OpenCV 5.0 ``CharucoDetector`` on the default 16-camera rig, 1024 x 1024 px,
0.1 mm/px, 30 random poses of ``examples/calibration/charuco_cube.toml``, defaults
``supersample=2, blur_px=0.7, noise_sigma=2``): detected corners are within 0.066 px RMS of
the true projections for boards seen within 30 degrees of their normal, 0.08 px at 30-50, 0.10
at 50-60, 0.17 at 60-70, 0.7 at 70-80 (the detector's corner refinement then reaches the
markers' edges, foreshortened to ~3 px from the corner; ``supersample=4`` does not change it);
every camera sees 1 to 3 boards. About 75 ms of CPU per 1024 x 1024 camera (the bounding box of
the target only), ~47 s of CPU for 16 cameras x 30 poses written as capture folders.

Limitations: no shading (every paper surface has the same grey, whatever its slant), no
defocus varying with depth, and the print is point-sampled at ``s x s`` points per pixel (a
texel pattern finer than a sub-pixel aliases; at steep views it is blurred afterwards
anyway). A lens whose distortion folds over (``undistort`` not one-to-one inside the image)
is rendered as OpenCV's ``undistortPoints`` inverts it.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from inspector.kernels import camera as camk
from inspector.model import Camera, Capture, Rig, Truth
from inspector_drivers.sim.simulate import random_pose

if TYPE_CHECKING:  # pragma: no cover
    from inspector.calibration.target import Target

__all__ = ["target_poses", "render_target", "simulate_target", "board_rectangles", "sample_offsets"]

#: Spacing of the undistortion lattice, px.
_LATTICE_PX = 4
#: Grey of the plain back of a one-sided board.
BACK_GREY = 150.0


# --------------------------------------------------------------------------- poses


def _target_centre(target: Target) -> np.ndarray:
    """(3,) float: centre of the target's corners in its body frame, mm (the cube's centre,
    the planar board's middle)."""
    return np.asarray(target.object_points(), float).mean(axis=0)


def target_poses(target: Target, n: int, *, seed: int = 0, offset_mm: float = 8.0) -> np.ndarray:
    """Random body -> world poses of the target in the rig.

    Parameters
    ----------
    target : Target
    n : int
        Number of poses.
    seed : int
        Seed of NumPy's ``default_rng``: the same seed gives the same poses, and the first
        ``k`` poses of ``n`` are those of ``k``.
    offset_mm : float
        The target's centre (the cube's centre, the planar board's middle) lies uniformly in a
        ball of this radius about the world origin, mm.

    Returns
    -------
    (n, 4, 4) float
        Body -> world transforms (mm). Orientations are uniformly random (scipy's
        ``Rotation.random``); for a planar board that makes its printed side's normal uniform
        over the sphere, so about half the cameras of a spherical rig see the print in each
        pose (the other half its back).
    """
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    rng = np.random.default_rng(seed)
    c = _target_centre(target)
    out = np.empty((int(n), 4, 4))
    for i in range(int(n)):
        T = random_pose(rng, float(offset_mm))
        T[:3, 3] -= T[:3, :3] @ c  # rotate about the target's centre, not its body origin
        out[i] = T
    return out


# --------------------------------------------------------------------------- geometry


def board_rectangles(target: Target) -> np.ndarray:
    """(B, 4) float: the surface of each board in its own frame, ``[x0, y0, x1, y1]`` mm.

    The board itself for ``charuco``; the cube's face square (``side_mm``, centred on the
    board) for ``charuco_cube``.
    """
    w, h = target.board_size_mm
    if target.kind == "charuco_cube" and target.side_mm is not None:
        s = float(target.side_mm) / 2.0
        rect = [w / 2.0 - s, h / 2.0 - s, w / 2.0 + s, h / 2.0 + s]
    else:
        rect = [0.0, 0.0, w, h]
    return np.tile(np.asarray(rect, float), (target.n_boards, 1))


def _outline(rect: np.ndarray, per_side: int = 32) -> np.ndarray:
    """(4 * per_side, 3) points along a rectangle's border, z = 0."""
    x0, y0, x1, y1 = rect
    s = np.linspace(0.0, 1.0, per_side, endpoint=False)
    pts = np.concatenate([
        np.stack([x0 + (x1 - x0) * s, np.full_like(s, y0)], 1),
        np.stack([np.full_like(s, x1), y0 + (y1 - y0) * s], 1),
        np.stack([x1 - (x1 - x0) * s, np.full_like(s, y1)], 1),
        np.stack([np.full_like(s, x0), y1 - (y1 - y0) * s], 1),
    ])
    return np.concatenate([pts, np.zeros((len(pts), 1))], axis=1)


@lru_cache(maxsize=32)
def _lattice(K: bytes, dist: bytes, width: int, height: int, step: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Undistorted normalized coordinates on a pixel lattice covering the image.

    Returns ``(x, y, origin)``: two ``(Nv, Nu)`` float64 arrays at pixels
    ``(origin + step * j, origin + step * i)``, ``origin = -0.5 - step``.
    """
    Km = np.frombuffer(K, float).reshape(3, 3)
    dm = np.frombuffer(dist, float)
    origin = -0.5 - step
    nu = int(np.ceil((width + 2 * step) / step)) + 1
    nv = int(np.ceil((height + 2 * step) / step)) + 1
    uu, vv = np.meshgrid(origin + step * np.arange(nu), origin + step * np.arange(nv))
    xy = camk.undistort_pixels(np.stack([uu.ravel(), vv.ravel()], 1), Km, dm)
    x = np.ascontiguousarray(xy[:, 0].reshape(nv, nu))
    y = np.ascontiguousarray(xy[:, 1].reshape(nv, nu))
    x.setflags(write=False)
    y.setflags(write=False)
    return x, y, origin


def _interp_axis(coords: np.ndarray, origin: float, step: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Lattice cell index and weight of each coordinate along one axis."""
    f = (coords - origin) / step
    i = np.clip(np.floor(f).astype(np.int64), 0, n - 2)
    return i, (f - i)


def sample_offsets(s: int) -> np.ndarray:
    """(s * s, 2) float: the sub-pixel sample offsets ``(du, dv)`` from a pixel's centre.

    A rotated grid (the ``s x s`` square grid turned by ``atan(1 / s)``): sample ``(i, j)``
    sits at ``((i s + j + 0.5) / s^2 - 0.5, (j s + s - 1 - i + 0.5) / s^2 - 0.5)``. It has
    the pixel's centre as its mean (no position bias), and its ``s^2`` samples take ``s^2``
    distinct values along each axis, so an edge parallel to an image axis is resolved to
    ``1 / s^2`` of a pixel instead of the ``1 / s`` of a square grid (for ``s = 1``: the
    pixel's centre).
    """
    s = int(s)
    i, j = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
    n = float(s * s)
    du = (i * s + j + 0.5) / n - 0.5
    dv = (j * s + (s - 1 - i) + 0.5) / n - 0.5
    return np.stack([du.ravel(), dv.ravel()], axis=1)


def _normalized_grid(cam: Camera, u0: int, v0: int, u1: int, v1: int, offsets: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalized coordinates of the samples of pixels ``[u0, u1) x [v0, v1)``.

    Returns two ``(S, v1 - v0, u1 - u0)`` float32 arrays: sample ``k`` of pixel ``(u, v)``
    is at ``(u, v) + offsets[k]``.
    """
    K = np.ascontiguousarray(cam.K, float)
    lx, ly, origin = _lattice(K.tobytes(), np.ascontiguousarray(cam.dist, float).tobytes(),
                              int(cam.width), int(cam.height), _LATTICE_PX)
    shape = (len(offsets), v1 - v0, u1 - u0)
    out = (np.empty(shape, np.float32), np.empty(shape, np.float32))
    for k, (du, dv) in enumerate(offsets):
        iu, wu = _interp_axis(np.arange(u0, u1) + du, origin, _LATTICE_PX, lx.shape[1])
        iv, wv = _interp_axis(np.arange(v0, v1) + dv, origin, _LATTICE_PX, lx.shape[0])
        rows = np.arange(iv.min(), iv.max() + 2)
        r = iv - rows[0]
        for lat, dst in zip((lx, ly), out):
            sub = lat[rows]
            a = sub[:, iu] * (1.0 - wu) + sub[:, iu + 1] * wu  # along u, on the lattice rows
            dst[k] = (1.0 - wv)[:, None] * a[r] + wv[:, None] * a[r + 1]
    return out


# --------------------------------------------------------------------------- texture

_TEXTURES: dict[tuple[str, int, float, str], tuple[np.ndarray, int, int, int]] = {}


def _texture(target: Target, b: int, px_per_mm: float, rect: np.ndarray, paper: float, ink: float
             ) -> tuple[np.ndarray, int, int, int]:
    """Board ``b``'s print as grey levels, padded with paper to cover ``rect``.

    Returns ``(flat, width, pad_x, pad_y)``: the flattened float32 texture, its width, and the
    texels added left and above: board coordinate ``(X, Y)`` is texel
    ``(floor(Y * px_per_mm) + pad_y, floor(X * px_per_mm) + pad_x)``.
    """
    key = (json.dumps(target.to_json(), sort_keys=True), int(b), float(px_per_mm),
           f"{rect.tolist()}/{paper}/{ink}")
    if key in _TEXTURES:
        return _TEXTURES[key]
    img = target.board_image(px_per_mm, b).astype(np.float32)
    grey = np.float32(ink) + (np.float32(paper) - np.float32(ink)) * img / np.float32(255.0)
    x0, y0, x1, y1 = (float(v) for v in rect)
    h, w = grey.shape
    px0 = max(0, int(np.ceil(-x0 * px_per_mm)) + 1)
    py0 = max(0, int(np.ceil(-y0 * px_per_mm)) + 1)
    px1 = max(0, int(np.ceil(x1 * px_per_mm)) - w + 1)
    py1 = max(0, int(np.ceil(y1 * px_per_mm)) - h + 1)
    padded = np.pad(grey, ((py0, py1), (px0, px1)), constant_values=np.float32(paper))
    entry = (np.ascontiguousarray(padded).ravel(), padded.shape[1], px0, py0)
    if len(_TEXTURES) > 64:
        _TEXTURES.clear()
    _TEXTURES[key] = entry
    return entry


# --------------------------------------------------------------------------- rendering


def _board_in_camera(cam: Camera, pose: np.ndarray, face: np.ndarray) -> np.ndarray:
    """(4, 4) board -> camera transform."""
    W2C = np.eye(4)
    W2C[:3, :3] = cam.R
    W2C[:3, 3] = cam.t
    return W2C @ np.asarray(pose, float) @ np.asarray(face, float)


def _pixel_box(cam: Camera, B2C: np.ndarray, rect: np.ndarray, margin: int) -> tuple[int, int, int, int] | None:
    """Pixel box ``(u0, v0, u1, v1)`` (half-open, clipped to the image) holding the
    projection of the board rectangle, or None when it misses the image."""
    pts = _outline(rect) @ B2C[:3, :3].T + B2C[:3, 3]
    if np.any(pts[:, 2] <= 1e-6):
        return 0, 0, int(cam.width), int(cam.height)  # reaches behind the camera: everything
    uv, _ = camk.project(pts, cam.K, cam.dist, np.eye(3), np.zeros(3))
    if not np.all(np.isfinite(uv)):
        return 0, 0, int(cam.width), int(cam.height)
    u0 = max(int(np.floor(uv[:, 0].min())) - margin, 0)
    v0 = max(int(np.floor(uv[:, 1].min())) - margin, 0)
    u1 = min(int(np.ceil(uv[:, 0].max())) + margin + 1, int(cam.width))
    v1 = min(int(np.ceil(uv[:, 1].max())) + margin + 1, int(cam.height))
    if u0 >= u1 or v0 >= v1:
        return None
    return u0, v0, u1, v1


def _shade_board(x: np.ndarray, y: np.ndarray, grey: np.ndarray, best: np.ndarray | None, Gi: np.ndarray,
                 rect: np.ndarray, px_per_mm: float, texture: tuple[np.ndarray, int, int, int] | None,
                 back: float) -> None:
    """Paint one board into ``grey`` (in place) where its rectangle is hit (and, with a
    ``best`` inverse-depth buffer, where it is nearer than what is there)."""
    G = np.asarray(Gi, np.float32)
    ppm = np.float32(px_per_mm)
    w = G[2, 0] * x
    w += G[2, 1] * y
    w += G[2, 2]  # inverse depth (scaled): > 0 in front of the camera
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inv = np.divide(ppm, w)
        X = G[0, 0] * x
        X += G[0, 1] * y
        X += G[0, 2]
        X *= inv  # board x, texels
        Y = G[1, 0] * x
        Y += G[1, 1] * y
        Y += G[1, 2]
        Y *= inv
    rx0, ry0, rx1, ry1 = (np.float32(v * px_per_mm) for v in rect)
    hit = w > (0.0 if best is None else best)
    hit &= X >= rx0
    hit &= X < rx1
    hit &= Y >= ry0
    hit &= Y < ry1
    if not hit.any():
        return
    if texture is None:
        np.copyto(grey, np.float32(back), where=hit)
    else:
        flat, tw, pad_x, pad_y = texture
        th = flat.size // tw
        # Clamp to the texture (NaN and inf too: fmax/fmin drop NaN), then texel indices.
        for A, pad, n in ((X, pad_x, tw), (Y, pad_y, th)):
            np.fmax(A, np.float32(-pad), out=A)
            np.fmin(A, np.float32(n - 1 - pad), out=A)
            np.floor(A, out=A)
        ix = X.astype(np.int32)
        ix += pad_x
        iy = Y.astype(np.int32)
        iy += pad_y
        iy *= tw
        iy += ix
        np.copyto(grey, flat.take(iy), where=hit)
    if best is not None:
        np.copyto(best, w, where=hit)


def _visible_boards(target: Target, cam: Camera, pose: np.ndarray, rects: np.ndarray,
                    margin: int) -> list[tuple[int, np.ndarray, tuple[int, int, int, int], bool]]:
    """The target's boards camera ``cam`` sees (not edge-on, not a cube's far faces, in the image).

    Parameters
    ----------
    pose : (4, 4) float
        Target body -> world transform, mm.
    rects : (B, 4) float
        Each board's surface in its own frame, mm (:func:`board_rectangles`).
    margin : int
        Pixels added around each board's box (the blur's reach).

    Returns
    -------
    list of (b, Gi, box, front)
        Board index; ``Gi`` (3, 3), ``(X, Y, 1) ~ Gi @ (x, y, 1)`` from normalised image
        coordinates to the board's (mm), scaled so its 3rd component is ``dist_o / depth``
        (> 0 in front); its pixel box ``(u0, v0, u1, v1)`` (:func:`_pixel_box`); whether the
        camera sees its printed (-z) side.
    """
    boards = []  # (b, Gi, box, front)
    for b in range(target.n_boards):
        B2C = _board_in_camera(cam, pose, target.faces[b])
        ex, ey, nz, o = B2C[:3, 0], B2C[:3, 1], B2C[:3, 2], B2C[:3, 3]
        facing = float(nz @ o)  # > 0: the camera is on the board's -z (printed) side
        dist_o = float(np.linalg.norm(o))
        if abs(facing) < 1e-9 * dist_o:
            continue  # edge-on: no area
        front = facing > 0.0
        if target.kind == "charuco_cube" and not front:
            continue  # inside the closed cube: hidden by the faces in front of it
        box = _pixel_box(cam, B2C, rects[b], margin)
        if box is None:
            continue
        # (X, Y, 1) ~ Gi @ (x, y, 1); scaled so its 3rd component is dist_o / depth (> 0 in front)
        Gi = np.linalg.inv(np.stack([ex, ey, o], axis=1)) * dist_o
        boards.append((b, Gi, box, front))
    return boards


def render_target(
    target: Target,
    cam: Camera,
    pose: np.ndarray,
    *,
    supersample: int = 2,
    blur_px: float = 0.7,
    noise_sigma: float = 2.0,
    rng: np.random.Generator | None = None,
    paper: float = 220.0,
    ink: float = 25.0,
    background: float = 90.0,
    back: float = BACK_GREY,
    px_per_mm: float = 20.0,
) -> np.ndarray:
    """The image camera ``cam`` takes of ``target`` at ``pose``.

    Parameters
    ----------
    target : Target
        A ``charuco`` board (printed on its -z side, plain ``back`` grey behind) or a
        ``charuco_cube`` (each face a ``side_mm`` paper square with its board in the middle).
    cam : Camera
        The camera, with its own ``K``, ``dist`` (OpenCV model), ``R``, ``t`` and size.
    pose : (4, 4) float
        Target body -> world transform, mm.
    supersample : int
        Samples per pixel side: ``supersample**2`` samples (:func:`sample_offsets`) averaged
        per pixel.
    blur_px : float
        Sigma of the Gaussian blur, px (0: none).
    noise_sigma : float
        Sigma of the additive Gaussian noise, grey levels (0: none).
    rng : numpy.random.Generator, optional
        Source of the noise (default: ``default_rng(0)``).
    paper, ink, background, back : float
        Grey levels (0..255) of white paper, black print, the empty rig, and the plain back
        of a one-sided board.
    px_per_mm : float
        Resolution of the print looked up, texels per mm; rounded so that a square is a whole
        number of texels (its edges then fall on texel boundaries exactly).

    Returns
    -------
    (H, W) uint8
        The camera's image; pixel ``(u, v)`` covers ``[u - 0.5, u + 0.5] x [v - 0.5, v + 0.5]``.
    """
    import cv2

    s = int(supersample)
    if s < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    H, W = int(cam.height), int(cam.width)
    img: np.ndarray = np.full((H, W), np.float32(background), np.float32)
    rects = board_rectangles(target)
    margin = 2 + int(np.ceil(3.0 * max(float(blur_px), 0.0)))
    sq = float(target.square_mm)
    px_per_mm = max(1, round(sq * float(px_per_mm))) / sq  # whole texels per square

    boards = _visible_boards(target, cam, pose, rects, margin)
    if boards:
        u0 = min(bx[2][0] for bx in boards)
        v0 = min(bx[2][1] for bx in boards)
        u1 = max(bx[2][2] for bx in boards)
        v1 = max(bx[2][3] for bx in boards)
        xs, ys = _normalized_grid(cam, u0, v0, u1, v1, sample_offsets(s))
        grey = np.full(xs.shape, np.float32(background), np.float32)
        # Front faces of a convex cube never overlap in an image, and a planar target has one
        # board: the depth test is needed only for other bodies.
        best = None if (target.kind == "charuco_cube" or len(boards) == 1) else np.zeros(xs.shape, np.float32)
        for b, Gi, (bu0, bv0, bu1, bv1), front in boards:
            sl = (slice(None), slice(bv0 - v0, bv1 - v0), slice(bu0 - u0, bu1 - u0))
            texture = _texture(target, b, px_per_mm, rects[b], paper, ink) if front else None
            _shade_board(xs[sl], ys[sl], grey[sl], None if best is None else best[sl], Gi, rects[b],
                         px_per_mm, texture, back)
        img[v0:v1, u0:u1] = grey.mean(axis=0)

    if blur_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), sigmaX=float(blur_px), sigmaY=float(blur_px),
                               borderType=cv2.BORDER_REPLICATE)
    if noise_sigma > 0:
        rng = rng if rng is not None else np.random.default_rng(0)
        img += rng.standard_normal((H, W), dtype=np.float32) * np.float32(noise_sigma)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


# --------------------------------------------------------------------------- captures


def simulate_target(
    target: Target,
    rig: Rig,
    n_poses: int,
    *,
    seed: int = 0,
    blur_px: float = 0.7,
    noise_sigma: float = 2.0,
    supersample: int = 2,
    offset_mm: float = 8.0,
) -> Iterator[Capture]:
    """Simulated captures of ``target`` in ``n_poses`` random poses, rendered as they are asked for.

    Parameters
    ----------
    target : Target
    rig : Rig
        Every camera renders every pose (its own ``K``, ``dist``, size and pose).
    n_poses : int
    seed : int
        Poses are :func:`target_poses` of ``seed``; the noise of pose ``i``, camera ``j``
        comes from ``default_rng([seed, i, j])`` (deterministic, whatever is rendered first).
    blur_px, noise_sigma, supersample
        As :func:`render_target`.
    offset_mm : float
        Largest distance of the target's centre from the rig centre, mm.

    Yields
    ------
    Capture
        Named ``pose_000``, ``pose_001``, ...: one uint8 image per camera, polarity
        ``dark-object``, ``metadata`` ``{"part_id": "calibration-target", "simulated": True,
        "pose_index": i, "seed": seed}`` and a :class:`~inspector.model.Truth` (no mesh) whose
        ``info`` holds ``"target_pose"`` (the 4x4 body -> world transform as nested lists, mm),
        ``"target"`` (:meth:`Target.to_json`) and the rendering settings.
    """
    poses = target_poses(target, n_poses, seed=seed, offset_mm=offset_mm)
    for i, pose in enumerate(poses):
        images = {
            cam.name: render_target(target, cam, pose, supersample=supersample, blur_px=blur_px,
                                    noise_sigma=noise_sigma, rng=np.random.default_rng([int(seed), i, j]))
            for j, cam in enumerate(rig.cameras)
        }
        info = {
            "target_pose": pose.tolist(),
            "target": target.to_json(),
            "seed": int(seed),
            "pose_index": i,
            "blur_px": float(blur_px),
            "noise_sigma": float(noise_sigma),
            "supersample": int(supersample),
        }
        yield Capture(
            name=f"pose_{i:03d}",
            rig=rig,
            images=images,
            polarity="dark-object",
            metadata={"part_id": "calibration-target", "simulated": True, "pose_index": i, "seed": int(seed)},
            truth=Truth(None, info),
        )
