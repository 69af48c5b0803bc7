"""``inspector calibrate TARGET.toml --captures DIR --out RIG.json``: every camera from a target.

Stages (progress lines on stderr, each stage's seconds of wall time on its last line; the
last line, ``calibrate: done in T s (C s of CPU): detection ..., machine load L``, is the
command's own benchmark, also in ``report.json`` ``timings_s``):

1. **Cameras.** ``DIR`` holds one capture folder per pose of the target (or is one); each
   ``images/<camera>.png`` names a camera, its size read from the PNG header. A ``rig.json``
   in a capture folder is not needed and its cameras are never used as the starting point
   (a cell being commissioned has no rig yet): only as a fallback first guess of a camera's
   intrinsics when its own initialisation fails, and the report then says so.
2. **Detection** (threads, OpenCV releases the GIL). Markers are found once per image with a
   dictionary of the target's own markers only (the first ``boards x markers`` of the
   predefined dictionary: the same ids, ten times faster than the 1000-marker dictionary),
   split by board (``id // markers_per_board``), and each board's ChArUco corners are
   interpolated and refined by ``cv2.aruco.CharucoDetector(target.board(b))``. A board seen
   with fewer than :data:`~inspector.calibration.detect.MIN_CORNERS` corners is dropped. Each board's markers must fit
   one homography: boards that do not (a description whose squares or marker size do not
   match the print) make the command refuse the target, as do markers of another
   dictionary (looked for only when nothing is found).
3. **Initialisation.** Each camera's intrinsics by ``cv2.calibrateCamera`` over its boards
   (each board of a view a planar view, at most 60, k2 = k3 = 0, no tangential terms), then each view's
   target pose (body -> camera) by ``solvePnP`` over all its corners. Cameras and target
   poses form a graph whose edges are the views; a maximum spanning tree (weights: corners)
   from the pose seen by most cameras chains the cameras' extrinsics through the poses they
   share. A camera the tree does not reach shares no pose with the others: refused.
4. **Bundle adjustment** (:func:`inspector.kernels.calibration.bundle_adjust`): all cameras'
   fx, fy, cx, cy, k1, k2, p1, p2 (k3 = 0, :data:`FREE_INTRINSICS`) and extrinsics and all
   target poses but the one seen by most cameras (the gauge; the metric scale is the
   target's), soft-L1 loss at 0.3 px. Steep boards' refined corners are biased: boards seen
   more than :data:`MAX_ANGLE_DEG` from face-on (at the initial pose) are rejected outright,
   those beyond :data:`WEIGHT_ANGLE_DEG` weigh less; then boards whose residual RMS exceeds
   3 x the median of all boards are rejected and the adjustment is run again, twice at most.
   The report names every rejected board and why.
5. **Uncertainty.** ``(J^T J)^-1 sigma^2`` at the solution, each camera's centre (mm) and
   orientation (degrees) in the datum of the cameras themselves
   (:func:`~inspector.kernels.calibration.camera_uncertainty`).
6. **Output frame.** The world origin is the point nearest all cameras' optical axes (least
   squares); the world axes are those of the target's body at its first pose used (the first
   capture folder, in name order, whose target some camera saw). ``RIG.json``: ``units``,
   ``cameras`` (CONTRACT) and ``calibration`` (date, target, poses, RMS, rejected boards, per
   camera figures), written whole (:func:`~inspector.calibration.command.write_rig`).
7. **Report** (:mod:`.report`): text on stdout (or JSON with ``--json``), ``report.json`` and
   pictures in ``--report`` (default ``<out stem>_report/`` beside the rig).

Stages 1 and 2 are :mod:`.detect`'s, stage 3 :mod:`.initial`'s; stage 7's text :mod:`.report`'s.

Every bad input is one line, exit 2 (:class:`~inspector.errors.RecipeError`), before anything
is written: no target in the images, a camera that never sees it, a description that does not
match the images, a target TOML with a wrong key, no ``--out``, no capture folder.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import json
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from inspector.calibration import report as rep
from inspector.calibration.command import check_new_file, write_rig
from inspector.calibration.detect import (
    BoardView,
    _diagnose_nothing,
    capture_folders,
    detect,
    find_cameras,
)
from inspector.calibration.initial import _initial_intrinsics, _initial_poses
from inspector.calibration.target import Target, load_target
from inspector.errors import RecipeError
from inspector.kernels import calibration as kc
from inspector.model import Camera, Rig

__all__ = ["run_calibrate", "calibrate", "Calibration", "FREE_INTRINSICS"]

#: Intrinsics the bundle adjustment adjusts for every camera (the others stay at 0) ...
FREE_INTRINSICS = ("fx", "fy", "cx", "cy", "k1", "p1", "p2")
#: ... and k2 (k3) too for a camera whose image corners lie farther than this from its axis
#: (normalised radius: half the image diagonal / f). Below, r^4 (r^6) is too small for k2 (k3)
#: to be observed: on the sphere rig (f = 4000 px on 1024^2, r = 0.18) k2 came out anywhere in
#: -9..+7 (true 0) and fixing it at 0 changed neither the working volume's reprojection
#: (0.022 px worst camera either way) nor the focal lengths (worst 0.137 % free, 0.133 % fixed).
K2_RADIUS, K3_RADIUS = 0.35, 0.7
#: Loss and scale (px) of the bundle adjustment.
LOSS, F_SCALE = "soft_l1", 0.3
#: A board whose residual RMS exceeds this many times the median is rejected; rounds of it.
REJECT_FACTOR, REJECT_ROUNDS = 3.0, 2
#: Boards seen more obliquely than this (degrees between their normal and the line of sight, at
#: the initial pose) are rejected: their refined corners are biased (measured on rendered cubes:
#: residual RMS 0.06 px face-on, 0.14 px at 65-70 degrees, 0.4-0.8 px beyond 70).
MAX_ANGLE_DEG = 70.0
#: Boards seen more obliquely than this weigh (cos(angle) / cos(this))^2 in the adjustment.
WEIGHT_ANGLE_DEG = 45.0
#: A board's markers fitting one homography worse than this (RMS, in marker sides) do not match the
#: description: markers of another board, a description with other squares (the median board of a
#: matching target: 0.05 on 20 px markers, their corners unrefined and the lens distorting). Markers
#: printed smaller or larger than described (4 mm described as 5: 0.11) pass: the corners are
#: the chessboard's, whatever the markers' size.
MISMATCH = 0.25

# --------------------------------------------------------------------------- small helpers


def _progress(msg: str) -> None:
    print(f"calibrate: {msg}", file=sys.stderr, flush=True)


@contextlib.contextmanager
def _one_blas_thread() -> Iterator[None]:
    """Run the block with the loaded OpenBLAS libraries on one thread each (as threadpoolctl
    would): scipy's LSMR makes thousands of small BLAS calls whose threads spin against each
    other and the rest of the machine (a bundle adjustment took 36 s instead of 8 s on a busy
    2-core machine). A no-op where the libraries or their functions cannot be found."""
    handles: list[tuple[Any, Any]] = []
    try:
        paths = set()
        with open("/proc/self/maps", encoding="utf-8") as f:
            for line in f:
                parts = line.split()
                p = parts[-1] if len(parts) >= 6 else ""
                if "openblas" in os.path.basename(p).lower() and ".so" in os.path.basename(p):
                    paths.add(p)
        for p in sorted(paths):
            lib = ctypes.CDLL(p)
            for prefix in ("scipy_openblas", "openblas"):
                for suffix in ("64_", ""):
                    set_fn = getattr(lib, f"{prefix}_set_num_threads{suffix}", None)
                    get_fn = getattr(lib, f"{prefix}_get_num_threads{suffix}", None)
                    if set_fn is not None and get_fn is not None:
                        get_fn.restype = ctypes.c_int
                        handles.append((set_fn, int(get_fn())))
                        set_fn(ctypes.c_int(1))
                        break
                else:
                    continue
                break
    except (OSError, ValueError, AttributeError):
        pass
    try:
        yield
    finally:
        for set_fn, n in handles:
            with contextlib.suppress(Exception):
                set_fn(ctypes.c_int(n))


# --------------------------------------------------------------------------- the calibration


@dataclass
class Calibration:
    """Everything the command found (what the report and the rig are made of)."""

    names: list[str]
    sizes: list[tuple[int, int]]
    captures: list[str]
    K: np.ndarray  # (C, 3, 3)
    dist: np.ndarray  # (C, 5)
    R: np.ndarray  # (C, 3, 3) world -> camera, output frame
    t: np.ndarray  # (C, 3) mm
    poses: dict[int, np.ndarray]  # capture -> (4, 4) body -> world, output frame
    views: list[BoardView]  # every board detected
    kept: np.ndarray  # (len(views),) bool: used by the final adjustment
    residuals: list[np.ndarray]  # per view (k, 2) px at the solution (projected - observed)
    rejected: list[dict[str, Any]]
    reject_threshold_px: float
    rms_px: float
    iterations: int
    sigma_px: float
    centre_std_mm: np.ndarray  # (C,)
    angle_std_deg: np.ndarray  # (C,)
    intrinsic_std: np.ndarray  # (C, 9) (0 where fixed)
    notes: list[str]
    timings: dict[str, float]
    target: Target
    max_angle_deg: float = MAX_ANGLE_DEG


def _free_mask(n_cams: int, n_poses: int, fixed_poses: Sequence[int], free_intrinsics: Sequence[Sequence[str]]
               ) -> np.ndarray:
    free = np.ones(n_cams * kc.N_CAM + n_poses * kc.N_POSE, bool)
    for c in range(n_cams):
        for k, name in enumerate(kc.INTRINSICS):
            if name not in free_intrinsics[c]:
                free[c * kc.N_CAM + k] = False
    for p in fixed_poses:
        o = n_cams * kc.N_CAM + p * kc.N_POSE
        free[o:o + kc.N_POSE] = False
    return free


def calibrate(target: Target, folders: Sequence[Path], *, free_intrinsics: Sequence[str] | None = None,
              progress: Callable[[str], None] = _progress, root: Path | None = None,
              max_angle_deg: float = MAX_ANGLE_DEG, weight_angle_deg: float | None = WEIGHT_ANGLE_DEG,
              reject_factor: float = REJECT_FACTOR, reject_rounds: int = REJECT_ROUNDS) -> Calibration:
    """Calibrate every camera of the capture folders ``folders`` (one per target pose).

    ``free_intrinsics`` (default: :data:`FREE_INTRINSICS`, and k2, k3 by :data:`K2_RADIUS`,
    :data:`K3_RADIUS`), ``max_angle_deg``, ``weight_angle_deg`` (None: every board weighs 1),
    ``reject_factor`` and ``reject_rounds``: see the module's constants."""
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    root = root if root is not None else (folders[0].parent if folders else Path("."))
    names, sizes, views, markers = _detect_boards(target, folders, root, progress, timings, t0)

    # --- intrinsics per camera, target pose in each view
    t1 = time.perf_counter()
    Ks, dists, notes = _initial_intrinsics(target, folders, names, sizes, views, markers, progress)
    obj_all, view_T, cam_T, pose_T, anchor = _initial_poses(target, names, len(folders), views, Ks, dists, root)
    timings["initialise_s"] = time.perf_counter() - t1
    progress(f"initialised {len(names)} cameras and {len(pose_T)} target poses ({timings['initialise_s']:.1f} s)")

    # --- the bundle adjustment
    t2 = time.perf_counter()
    b = _observations(names, sizes, views, view_T, cam_T, pose_T, Ks, dists, free_intrinsics, max_angle_deg,
                      weight_angle_deg, progress)
    prob, res = _adjust(obj_all, names, views, anchor, b, reject_factor, reject_rounds, progress)
    timings["adjust_s"] = time.perf_counter() - t2

    # --- uncertainty
    t3 = time.perf_counter()
    cb, sigma, cen_std, ang_std, intr_std = _uncertainty(prob, b.params, len(names))
    timings["covariance_s"] = time.perf_counter() - t3
    progress(f"uncertainty of every camera's position and orientation ({timings['covariance_s']:.1f} s)")

    K_out, R_out, t_out, poses_out = _output_frame(prob, b, cb, len(names))
    residuals, kept_views, rejected = _view_residuals(obj_all, names, folders, views, prob, b)
    timings["total_s"] = time.perf_counter() - t0
    return Calibration(
        names=names, sizes=sizes, captures=[f.name for f in folders], K=K_out, dist=cb[:, 4:9].copy(), R=R_out, t=t_out,
        poses=poses_out, views=views, kept=kept_views, residuals=residuals, rejected=rejected,
        reject_threshold_px=b.thr, rms_px=res.rms_px, iterations=b.iterations, sigma_px=sigma, centre_std_mm=cen_std,
        angle_std_deg=ang_std, intrinsic_std=intr_std, notes=notes, timings=timings, target=target,
        max_angle_deg=max_angle_deg)


