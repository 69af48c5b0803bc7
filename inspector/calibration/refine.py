"""``inspector calibrate --refine``: a rig refined from the silhouettes of the parts it inspects.

::

    inspector calibrate --refine RIG.json --captures DIR --reference MESH --out RIG2.json
                        [--intrinsics] [--recipe R] [--json] [--force]

Every contour ray of a good part grazes it; with the reference placed where the part is,
each ray's *silhouette residual* (its smallest signed distance to the reference along the
ray, :mod:`inspector.kernels.silhouette_fit`) is zero up to image noise (0.015 px median on
the simulated rig). A camera whose rig entry is off sees the part where the rig does not
expect it: its rays miss the reference on one side of the silhouette and cut into it on the
other. The refinement moves every camera, and every capture's part, until the rays graze:

1. each capture is inspected with the input rig and the recipe (default: the shipped
   ``default.toml``): the part's pose and size model (the bcps stage's), its silhouettes and
   the range along each contour ray where the part can be (from its visual hull);
2. robust Gauss-Newton (Levenberg-Marquardt: soft-L1 loss at ``ROBUST_PX``, then Tukey's at
   a few robust sigmas of the residuals) over every camera's turn about its centre and
   centre shift (and with ``--intrinsics`` its focal lengths and principal point) and every
   capture's rigid pose and residual offset; the grazing points are found again at every
   iteration (the Jacobians hold at them by the envelope theorem); a weak prior keeps each
   centre shift near the input rig's (``SHIFT_SIGMA_MM``);
3. the gauge is fixed by exact constraints: the mean of the camera turns and the mean of the
   centre shifts are zero (over the cameras that agree: a camera whose change stands out
   from the others' by more than ``GAUGE_SIGMAS`` robust sigmas, and ``GAUGE_FLOOR_PX``, is left
   out of the means, so one knocked camera does not turn the frame), and the mean camera
   distance to the origin is unchanged: the frame and the scale stay the input rig's.

Each part is held at the size the bcps stage measured (its size model; the identity for a
part of nominal size): with the rig's scale held, a size free per capture would be another
name for the residual offset each capture has (a uniform offset of a cube's silhouettes and
a change of its size look alike) and for the rig's scale, which the constraints fix. The
offset absorbs what all cameras see alike on a part (its size within tolerance, the
segmentation's bias), which is no camera's fault.

The report gives, per camera, the median absolute residual (px, each capture's median
removed) before and after, and the turn and shift found; the rig is written whole with a
``refinement`` object. Bad inputs are one line and exit 2, with nothing written.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from inspector.capture_folder import expand, is_capture_folder, parse_rig, read_capture, read_rig
from inspector.errors import InspectorError, RecipeError
from inspector.kernels import bcps as bk
from inspector.kernels import silhouette_fit as sf
from inspector.kernels.robust import tukey, tukey_loss
from inspector.manager import create_plugin_manager
from inspector.model import Camera, Rig
from inspector.recipe import load_recipe
from inspector.reference import Reference
from inspector.resources import recipe_path
from inspector.runner import inspect_capture

if TYPE_CHECKING:
    from inspector.manager import PluginManager
    from inspector.recipe import Recipe

__all__ = ["PartView", "Refinement", "refine_rig", "InspectedCapture", "inspect_with_rig",
           "load_inputs", "placed_field", "ROBUST_PX"]

#: Scale of the soft-L1 loss, px: residuals within it count fully, beyond it less and less.
ROBUST_PX = 0.5
#: The gauge's means leave out a camera whose turn or shift stands out from the others' by
#: more than this many robust sigmas, and at least ``GAUGE_FLOOR_PX``.
GAUGE_SIGMAS = 3.0
GAUGE_FLOOR_PX = 0.5
#: The second phase's Tukey cutoff: this many robust sigmas of the residuals, at least
#: ``TUKEY_FLOOR_PX``.
TUKEY_SIGMAS = 4.685
TUKEY_FLOOR_PX = 0.05
#: A weak prior on each camera's centre shift, mm (about what a target calibration gives
#: its centres). The silhouettes tell a camera's turn from a shift that moves the part's image
#: alike only by perspective (a 0.1 mm shift at 400 mm changes a 30 mm part's silhouette by
#: ~0.04 px beyond what a turn does): without it, the shifts drift along that direction
#: with whatever the model does not explain (8 cameras, 0.4 mm/px: turns of 0.1-0.3 px on
#: cameras that did not move, traded for shifts; the cost lower by 1 %).
SHIFT_SIGMA_MM = 0.5
#: With ``--intrinsics``, a weak prior on the changes of ``fx, fy, cx, cy``, px: a principal
#: point moved by a pixel looks like the camera turned by a pixel (a narrow lens), a focal
#: length like the camera moved along its axis; the turns and shifts explain such changes first.
INTRINSICS_SIGMA_PX = 2.0
#: Every n-th contour point of each camera gives a ray.
STRIDE = 2
#: The search along each ray: coarse step (mm) and refinement levels (each 4 times finer).
STEP_MM = 0.25
LEVELS = 5
#: Iterations at most, and the step (px, largest over every camera) below which it has converged.
ITERATIONS = 30
CONVERGED_PX = 0.005
#: After the first search, each ray's minimum is looked for within this (mm) of the last one.
WINDOW_MM = 0.75
#: Widening of each ray's range (mm) beyond the input rig's visual hull, for the moves.
RANGE_MARGIN_MM = 1.0
#: Residual (px) an invalid ray costs (it left its range or found no surface).
_INVALID_PX = 5.0

Progress = Callable[[str], None]


# --------------------------------------------------------------------------------------- model


@dataclass(frozen=True, eq=False)
class PartView:
    """One capture as the refinement sees it.

    Attributes
    ----------
    name : str
    contours : sequence of (M_i, 2) float
        Each camera's sub-pixel contour points (the rays' pixels), in the rig's camera order.
    ranges : sequence of ((M_i,), (M_i,)) float
        Where along each ray the part can be, mm from the camera centre.
    placement : (4, 4) float
        The sized reference's placement (reference -> world; its linear part is the size
        model's scale times a rotation).
    scale : float
        The size model's scale (the signed distance is ``scale * sd_ref(placement^-1 x)``).
    """

    name: str
    contours: Sequence[np.ndarray]
    ranges: Sequence[tuple[np.ndarray, np.ndarray]]
    placement: np.ndarray
    scale: float = 1.0


@dataclass(frozen=True, eq=False)
class Refinement:
    """What :func:`refine_rig` found.

    Attributes
    ----------
    rig : Rig
        The refined rig.
    before_px, after_px : (C,) float
        Each camera's median absolute silhouette residual, px (each capture's median over
        every camera removed), with the input rig and the parts' pipeline poses, and after.
    turn_px : (C,) float
        Each camera's turn about its centre, px (angle times focal length).
    turn : (C, 3) float
        The turns as world rotation vectors, rad.
    shift_mm : (C, 3) float
        Each camera's centre shift, world mm.
    intrinsics : (C, 4) float or None
        Changes of ``fx, fy, cx, cy``, px (None: not refined).
    placements : tuple of (4, 4) float
        Each capture's refined placement.
    offset_mm : (K,) float
        Each capture's residual offset, mm.
    rays : (C,) int
        Residuals each camera's figures stand on (after).
    iterations : int
    converged : bool
    gauge_cameras : tuple of str
        The cameras whose means fix the gauge.
    cost : tuple of float
        The robust cost per accepted iteration (first: before).
    """

    rig: Rig
    before_px: np.ndarray
    after_px: np.ndarray
    turn_px: np.ndarray
    turn: np.ndarray
    shift_mm: np.ndarray
    intrinsics: np.ndarray | None
    placements: tuple[np.ndarray, ...]
    offset_mm: np.ndarray
    rays: np.ndarray
    iterations: int
    converged: bool
    gauge_cameras: tuple[str, ...]
    cost: tuple[float, ...] = field(default_factory=tuple)


def placed_field(index: Any, placement: np.ndarray, scale: float) -> tuple[Callable[[np.ndarray], np.ndarray],
                                                                            Callable[[np.ndarray], np.ndarray]]:
    """The signed distance (world mm -> mm, NaN beyond the index's band) and its unit outward
    gradient of the reference under ``placement`` (maybe scaled by ``scale``), from its
    distance index (:class:`~inspector.kernels.meshdist.MeshDistance`)."""
    A = np.asarray(placement, float)
    inv = np.linalg.inv(A)
    Li, ti = inv[:3, :3], inv[:3, 3]
    M = A[:3, :3] / float(scale)  # a rotation (the distance's gradient turns with it)

    def sd(X: np.ndarray) -> np.ndarray:
        return float(scale) * index.near(X @ Li.T + ti)

    def normal(X: np.ndarray) -> np.ndarray:
        p = X @ Li.T + ti
        s = index.near(p)
        c, tid = index.closest(p)
        v = p - c
        nv = np.linalg.norm(v, axis=1)
        far = (nv > 1e-9) & np.isfinite(s)
        g = np.where(far[:, None], v / np.where(far, nv, 1.0)[:, None] * np.sign(np.where(far, s, 1.0))[:, None],
                     index.pn[np.maximum(tid, 0), 0])
        g[(tid < 0) | ~np.isfinite(s)] = np.nan
        return g @ M.T

    return sd, normal


class _Problem:
    """The parameters, residuals and Jacobians of one refinement."""

    def __init__(self, rig: Rig, parts: Sequence[PartView], index: Any, intrinsics: bool) -> None:
        self.rig, self.parts, self.index = rig, list(parts), index
        self.nc = 10 if intrinsics else 6
        self.intrinsics = intrinsics
        self.C = len(rig)
        self.K = len(self.parts)
        self.n = self.C * self.nc + self.K * 7
        self.centres0 = np.array([c.centre for c in rig.cameras])
        self.focal = np.array([float(np.sqrt(c.K[0, 0] * c.K[1, 1])) for c in rig.cameras])
        mid = np.mean([p.placement[:3, 3] for p in self.parts], axis=0) if self.parts else np.zeros(3)
        self.depth = np.array([max(float(c.R[2] @ (mid - c.centre)), 1e-6) for c in rig.cameras])
        # Weak priors on each camera's centre shift and intrinsics (SHIFT_SIGMA_MM, INTRINSICS_SIGMA_PX).
        self.prior = np.zeros(self.n)
        for i in range(self.C):
            s = self.cam(i).start
            if SHIFT_SIGMA_MM:
                self.prior[s + 3: s + 6] = 1.0 / SHIFT_SIGMA_MM ** 2
            if intrinsics and INTRINSICS_SIGMA_PX:
                self.prior[s + 6: s + 10] = 1.0 / INTRINSICS_SIGMA_PX ** 2

    # layout
    def cam(self, i: int) -> slice:
        return slice(i * self.nc, (i + 1) * self.nc)

    def part(self, k: int) -> slice:
        o = self.C * self.nc
        return slice(o + 7 * k, o + 7 * (k + 1))

    def camera(self, x: np.ndarray, i: int) -> Camera:
        c0 = self.rig.cameras[i]
        p = x[self.cam(i)]
        R, t = sf.turn_camera(c0.R, c0.t, p[:3], p[3:6])
        K = np.array(c0.K, float)
        if self.intrinsics:
            K[0, 0] += p[6]
            K[1, 1] += p[7]
            K[0, 2] += p[8]
            K[1, 2] += p[9]
        return Camera(c0.name, c0.width, c0.height, K, c0.dist, R, t)

    def placement(self, x: np.ndarray, k: int) -> np.ndarray:
        p = x[self.part(k)]
        return sf.twist_pose(self.parts[k].placement, p[:3], p[3:6])

    def evaluate(self, x: np.ndarray, prev: list[dict[str, Any]] | None = None) -> list[dict[str, Any]]:
        """Per (capture, camera) block: the residuals (px, offset removed), their validity,
        where along the rays they are and the Jacobian blocks, px per parameter unit. With
        ``prev`` (blocks of a nearby ``x``) each ray is searched near its earlier minimum."""
        cams = [self.camera(x, i) for i in range(self.C)]
        guesses = {(b["k"], b["i"]): b["t"] for b in prev} if prev is not None else {}
        blocks = []
        for k, part in enumerate(self.parts):
            sd, normal = placed_field(self.index, self.placement(x, k), part.scale)
            off = x[self.part(k)][6]
            # Every camera's rays of this capture in one search (one distance query per step).
            which = [i for i in range(self.C) if len(part.contours[i])]
            if not which:
                continue
            rays = [cams[i].rays(part.contours[i]) for i in which]
            sizes = [len(part.contours[i]) for i in which]
            origins = np.concatenate([np.broadcast_to(o, (m, 3)) for (o, _), m in zip(rays, sizes)])
            dirs = np.concatenate([d for _, d in rays])
            t0 = np.concatenate([part.ranges[i][0] for i in which]) - RANGE_MARGIN_MM
            t1 = np.concatenate([part.ranges[i][1] for i in which]) + RANGE_MARGIN_MM
            guess = (np.concatenate([guesses.get((k, i), np.full(m, np.nan)) for i, m in zip(which, sizes)])
                     if guesses else None)
            g = sf.grazes(origins, dirs, t0, t1, sd, normal, step_mm=STEP_MM, levels=LEVELS, guess=guess,
                          window_mm=WINDOW_MM)
            start = 0
            for i, m, (origin, _) in zip(which, sizes, rays):
                cam, sl = cams[i], slice(start, start + m)
                start += m
                ok, q_all, t_all = g.ok[sl], g.q[sl], g.t[sl]
                z = np.where(ok, (np.nan_to_num(q_all) - origin) @ cam.R[2], 1.0)
                px = self.focal[i] / np.maximum(z, 1e-6)
                r = np.where(ok, (g.r[sl] - off) * px, np.nan)
                q, n = q_all[ok], g.n[sl][ok]
                Jc = sf.camera_jacobian(origin, q, n)
                if self.intrinsics:
                    dd = sf.direction_derivatives(part.contours[i][ok], cam.K, cam.dist, cam.R)
                    Jc = np.concatenate([Jc, sf.intrinsics_jacobian(t_all[ok], n, dd)], axis=1)
                Jp = np.concatenate([sf.pose_jacobian(q, n), -np.ones((len(q), 1))], axis=1)
                blocks.append({"k": k, "i": i, "r": r, "ok": ok, "t": t_all, "Jc": Jc * px[ok, None],
                               "Jp": Jp * px[ok, None]})
        return blocks

    # units: a parameter change's effect in px, for the steps and the gauge
    def cam_px(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each camera's turn (C, 3) and shift (C, 3) in px at the parts."""
        P = x[: self.C * self.nc].reshape(self.C, self.nc)
        return P[:, :3] * self.focal[:, None], P[:, 3:6] * (self.focal / self.depth)[:, None]


def _loss(r: np.ndarray, c: float, kind: str) -> tuple[np.ndarray, np.ndarray]:
    """The robust loss of residuals ``r`` at scale ``c`` and its IRLS weight (both losses
    ``r^2 / 2`` for small ``r``): soft-L1 ``c^2 (sqrt(1 + (r/c)^2) - 1)``, weight ``1/sqrt(1 + (r/c)^2)``; or Tukey's biweight
    ``c^2/6 (1 - (1 - (r/c)^2)^3)`` (constant beyond ``c``), weight ``(1 - (r/c)^2)^2``."""
    if kind == "soft_l1":
        u = 1.0 + (r / c) ** 2
        return c * c * (np.sqrt(u) - 1.0), 1.0 / np.sqrt(u)
    return c * c / 6.0 * tukey_loss(r, c), tukey(r, c)


def _cost(blocks: list[dict[str, Any]], c: float, kind: str) -> float:
    total = 0.0
    bad, _ = _loss(np.array([max(_INVALID_PX, 2.0 * c)]), c, kind)
    for b in blocks:
        ok = b["ok"]
        loss, _ = _loss(b["r"][ok], c, kind)
        total += float(loss.sum()) + float(bad[0]) * int((~ok).sum())
    return total


def _normal_equations(pb: _Problem, blocks: list[dict[str, Any]], c: float,
                      kind: str) -> tuple[np.ndarray, np.ndarray]:
    H = np.zeros((pb.n, pb.n))
    g = np.zeros(pb.n)
    for b in blocks:
        ok = b["ok"]
        r = b["r"][ok]
        if not len(r):
            continue
        _, w = _loss(r, c, kind)
        ci, pk = pb.cam(b["i"]), pb.part(b["k"])
        Jc, Jp = b["Jc"], b["Jp"]
        WJc, WJp = Jc * w[:, None], Jp * w[:, None]
        H[ci, ci] += Jc.T @ WJc
        H[pk, pk] += Jp.T @ WJp
        cp = Jc.T @ WJp
        H[ci, pk] += cp
        H[pk, ci] += cp.T
        g[ci] += WJc.T @ r
        g[pk] += WJp.T @ r
    return H, g


def _agreeing(v: np.ndarray) -> np.ndarray:
    """(C,) bool: the rows of ``v`` (C, 3), px, within ``GAUGE_SIGMAS`` robust sigmas (and
    ``GAUGE_FLOOR_PX``) of their median."""
    m = np.median(v, axis=0)
    dev = np.linalg.norm(v - m, axis=1)
    cut = max(GAUGE_SIGMAS * 1.4826 * float(np.median(dev)), GAUGE_FLOOR_PX)
    keep = dev <= cut
    for _ in range(3):  # the median of the ones kept (a knocked camera moved the median a little)
        m = v[keep].mean(axis=0) if keep.any() else m
        dev = np.linalg.norm(v - m, axis=1)
        keep = dev <= cut
    return keep if keep.sum() >= 3 else np.ones(len(v), bool)


def _constraints(pb: _Problem, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gauge rows ``A`` (7 or 8, n): the mean turn and mean shift over the agreeing cameras, the
    change of the mean distance to the origin (all cameras) and, with the intrinsics, the
    mean relative change of the focal lengths, each zero; and which cameras agree.

    The silhouettes cannot tell every camera's focal length grown alike from every part grown
    alike (each capture's residual offset): the focal lengths' scale stays the input rig's."""
    turn, shift = pb.cam_px(x)
    keep = _agreeing(turn) & _agreeing(shift)
    A = np.zeros((8 if pb.intrinsics else 7, pb.n))
    w = keep / max(int(keep.sum()), 1)
    unit = pb.centres0 / np.maximum(np.linalg.norm(pb.centres0, axis=1, keepdims=True), 1e-9)
    for i in range(pb.C):
        s = pb.cam(i).start
        for a in range(3):
            A[a, s + a] = w[i] * pb.focal[i]  # px
            A[3 + a, s + 3 + a] = w[i] * pb.focal[i] / pb.depth[i]
        A[6, s + 3: s + 6] = unit[i] * pb.focal[i] / pb.depth[i] / pb.C
        if pb.intrinsics:
            A[7, s + 6: s + 8] = 1.0 / pb.C  # px of focal length
    return A, keep


def _solve(H: np.ndarray, g: np.ndarray, A: np.ndarray, rhs: np.ndarray, lam: float) -> np.ndarray:
    """The damped Gauss-Newton step ``dx`` minimising ``dx' H dx / 2 + g' dx + lam/2 dx' diag(H) dx``
    with ``A dx = rhs`` (KKT, Jacobi-scaled)."""
    d = np.sqrt(np.maximum(np.diag(H), 0.0))
    d = np.where(d > 0, d, 1.0)
    Hs = H / d[:, None] / d[None, :]
    Hs = Hs + lam * np.eye(len(d)) + 1e-12 * np.eye(len(d))
    As = A / d[None, :]
    m = len(A)
    KKT = np.block([[Hs, As.T], [As, np.zeros((m, m))]])
    sol = np.linalg.lstsq(KKT, np.concatenate([-g / d, rhs]), rcond=None)[0]
    return sol[: len(d)] / d


def _median_abs(pb: _Problem, blocks: list[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray]:
    """Each camera's median absolute residual (px, each capture's median removed) and count."""
    per_cam: list[list[np.ndarray]] = [[] for _ in range(pb.C)]
    for k in range(pb.K):
        mine = [b for b in blocks if b["k"] == k]
        every = np.concatenate([b["r"][b["ok"]] for b in mine]) if mine else np.zeros(0)
        if not len(every):
            continue
        mid = float(np.median(every))
        for b in mine:
            per_cam[b["i"]].append(np.abs(b["r"][b["ok"]] - mid))
    med = np.full(pb.C, np.nan)
    count = np.zeros(pb.C, np.int64)
    for i, rs in enumerate(per_cam):
        a = np.concatenate(rs) if rs else np.zeros(0)
        count[i] = len(a)
        if len(a):
            med[i] = float(np.median(a))
    return med, count


def _descend(pb: _Problem, x: np.ndarray, blocks: list[dict[str, Any]], c: float, phase: str, *, iterations: int,
             intrinsics: bool, it: int, costs: list[float], say: Callable[[str], None]
             ) -> tuple[np.ndarray, list[dict[str, Any]], int, bool]:
    """One phase of :func:`refine_rig`: Levenberg-Marquardt steps under the loss ``phase`` at
    the scale ``c`` until no step lowers the cost, the step or the cost's decrease is small,
    or ``iterations`` steps.

    Parameters
    ----------
    pb : _Problem
        The problem.
    x : array
        The parameters at the start of the phase.
    blocks : list of dict
        Their evaluation (:meth:`_Problem.evaluate`).
    c : float
        The loss's scale, px.
    phase : str
        ``"soft_l1"`` or ``"tukey"``.
    iterations : int
        Steps at most.
    intrinsics : bool
        The cameras' intrinsics are refined too (their steps count in the convergence test).
    it : int
        Steps taken before this phase (the progress lines count on).
    costs : list of float
        The cost at the start and after each step is appended to it.
    say : callable
        Receives the progress lines.

    Returns
    -------
    x, blocks
        The parameters at the end of the phase and their evaluation.
    it : int
        Steps taken, this phase's included.
    converged : bool
        Whether the phase ended converged (rather than out of iterations).
    """
    cost = _cost(blocks, c, phase) + 0.5 * float(x @ (pb.prior * x))
    costs.append(cost)
    lam = 1e-4
    converged = False
    for _ in range(iterations):
        H, g = _normal_equations(pb, blocks, c, phase)
        H, g = H + np.diag(pb.prior), g + pb.prior * x
        A, _keep = _constraints(pb, x)
        step_ok = False
        for _ in range(8):
            dx = _solve(H, g, A, -A @ x, lam)
            trial = x + dx
            new_blocks = pb.evaluate(trial, blocks)
            new_cost = _cost(new_blocks, c, phase) + 0.5 * float(trial @ (pb.prior * trial))
            if new_cost <= cost * (1.0 + 1e-9):
                step_ok = True
                break
            lam = min(lam * 10.0, 1e6)
        if not step_ok:  # no step lowers the cost: at its minimum
            converged = True
            break
        it += 1
        x, blocks = trial, new_blocks
        turn, shift = pb.cam_px(dx)
        step_px = float(max(np.linalg.norm(turn, axis=1).max(), np.linalg.norm(shift, axis=1).max()))
        if intrinsics:
            di = dx[: pb.C * pb.nc].reshape(pb.C, pb.nc)[:, 6:]
            step_px = max(step_px, float(np.abs(di).max()) * 0.1)  # a px of focal length moves the part's image ~0.04 px
        rel = (cost - new_cost) / max(cost, 1e-12)
        cost = new_cost
        costs.append(cost)
        lam = max(lam / 3.0, 1e-7)
        med, _ = _median_abs(pb, blocks)
        say(f"refine: iteration {it} ({phase.replace('_', '-')} at {c:.3f} px): median |residual| "
            f"{float(np.nanmedian(med)):.4f} px, worst camera {float(np.nanmax(med)):.4f} px, step {step_px:.4f} px")
        if step_px < CONVERGED_PX or rel < 1e-7:
            converged = True
            break
    return x, blocks, it, converged


def refine_rig(rig: Rig, parts: Sequence[PartView], index: Any, *, intrinsics: bool = False,
               robust_px: float = ROBUST_PX, iterations: int = ITERATIONS,
               progress: Progress | None = None) -> Refinement:
    """Refine ``rig`` jointly with the parts' placements so that their contour rays graze
    the reference (see the module docstring).

    Parameters
    ----------
    rig : Rig
    parts : sequence of PartView
        At least one capture; each part's contours in ``rig``'s camera order.
    index : MeshDistance
        The reference's distance index (its own frame): ``near``, ``closest``, ``pn``.
    intrinsics : bool
        Also refine each camera's ``fx, fy, cx, cy``.
    robust_px : float
        Scale of the soft-L1 loss, px.
    iterations : int
        Levenberg-Marquardt iterations at most.

    Returns
    -------
    Refinement
    """
    say = progress or (lambda _line: None)
    pb = _Problem(rig, parts, index, intrinsics)
    x = np.zeros(pb.n)
    blocks = pb.evaluate(x)
    # Each capture's offset starts at its median residual (mm).
    for k in range(pb.K):
        r = [b["r"][b["ok"]] * pb.depth[b["i"]] / pb.focal[b["i"]] for b in blocks if b["k"] == k]
        rr = np.concatenate(r) if r else np.zeros(0)
        x[pb.part(k)][6] = float(np.median(rr)) if len(rr) else 0.0
    blocks = pb.evaluate(x, blocks)
    before, _ = _median_abs(pb, blocks)
    costs: list[float] = []
    converged = False
    it = 0
    say(f"refine: {pb.C} cameras, {pb.K} captures, {sum(int(b['ok'].sum()) for b in blocks)} contour rays; "
        f"median |residual| {float(np.nanmedian(before)):.3f} px")
    # Two phases: soft-L1 at robust_px brings every camera in (a camera pixels off still
    # pulls); then Tukey at a few times the residuals' robust spread leaves out the rays the
    # model does not explain (silhouette corners, where the sub-pixel contour rounds the
    # corner: their residuals depend on the view, and would pull the weakly fixed balance of
    # each camera's turn and shift).
    for phase in ("soft_l1", "tukey"):
        if phase == "soft_l1":
            c = float(robust_px)
        else:
            every = np.concatenate([b["r"][b["ok"]] - np.median(b["r"][b["ok"]]) for b in blocks if b["ok"].any()])
            c = max(TUKEY_SIGMAS * 1.4826 * float(np.median(np.abs(every))), TUKEY_FLOOR_PX)
        x, blocks, it, converged = _descend(pb, x, blocks, c, phase, iterations=iterations, intrinsics=intrinsics,
                                           it=it, costs=costs, say=say)
    after, count = _median_abs(pb, pb.evaluate(x))  # every ray searched in full
    turn_px, _ = pb.cam_px(x)
    P = x[: pb.C * pb.nc].reshape(pb.C, pb.nc)
    _, keep = _constraints(pb, x)
    return Refinement(
        rig=Rig(tuple(pb.camera(x, i) for i in range(pb.C))),
        before_px=before, after_px=after,
        turn_px=np.linalg.norm(turn_px, axis=1), turn=P[:, :3].copy(), shift_mm=P[:, 3:6].copy(),
        intrinsics=P[:, 6:10].copy() if intrinsics else None,
        placements=tuple(pb.placement(x, k) for k in range(pb.K)),
        offset_mm=np.array([x[pb.part(k)][6] for k in range(pb.K)]),
        rays=count, iterations=it, converged=converged,
        gauge_cameras=tuple(c.name for c, k in zip(rig.cameras, keep) if k), cost=tuple(costs),
    )


# ------------------------------------------------------------------------------ the captures


@dataclass(frozen=True, eq=False)
class InspectedCapture:
    """One capture inspected with a given rig: what the refinement and the gauge need.

    ``view`` is None when the inspection ended in an error (``error`` says why).
    """

    name: str
    verdict: str
    error: str | None
    view: PartView | None
    size: Any = None  # the bcps stage's SizePrior
    bcps_mean_px: float | None = None  # mean |deviation| of the BCPS points, px
    bcps_signed_px: float | None = None
    points: np.ndarray | None = None  # BCPS points, world mm
    pose: np.ndarray | None = None  # the final (rigid) pose
    truth_px: float | None = None  # BCPS mean distance to the true surface, px (simulated captures)
    seconds: float = 0.0


def load_inputs(captures: str, reference: str, recipe: str | None, rig_path: str,
                what: str) -> tuple[Rig, list[Path], Recipe, Reference, PluginManager]:
    """The rig, the capture folders, the recipe, the reference and the plugin manager, each
    checked (RecipeError, one line)."""
    try:
        rig = read_rig(rig_path)
    except InspectorError as e:
        raise RecipeError(f"{what}: {e}") from None
    cap = Path(captures)
    if not cap.is_dir():
        raise RecipeError(f"--captures {captures}: no such folder")
    folders = [f for f in expand([str(cap)]) if is_capture_folder(f)]
    if not folders:
        raise RecipeError(f"--captures {captures}: no capture folder in it (each holds rig.json, images/)")
    pm = create_plugin_manager()
    rec = load_recipe(recipe or recipe_path("default.toml"), pm, reference=reference)
    try:
        ref = Reference.load(rec.reference) if rec.reference is not None else None
    except InspectorError as e:
        raise RecipeError(str(e)) from None
    if ref is None:
        raise RecipeError("no reference mesh (give one)")
    if not any(s.spec.kind == "bcps" for s in rec.steps):
        raise RecipeError(f"recipe {rec.name!r}: has no bcps stage (the refinement needs its pose and size model)")
    return rig, folders, rec, ref, pm


def _read_with_rig(folder: Path, rig: Rig) -> Any:
    """The capture in ``folder`` with ``rig`` in place of its own (same cameras and image sizes)."""
    try:
        cap = read_capture(folder)
    except InspectorError as e:
        raise RecipeError(f"capture {folder.name}: {e}") from None
    mine = {c.name: c for c in cap.rig.cameras}
    if set(mine) != set(rig.names):
        missing = sorted(set(rig.names) - set(mine)) or sorted(set(mine) - set(rig.names))
        raise RecipeError(f"capture {folder.name}: its cameras are not the rig's (camera {missing[0]})")
    for c in rig.cameras:
        img = cap.images[c.name]
        if (img.shape[1], img.shape[0]) != (c.width, c.height):
            raise RecipeError(f"capture {folder.name}: camera {c.name}'s image is {img.shape[1]}x{img.shape[0]}, "
                              f"the rig says {c.width}x{c.height}")
    return dataclasses.replace(cap, rig=rig)


def _placement(pose: np.ndarray, size: Any) -> tuple[np.ndarray, float]:
    """The sized reference's placement from the bcps stage's final (rigid) pose and size
    model (its rotation and shift are in the pose already: the scale about its centre)."""
    s = float(size.scale) if size is not None else 1.0
    c0 = np.asarray(size.centre, float) if size is not None else np.zeros(3)
    place = np.asarray(pose, float).copy()
    place[:3, 3] = place[:3, :3] @ (c0 - s * c0) + place[:3, 3]
    place[:3, :3] = place[:3, :3] * s
    return place, s


def part_view(ctx: Any, name: str, stride: int = STRIDE) -> PartView:
    """What the refinement needs of an inspected capture's context."""
    rig = ctx.capture.rig
    recon = ctx.reconstruction
    place, s = _placement(ctx.alignment.pose, ctx.bcps.size if ctx.bcps is not None else None)
    contours, ranges = [], []
    radius = max(1.0, 2.0 * float(recon.voxel_mm))
    for cam, sil in zip(rig.cameras, ctx.silhouettes):
        uv = np.asarray(sil.contour, float)[::stride]
        if not len(uv):
            contours.append(np.zeros((0, 2)))
            ranges.append((np.zeros(0), np.zeros(0)))
            continue
        origin, dirs = cam.rays(uv)
        t0, t1 = bk.ray_ranges(cam, uv, origin, dirs, recon.points, radius, compiled=True)
        keep = t0 <= t1
        contours.append(uv[keep])
        ranges.append((t0[keep], t1[keep]))
    return PartView(name, contours, ranges, place, s)


def inspect_with_rig(folders: Sequence[Path], rig: Rig, recipe: Recipe, ref: Reference, pm: PluginManager, *,
                     progress: Progress | None = None, label: str = "inspect") -> list[InspectedCapture]:
    """Inspect each capture folder with ``rig`` (in place of its own); one line each."""
    say = progress or (lambda _line: None)
    out = []
    for j, folder in enumerate(folders):
        cap = _read_with_rig(folder, rig)
        t = time.perf_counter()
        o = inspect_capture(cap, recipe, ref, pm)
        dt = time.perf_counter() - t
        res, ctx = o.result, o.context
        if res.verdict == "error" or ctx is None or ctx.bcps is None or ctx.alignment is None:
            say(f"{label}: [{j + 1}/{len(folders)}] {cap.name}: error: {res.error} (left out)")
            out.append(InspectedCapture(cap.name, "error", res.error, None, seconds=dt))
            continue
        fp = rig.footprint_mm()
        dev = np.asarray(ctx.bcps.deviation, float)
        truth = (res.stats.get("truth") or {}).get("bcps") or {}
        out.append(InspectedCapture(
            cap.name, res.verdict, res.error, part_view(ctx, cap.name), ctx.bcps.size,
            float(np.mean(np.abs(dev))) / fp if len(dev) else None,
            float(np.mean(dev)) / fp if len(dev) else None,
            np.asarray(ctx.bcps.points, float), np.asarray(ctx.alignment.pose, float),
            truth.get("mean_px"), dt))
        mean = out[-1].bcps_mean_px
        say(f"{label}: [{j + 1}/{len(folders)}] {cap.name}: {res.verdict}, BCPS mean |deviation| "
            f"{'-' if mean is None else f'{mean:.3f}'} px ({dt:.1f} s)")
        o = ctx = cap = None  # type: ignore[assignment]  # images freed before the next capture
    return out


# ---------------------------------------------------------------------------------- the folders


def _check_folder(folder: Path, rig: Rig) -> None:
    """The capture folder's cameras are the rig's (its rig.json names them), without reading images."""
    try:
        theirs = parse_rig(json.loads((folder / "rig.json").read_text(encoding="utf-8")), "rig.json")
    except (InspectorError, ValueError, OSError) as e:
        raise RecipeError(f"capture {folder.name}: {' '.join(str(e).split())}") from None
    if set(theirs.names) != set(rig.names):
        diff = sorted(set(rig.names) ^ set(theirs.names))
        raise RecipeError(f"capture {folder.name}: its cameras are not the rig's (camera {diff[0]})")