def _detect_boards(target: Target, folders: Sequence[Path], root: Path, progress: Callable[[str], None],
                   timings: dict[str, float], t0: float
                   ) -> tuple[list[str], list[tuple[int, int]], list[BoardView], dict[tuple[int, int], int]]:
    """Stages 1 and 2 of :func:`calibrate`: the cameras and the boards they see.

    Parameters
    ----------
    target : Target
        The calibration target.
    folders : sequence of Path
        The capture folders, one per target pose.
    root : Path
        Their parent, named in the error when no board is found.
    progress : callable
        Receives the progress lines.
    timings : dict
        ``detect_s`` is set in it (seconds since ``t0``).
    t0 : float
        :func:`time.perf_counter` at the start of the calibration.

    Returns
    -------
    names : list of str
        The cameras.
    sizes : list of (int, int)
        Each camera's ``(width, height)``.
    views : list of BoardView
        The boards seen whose markers fit one homography.
    markers : dict
        Markers found per ``(capture, camera)``.

    Raises
    ------
    RecipeError
        No board found, or the description does not match the images.
    """
    names, sizes_by, images = find_cameras(folders)
    sizes = [sizes_by[n] for n in names]
    jobs = [(i, j, images[(i, n)], sizes_by[n], f"{folders[i].name}/images/{n}.png")
            for i in range(len(folders)) for j, n in enumerate(names) if (i, n) in images]
    n_caps = len(folders)
    done = [0] * n_caps
    per_cap = [sum(1 for (i, _) in images if i == k) for k in range(n_caps)]
    finished = [0]
    step = max(1, n_caps // 10)
    progress(f"detecting the target in {len(jobs)} images of {n_caps} capture{'s' * (n_caps != 1)} "
             f"({len(names)} cameras, {min(len(jobs), os.cpu_count() or 1)} threads)")

    def on_done(i: int) -> None:
        done[i] += 1
        if done[i] == per_cap[i]:
            finished[0] += 1
            if finished[0] % step == 0 or finished[0] == n_caps:
                progress(f"detecting {finished[0]}/{n_caps} captures")

    views, markers = detect(target, jobs, on_done)
    timings["detect_s"] = time.perf_counter() - t0
    if not views:
        raise _diagnose_nothing(target, jobs, root)
    h = np.array([v.homography_px for v in views])
    if np.median(h) > MISMATCH:
        raise RecipeError(f"the target description does not match the images: the markers of a board do not lie where "
                          f"{target.source} puts them (off by {100 * np.median(h):.0f} % of a marker's side): check its "
                          "squares, square_mm and marker_mm")
    good = h <= MISMATCH
    views = [v for v, g in zip(views, good) if g]
    n_corners = sum(len(v.ids) for v in views)
    progress(f"found {len(views)} boards, {n_corners} corners (detection {timings['detect_s']:.1f} s)")
    return names, sizes, views, markers


@dataclass
class _Bundle:
    """The bundle adjustment's observations and its state (:func:`_observations`, :func:`_adjust`)."""

    pose_list: list[int]  # the target poses adjusted, capture order
    pose_index: dict[int, int]  # capture -> its row in pose_list
    use: list[int]  # the views (indices into views) observed
    steep: list[int]  # the views rejected as seen too obliquely
    cam_idx: np.ndarray  # per corner: its camera, target pose, corner id, pixel and view
    pose_idx: np.ndarray
    pt_idx: np.ndarray
    uv: np.ndarray
    group: np.ndarray
    weight: np.ndarray  # per corner: its board's weight (obliquity)
    params: np.ndarray  # the packed parameters: first guess, then the solution
    keep: np.ndarray  # per corner: still in the adjustment
    per_cam: list[tuple[str, ...]]  # each camera's free intrinsics
    rejected_groups: list[int] = field(default_factory=list)  # views rejected for their residual
    thr: float = 0.0  # the residual threshold of the rejection, px
    iterations: int = 0  # Jacobian evaluations of all rounds


def _observations(names: list[str], sizes: list[tuple[int, int]], views: list[BoardView],
                  view_T: dict[tuple[int, int], np.ndarray], cam_T: dict[int, np.ndarray], pose_T: dict[int, np.ndarray],
                  Ks: np.ndarray, dists: np.ndarray, free_intrinsics: Sequence[str] | None, max_angle_deg: float,
                  weight_angle_deg: float | None, progress: Callable[[str], None]) -> _Bundle:
    """The corners the bundle adjustment fits, their weights, the first guess of the parameters
    and each camera's free intrinsics (stage 4 of :func:`calibrate`); steep boards rejected.

    Parameters
    ----------
    names, sizes : list
        The cameras and their ``(width, height)``.
    views : list of BoardView
        The boards seen (``angle_deg`` set).
    view_T, cam_T, pose_T : dict
        The first guess (:func:`_initial_poses`).
    Ks, dists : array
        The cameras' first intrinsics.
    free_intrinsics : sequence of str or None
        As :func:`calibrate`'s.
    max_angle_deg, weight_angle_deg : float
        As :func:`calibrate`'s.
    progress : callable
        Receives the progress lines.

    Returns
    -------
    _Bundle
        Before the first round.
    """
    pose_list = sorted(pose_T)
    pose_index = {p: k for k, p in enumerate(pose_list)}
    use = [k for k, v in enumerate(views) if v.capture in pose_index and (v.camera, v.capture) in view_T]
    steep = [k for k in use if views[k].angle_deg > max_angle_deg]
    # keep at least one board per camera whatever its angle
    for j in range(len(names)):
        mine = [k for k in use if views[k].camera == j]
        if mine and all(k in steep for k in mine):
            steep.remove(min(mine, key=lambda k: views[k].angle_deg))
    if steep:
        progress(f"rejected {len(steep)} board{'s' * (len(steep) != 1)} seen at more than {max_angle_deg:g} degrees "
                 "from face-on")
    cam_idx = np.concatenate([np.full(len(views[k].ids), views[k].camera) for k in use])
    pose_idx = np.concatenate([np.full(len(views[k].ids), pose_index[views[k].capture]) for k in use])
    pt_idx = np.concatenate([views[k].ids for k in use])
    uv = np.concatenate([views[k].uv for k in use])
    group = np.concatenate([np.full(len(views[k].ids), k) for k in use])
    weight = np.ones(len(group))
    if weight_angle_deg is not None:
        c0 = np.cos(np.radians(weight_angle_deg))
        wk = {k: min(1.0, (np.cos(np.radians(views[k].angle_deg)) / c0) ** 2) for k in use}
        weight = np.array([wk[int(g)] for g in group])
    intr = np.zeros((len(names), 9))
    intr[:, 0], intr[:, 1], intr[:, 2], intr[:, 3] = Ks[:, 0, 0], Ks[:, 1, 1], Ks[:, 0, 2], Ks[:, 1, 2]
    intr[:, 4:9] = dists
    cr = np.array([kc.rotvec(cam_T[j][:3, :3]) for j in range(len(names))])
    ct = np.array([cam_T[j][:3, 3] for j in range(len(names))])
    pr = np.array([kc.rotvec(pose_T[p][:3, :3]) for p in pose_list])
    pt = np.array([pose_T[p][:3, 3] for p in pose_list])
    params = kc.BundleProblem.pack(intr, cr, ct, pr, pt)
    keep = ~np.isin(group, steep)
    if free_intrinsics is None:
        per_cam: list[tuple[str, ...]] = []
        for j in range(len(names)):
            w, hh = sizes[j]
            radius = 0.5 * float(np.hypot(w, hh)) / float(min(Ks[j, 0, 0], Ks[j, 1, 1]))
            per_cam.append(FREE_INTRINSICS + ("k2",) * (radius > K2_RADIUS) + ("k3",) * (radius > K3_RADIUS))
    else:
        per_cam = [tuple(free_intrinsics)] * len(names)
    return _Bundle(pose_list, pose_index, use, steep, cam_idx, pose_idx, pt_idx, uv, group, weight, params, keep,
                   per_cam)


def _adjust(obj_all: np.ndarray, names: list[str], views: list[BoardView], anchor: int, b: _Bundle,
            reject_factor: float, reject_rounds: int, progress: Callable[[str], None]
            ) -> tuple[kc.BundleProblem, kc.BundleResult]:
    """The bundle adjustment's rounds (stage 4 of :func:`calibrate`): adjust, reject the boards
    whose residual RMS exceeds ``reject_factor`` x the median, adjust again.

    Parameters
    ----------
    obj_all : (P, 3) array
        The target's corners, body frame.
    names : list of str
        The cameras.
    views : list of BoardView
        The boards seen.
    anchor : int
        The target pose that stays fixed (the gauge).
    b : _Bundle
        The observations (:func:`_observations`); its ``params``, ``keep``,
        ``rejected_groups``, ``thr`` and ``iterations`` are updated.
    reject_factor : float
        As :func:`calibrate`'s.
    reject_rounds : int
        As :func:`calibrate`'s.
    progress : callable
        Receives the progress lines.

    Returns
    -------
    prob : kc.BundleProblem
        The last round's problem.
    res : kc.BundleResult
        Its solution.
    """
    pose_list, pose_index, keep = b.pose_list, b.pose_index, b.keep
    params = b.params
    rejected_groups: list[int] = []
    thr = 0.0
    iterations = 0
    res: kc.BundleResult | None = None
    prob: kc.BundleProblem | None = None
    with _one_blas_thread():
        for rnd in range(reject_rounds + 1):
            t_round = time.perf_counter()
            used_poses = set(b.pose_idx[keep].tolist())
            fixed = [pose_index[anchor]] + [q for q in range(len(pose_list)) if q not in used_poses]
            free = _free_mask(len(names), len(pose_list), fixed, b.per_cam)
            prob = kc.BundleProblem(obj_all, b.cam_idx[keep], b.pose_idx[keep], b.pt_idx[keep], b.uv[keep], len(names),
                                    len(pose_list), params, free, b.weight[keep])
            res = kc.bundle_adjust(prob, loss=LOSS, f_scale=F_SCALE)
            iterations += res.njev
            params = res.params
            progress(f"adjusting: {len(names)} cameras, {len(used_poses)} poses, {int(keep.sum())} corners: "
                     f"{res.njev} iterations, RMS {res.rms_px:.3f} px ({time.perf_counter() - t_round:.1f} s)")
            if rnd == reject_rounds:
                break
            bad_ids, thr_r = kc.reject_groups(res.residuals, b.group[keep], reject_factor)
            # never leave a camera without boards
            bad = [int(g) for g in bad_ids]
            for g in list(bad):
                c = views[g].camera
                others = set(b.group[keep & (b.cam_idx == c)].tolist()) - set(bad)
                if not others:
                    bad.remove(g)
            if not bad:
                thr = thr if rejected_groups else thr_r
                break
            thr = thr_r
            rejected_groups += bad
            keep &= ~np.isin(b.group, bad)
            progress(f"rejected {len(bad)} board{'s' * (len(bad) != 1)} whose residual RMS exceeds {thr_r:.3f} px "
                     f"({reject_factor:g} x the median)")
    assert res is not None and prob is not None
    b.params, b.rejected_groups, b.thr, b.iterations = params, rejected_groups, thr, iterations
    return prob, res


def _uncertainty(prob: kc.BundleProblem, params: np.ndarray, n_cams: int
                 ) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]:
    """The uncertainty at the solution (stage 5 of :func:`calibrate`).

    Parameters
    ----------
    prob : kc.BundleProblem
        The last round's problem.
    params : array
        Its solution (packed).
    n_cams : int
        The number of cameras.

    Returns
    -------
    cb : (C, 15) array
        The cameras' block of the solution.
    sigma : float
        The residuals' standard deviation (weighted).
    cen_std : (C,) array
        Each camera's centre standard deviation, mm.
    ang_std : (C,) array
        Each camera's orientation standard deviation, degrees.
    intr_std : (C, 9) array
        The intrinsics' standard deviations (0 for a fixed one).
    """
    J = prob.jacobian(params[prob.free])
    cov, sigma = kc.normal_covariance(J, prob.residuals(params[prob.free]))  # weighted, as J
    col = np.cumsum(prob.free) - 1
    ext_idx = [int(col[j * kc.N_CAM + 9 + k]) for j in range(n_cams) for k in range(6)]
    ext_free = all(prob.free[j * kc.N_CAM + 9 + k] for j in range(n_cams) for k in range(6))
    cb = prob.cam_block(params)
    if ext_free:
        cen_std, ang_std, _ = kc.camera_uncertainty(cb[:, 9:12], cb[:, 12:15], cov[np.ix_(ext_idx, ext_idx)])
    else:  # pragma: no cover - every camera's extrinsics are free
        cen_std = ang_std = np.full(n_cams, np.nan)
    intr_std = np.zeros((n_cams, 9))
    for j in range(n_cams):
        for k in range(9):
            i = j * kc.N_CAM + k
            if prob.free[i]:
                intr_std[j, k] = float(np.sqrt(max(cov[col[i], col[i]], 0.0)))
    return cb, sigma, cen_std, ang_std, intr_std


def _output_frame(prob: kc.BundleProblem, b: _Bundle, cb: np.ndarray, n_cams: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[int, np.ndarray]]:
    """The solution in the output frame (stage 6 of :func:`calibrate`): origin nearest the
    optical axes, axes of the body at the first pose.

    Parameters
    ----------
    prob : kc.BundleProblem
        The last round's problem.
    b : _Bundle
        The adjustment (its ``params``, ``pose_list``, ``pose_index``).
    cb : (C, 15) array
        The cameras' block of the solution.
    n_cams : int
        The number of cameras.

    Returns
    -------
    K_out : (C, 3, 3) array
        Camera matrices.
    R_out, t_out : arrays
        World -> camera of each camera.
    poses_out : dict
        Body -> world of each target pose, by capture.
    """
    pose_list, pose_index = b.pose_list, b.pose_index
    Rc = kc.rodrigues(cb[:, 9:12])
    tc = cb[:, 12:15]
    pb = prob.pose_block(b.params)
    first = min(p for p in pose_list if pose_index[p] in set(prob.pose.tolist()))
    Rp0 = kc.rodrigues(pb[pose_index[first], :3])
    centres = -np.einsum("nji,nj->ni", Rc, tc)
    origin = kc.nearest_point_to_lines(centres, Rc[:, 2, :])
    R_out = Rc @ Rp0  # world' -> camera: X_w = Rp0 X' + origin
    t_out = np.einsum("nij,j->ni", Rc, origin) + tc
    poses_out: dict[int, np.ndarray] = {}
    for p in pose_list:
        q = pose_index[p]
        T = np.eye(4)
        T[:3, :3] = Rp0.T @ kc.rodrigues(pb[q, :3])
        T[:3, 3] = Rp0.T @ (pb[q, 3:] - origin)
        poses_out[p] = T
    K_out = np.zeros((n_cams, 3, 3))
    K_out[:, 0, 0], K_out[:, 1, 1], K_out[:, 0, 2], K_out[:, 1, 2], K_out[:, 2, 2] = cb[:, 0], cb[:, 1], cb[:, 2], cb[:, 3], 1.0
    return K_out, R_out, t_out, poses_out


def _view_residuals(obj_all: np.ndarray, names: list[str], folders: Sequence[Path], views: list[BoardView],
                    prob: kc.BundleProblem, b: _Bundle) -> tuple[list[np.ndarray], np.ndarray, list[dict[str, Any]]]:
    """The residuals of every view at the solution, rejected ones too.

    Parameters
    ----------
    obj_all : (P, 3) array
        The target's corners, body frame.
    names : list of str
        The cameras.
    folders : sequence of Path
        The capture folders.
    views : list of BoardView
        The boards seen.
    prob : kc.BundleProblem
        The last round's problem (its free parameters).
    b : _Bundle
        The adjustment.

    Returns
    -------
    residuals : list of (k, 2) arrays
        Each view's residuals, px (empty for a view not observed).
    kept : (V,) bool array
        The views the solution rests on.
    rejected : list of dict
        The rejected boards, for the report.
    """
    steep_set = set(b.steep)
    full = kc.BundleProblem(obj_all, b.cam_idx, b.pose_idx, b.pt_idx, b.uv, len(names), len(b.pose_list), b.params,
                            prob.free)
    r_all = full.project(b.params) - b.uv
    residuals: list[np.ndarray] = [np.zeros((0, 2)) for _ in views]
    kept_views = np.zeros(len(views), bool)
    for k in b.use:
        residuals[k] = r_all[b.group == k]
        kept_views[k] = True
    for g in list(steep_set) + b.rejected_groups:
        kept_views[g] = False
    rejected = []
    for g in sorted(steep_set) + b.rejected_groups:
        v = views[g]
        r = residuals[g]
        rejected.append({"camera": names[v.camera], "capture": folders[v.capture].name, "board": int(v.board),
                         "corners": int(len(v.ids)), "rms_px": round(float(np.sqrt(np.mean(np.sum(r * r, axis=1)))), 4),
                         "angle_deg": round(v.angle_deg, 1),
                         "reason": "steep" if g in steep_set else "residual"})
    return residuals, kept_views, rejected


# --------------------------------------------------------------------------- the command


def run_calibrate(args: argparse.Namespace) -> int:
    """``inspector calibrate TARGET.toml --captures DIR --out RIG.json [--force] [--report DIR] [--json]``."""
    t0, cpu0 = time.perf_counter(), time.process_time()
    target = load_target(args.target)
    if not getattr(args, "out", None):
        raise RecipeError("calibrate: --out RIG.json is required (the rig file to write)")
    out = check_new_file(args.out, getattr(args, "force", False), "rig")
    report_dir = Path(args.report) if getattr(args, "report", None) else out.with_name(f"{out.stem}_report")
    if report_dir.exists() and not report_dir.is_dir():
        raise RecipeError(f"--report {report_dir}: is a file, not a folder")
    if not report_dir.parent.is_dir():
        raise RecipeError(f"--report {report_dir}: no such folder {report_dir.parent}")
    root = Path(args.captures)
    folders = capture_folders(root)
    cal = calibrate(target, folders, root=root)

    progress = _progress
    t_w = time.perf_counter()
    progress(f"writing {out}")
    cameras = tuple(Camera(n, w, h, cal.K[j], cal.dist[j], cal.R[j], cal.t[j])
                    for j, (n, (w, h)) in enumerate(zip(cal.names, cal.sizes)))
    summary = rep.summarise(cal)
    extra = {"calibration": {
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "target": {**target.to_json(), "file": Path(args.target).name},
        "captures": str(root),
        "poses": len(cal.poses),
        "rms_px": round(cal.rms_px, 4),
        "frame": "origin: the point nearest all optical axes; axes: the target's body at its first pose "
                 f"({cal.captures[min(cal.poses)]})",
        "rejected_boards": cal.rejected,
        "cameras": {c["name"]: {k: c[k] for k in ("rms_px", "max_px", "corners", "views", "coverage_pct", "centre_std_mm",
                                                   "angle_std_deg")} for c in summary["cameras"]},
    }}
    write_rig(Rig(cameras), out, extra)
    report_dir.mkdir(exist_ok=True)
    summary["rig"] = str(out)
    summary["report_dir"] = str(report_dir)
    pictures = rep.write_pictures(cal, summary, report_dir)
    summary["pictures"] = [p.name for p in pictures]
    cal.timings["write_s"] = time.perf_counter() - t_w
    cal.timings["command_s"] = time.perf_counter() - t0
    cal.timings["cpu_s"] = time.process_time() - cpu0
    progress(f"wrote {out} and {len(pictures)} pictures in {report_dir} ({cal.timings['write_s']:.1f} s)")
    progress(rep.timing_line(cal.timings))
    summary["timings_s"] = {k: round(v, 3) for k, v in cal.timings.items()}
    summary["load_1min"] = round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None
    (report_dir / "report.json").write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    if getattr(args, "json", False):
        print(json.dumps(summary, indent=1))
    else:
        print(rep.text(summary))
    return 0
