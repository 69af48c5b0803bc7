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
   with fewer than :data:`MIN_CORNERS` corners is dropped. Each board's markers must fit
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

Every bad input is one line, exit 2 (:class:`~inspector.errors.RecipeError`), before anything
is written: no target in the images, a camera that never sees it, a description that does not
match the images, a target TOML with a wrong key, no ``--out``, no capture folder.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import heapq
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import datetime, UTC
from pathlib import Path
from typing import Any

import numpy as np

from inspector.calibration.target import Target, load_target
from inspector.errors import CaptureError, RecipeError
from inspector.kernels import calibration as kc

__all__ = ["run_calibrate", "calibrate", "find_cameras", "capture_folders", "detect", "Calibration",
           "BoardView", "MIN_CORNERS", "FREE_INTRINSICS", "timing_line", "STAGES"]

#: A board is kept in a view only with this many corners.
MIN_CORNERS = 6
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
#: Dictionaries looked for when the target's finds nothing (the largest of each family: the
#: smaller ones are their first ids).
_OTHER_DICTIONARIES = ("DICT_4X4_1000", "DICT_5X5_1000", "DICT_6X6_1000", "DICT_7X7_1000", "DICT_ARUCO_ORIGINAL",
                       "DICT_APRILTAG_36h11", "DICT_ARUCO_MIP_36h12")


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


def _natural_key(name: str) -> tuple[Any, ...]:
    import re

    return tuple(int(s) if s.isdigit() else s for s in re.split(r"(\d+)", name))


# --------------------------------------------------------------------------- inputs


def capture_folders(root: Path) -> list[Path]:
    """The capture folders of ``root`` (its sub-folders holding ``images/``, in name order),
    or ``[root]`` when it is one itself."""
    if not root.exists():
        raise RecipeError(f"--captures {root}: no such folder")
    if not root.is_dir():
        raise RecipeError(f"--captures {root}: not a folder")
    if (root / "images").is_dir():
        return [root]
    try:
        subs = [p for p in root.iterdir() if not p.name.startswith(".") and p.is_dir() and (p / "images").is_dir()]
    except OSError as e:
        raise RecipeError(f"--captures {root}: cannot be listed ({e.strerror or e})") from None
    if not subs:
        raise RecipeError(f"--captures {root}: no capture folder in it (one folder per target pose, each with "
                          "images/<camera>.png)")
    return sorted(subs, key=lambda p: _natural_key(p.name))


def find_cameras(folders: Sequence[Path]) -> tuple[list[str], dict[str, tuple[int, int]], dict[tuple[int, str], Path]]:
    """Camera names (in a ``rig.json``'s order when one lists them all, else name order), each
    camera's ``(width, height)`` from its PNG headers, and ``{(capture, camera): image}``."""
    from inspector.capture_folder import png_header

    sizes: dict[str, tuple[int, int]] = {}
    where: dict[str, str] = {}
    images: dict[tuple[int, str], Path] = {}
    for i, folder in enumerate(folders):
        for p in sorted((folder / "images").iterdir()):
            if p.name.startswith(".") or p.suffix.lower() != ".png" or not p.is_file():
                continue
            label = f"{folder.name}/images/{p.name}"
            try:
                with open(p, "rb") as f:
                    w, h, _, _ = png_header(f.read(33), label, RecipeError)
            except OSError as e:
                raise RecipeError(f"{label}: cannot be read ({e.strerror or e})") from None
            name = p.stem
            if name in sizes and sizes[name] != (w, h):
                raise RecipeError(f"{label}: {w}x{h}, but camera {name} is {sizes[name][0]}x{sizes[name][1]} in {where[name]}")
            sizes.setdefault(name, (w, h))
            where.setdefault(name, label)
            images[(i, name)] = p
    if not sizes:
        raise RecipeError(f"{folders[0].parent}: no image in its capture folders (images/<camera>.png)")
    names = sorted(sizes, key=_natural_key)
    for folder in folders:
        rig_order = _rig_order(folder)
        if rig_order is not None and set(rig_order) == set(names):
            names = rig_order
            break
    return names, sizes, images


def _rig_order(folder: Path) -> list[str] | None:
    import json

    p = folder / "rig.json"
    if not p.is_file():
        return None
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
        return [str(c["name"]) for c in data["cameras"]]
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _fallback_rig(folders: Sequence[Path]) -> dict[str, Any]:
    """Cameras of the first readable ``rig.json`` of the captures, by name (fallback guesses)."""
    from inspector.capture_folder import read_rig

    for folder in folders:
        if (folder / "rig.json").is_file():
            try:
                return {c.name: c for c in read_rig(folder / "rig.json")}
            except CaptureError:
                continue
    return {}


# --------------------------------------------------------------------------- detection


@dataclass
class BoardView:
    """One board seen by one camera in one capture."""

    capture: int
    camera: int
    board: int
    ids: np.ndarray  # (k,) global corner ids (rows of target.object_points())
    uv: np.ndarray  # (k, 2) pixels
    markers: int
    homography_px: float  # RMS of the markers' corners about one homography, in marker sides
    angle_deg: float = float("nan")  # between the board's normal and the line of sight (initial pose)


@dataclass
class _Detected:
    boards: list[BoardView] = field(default_factory=list)
    markers: int = 0


class _Detectors(threading.local):
    def __init__(self, target: Target) -> None:
        import cv2

        n = target.markers_per_board * target.n_boards
        full = target.cv_dictionary()
        own = cv2.aruco.Dictionary(full.bytesList[:n], full.markerSize, full.maxCorrectionBits)
        self.markers = cv2.aruco.ArucoDetector(own, cv2.aruco.DetectorParameters())
        self.boards = [cv2.aruco.CharucoDetector(target.board(b)) for b in range(target.n_boards)]


def _grey8(img: np.ndarray) -> np.ndarray:
    import cv2

    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    return np.ascontiguousarray(img)


def _homography_rms(obj: np.ndarray, img: np.ndarray) -> float:
    import cv2

    H, _ = cv2.findHomography(obj.astype(np.float64), img.astype(np.float64), 0)
    if H is None:
        return float("inf")
    p = cv2.perspectiveTransform(obj.reshape(-1, 1, 2).astype(np.float64), H).reshape(-1, 2)
    return float(np.sqrt(np.mean(np.sum((p - img) ** 2, axis=1))))


def _detect_one(grey: np.ndarray, target: Target, det: _Detectors, capture: int, camera: int) -> _Detected:
    corners, ids, _ = det.markers.detectMarkers(grey)
    out = _Detected()
    if ids is None or not len(ids):
        return out
    ids = ids.ravel().astype(np.int32)
    out.markers = int(len(ids))
    m = target.markers_per_board
    for b in range(target.n_boards):
        sel = np.flatnonzero(ids // m == b)
        if len(sel) < 2:
            continue
        mc = [np.asarray(corners[int(i)], np.float32).reshape(1, 4, 2) for i in sel]
        cc, ci, _, _ = det.boards[b].detectBoard(grey, markerCorners=mc, markerIds=ids[sel].reshape(-1, 1))
        if ci is None or len(ci) < MIN_CORNERS:
            continue
        board = target.board(b)
        objs = board.getObjPoints()
        ob = np.concatenate([np.asarray(objs[int(ids[i]) - b * m], float)[:, :2] for i in sel])
        im = np.concatenate([c.reshape(4, 2) for c in mc]).astype(float)
        quads = im.reshape(-1, 4, 2)
        side = float(np.mean(np.linalg.norm(quads - np.roll(quads, 1, axis=1), axis=2)))
        out.boards.append(BoardView(capture, camera, b, target.corner_ids(b, ci.ravel()),
                                    np.asarray(cc, float).reshape(-1, 2), int(len(sel)), _homography_rms(ob, im) / max(side, 1e-9)))
    return out


def detect(target: Target, jobs: Sequence[tuple[int, int, Path, tuple[int, int], str]],
           on_done: Callable[[int], None] | None = None) -> tuple[list[BoardView], dict[tuple[int, int], int]]:
    """Detect the target's boards in every image of ``jobs`` ``(capture, camera, path, size,
    label)``, on one thread per core. Returns the boards seen (at least :data:`MIN_CORNERS`
    corners) and the markers found per ``(capture, camera)``."""
    from inspector.capture_folder import decode_image

    local: dict[int, _Detectors] = {}
    lock = threading.Lock()

    def detectors() -> _Detectors:
        k = threading.get_ident()
        with lock:
            if k not in local:
                local[k] = _Detectors(target)
            return local[k]

    def work(job: tuple[int, int, Path, tuple[int, int], str]) -> tuple[int, int, _Detected]:
        i, j, path, size, label = job
        img = decode_image(path, label, CaptureError, size=size)
        return i, j, _detect_one(_grey8(img), target, detectors(), i, j)

    boards: list[BoardView] = []
    markers: dict[tuple[int, int], int] = {}
    workers = max(1, min(len(jobs), os.cpu_count() or 1))
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="calibrate-detect") as pool:
        for i, j, d in pool.map(work, jobs):
            boards += d.boards
            markers[(i, j)] = d.markers
            if on_done is not None:
                on_done(i)
    return boards, markers


def _diagnose_nothing(target: Target, jobs: Sequence[tuple[int, int, Path, tuple[int, int], str]], root: Path) -> RecipeError:
    """Why no board was found: markers of the target's dictionary with other ids, of another
    dictionary (the description does not match), or no marker at all (no target)."""
    import cv2

    from inspector.capture_folder import decode_image

    # a few images spread over the captures and cameras
    sample = list(jobs)[:: max(1, len(jobs) // 6)][:6]
    greys = [_grey8(decode_image(p, label, CaptureError, size=size)) for _, _, p, size, label in sample]
    n_own = target.markers_per_board * target.n_boards
    params = cv2.aruco.DetectorParameters()
    full = cv2.aruco.ArucoDetector(target.cv_dictionary(), params)
    seen: list[int] = []
    for g in greys:
        _, ids, _ = full.detectMarkers(g)
        if ids is not None:
            seen += [int(x) for x in ids.ravel()]
    if seen and max(seen) >= n_own:
        return RecipeError(f"the target description does not match the images: {target.dictionary} markers with ids up to "
                           f"{max(seen)} found, but the target ({target.source}) has ids 0..{n_own - 1}: check its "
                           "dictionary and squares")
    if seen:
        return RecipeError(f"the target description does not match the images: {len(seen)} {target.dictionary} markers "
                           f"found in {len(greys)} images, but no board of {target.source} fits them: check its squares, "
                           "square_mm and marker_mm")
    for name in _OTHER_DICTIONARIES:
        if name == target.dictionary or not hasattr(cv2.aruco, name):
            continue
        det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)), params)
        hits = 0
        for g in greys[:3]:
            _, ids, _ = det.detectMarkers(g)
            hits += 0 if ids is None else len(ids)
        if hits >= 3:
            return RecipeError(f"the target description does not match the images: they show markers of {name}, "
                               f"{target.source} says {target.dictionary}")
    return RecipeError(f"{root}: no target in the images (no {target.dictionary} marker in {len(jobs)} images): "
                       "are these captures of the target?")


# --------------------------------------------------------------------------- initialisation


def _rt_to_T(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = kc.rodrigues(np.ravel(rvec))
    T[:3, 3] = np.ravel(tvec)
    return T


def _inv(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def _init_intrinsics(target: Target, views: list[BoardView], size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, float]:
    """``K`` (3, 3), ``dist`` (5,) and RMS px of ``cv2.calibrateCamera`` over a camera's boards."""
    import cv2

    local = target.board_corners().astype(np.float32)
    C = target.corners_per_board
    # the boards with most corners, at most 60 (plenty for a first guess)
    use = sorted(views, key=lambda v: -len(v.ids))[:60]
    obj = [local[v.ids - v.board * C] for v in use]
    img = [v.uv.astype(np.float32) for v in use]
    flags = cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    rms, K, dist, _, _ = cv2.calibrateCamera(obj, img, size, None, None, flags=flags)
    d = np.zeros(5)
    d[: min(5, np.size(dist))] = np.ravel(dist)[:5]
    return np.asarray(K, float), d, float(rms)


def _solve_view(target: Target, obj_all: np.ndarray, views: list[BoardView], K: np.ndarray, dist: np.ndarray
                ) -> tuple[np.ndarray, float] | None:
    """Body -> camera transform of one view (all its boards) and its RMS px, or None."""
    import cv2

    best = max(views, key=lambda v: len(v.ids))
    C = target.corners_per_board
    local = target.board_corners()[best.ids - best.board * C]
    ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(local.astype(np.float64), best.uv.astype(np.float64), K, dist,
                                              flags=cv2.SOLVEPNP_IPPE)[:4]
    if not ok:
        return None
    ids = np.concatenate([v.ids for v in views])
    uv = np.concatenate([v.uv for v in views]).astype(np.float64)
    X = obj_all[ids].astype(np.float64)
    face = target.faces[best.board]
    found = None
    for rv, tv in zip(rvecs, tvecs):
        T = _rt_to_T(rv, tv) @ _inv(face)  # body -> camera
        r0 = kc.rotvec(T[:3, :3]).reshape(3, 1)
        t0 = T[:3, 3].reshape(3, 1).copy()
        if np.any((X @ T[:3, :3].T + T[:3, 3])[:, 2] <= 0):
            continue
        r1, t1 = cv2.solvePnPRefineLM(X, uv, K, dist, r0, t0)
        p, _ = cv2.projectPoints(X, r1, t1, K, dist)
        rms = float(np.sqrt(np.mean(np.sum((p.reshape(-1, 2) - uv) ** 2, axis=1))))
        if found is None or rms < found[1]:
            found = (_rt_to_T(r1, t1), rms)
    return found


def _spanning_tree(n_cams: int, n_caps: int, edges: dict[tuple[int, int], float], root_pose: int
                   ) -> list[tuple[str, int, int]]:
    """Maximum spanning tree of the camera-pose graph from pose ``root_pose`` (Prim): the order
    in which to place nodes, ``("cam", c, via_pose)`` or ``("pose", p, via_cam)``."""
    by_cam: dict[int, list[tuple[int, float]]] = {}
    by_pose: dict[int, list[tuple[int, float]]] = {}
    for (c, p), w in edges.items():
        by_cam.setdefault(c, []).append((p, w))
        by_pose.setdefault(p, []).append((c, w))
    done_c: set[int] = set()
    done_p = {root_pose}
    heap: list[tuple[float, str, int, int]] = [(-w, "cam", c, root_pose) for c, w in by_pose.get(root_pose, [])]
    heapq.heapify(heap)
    order: list[tuple[str, int, int]] = []
    while heap:
        _, kind, node, via = heapq.heappop(heap)
        if kind == "cam":
            if node in done_c:
                continue
            done_c.add(node)
            order.append(("cam", node, via))
            heap_items = [(-w, "pose", p, node) for p, w in by_cam.get(node, []) if p not in done_p]
        else:
            if node in done_p:
                continue
            done_p.add(node)
            order.append(("pose", node, via))
            heap_items = [(-w, "cam", c, node) for c, w in by_pose.get(node, []) if c not in done_c]
        for item in heap_items:
            heapq.heappush(heap, item)
    return order


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

    # --- intrinsics per camera
    t1 = time.perf_counter()
    by_cam: dict[int, list[BoardView]] = {}
    for v in views:
        by_cam.setdefault(v.camera, []).append(v)
    for j, n in enumerate(names):
        if j not in by_cam:
            seen = sum(1 for (i, jj), m in markers.items() if jj == j and m)
            why = (f"markers in {seen} images but never {MIN_CORNERS} corners of a board" if seen
                   else f"no marker in any of its {sum(1 for (i, jj) in markers if jj == j)} images")
            raise RecipeError(f"camera {n} never sees the target ({why}): show the target to {n}, or remove its images")
    notes: list[str] = []
    progress(f"initialising {len(names)} cameras (intrinsics, target poses, camera graph)")
    fallback: dict[str, Any] | None = None
    Ks = np.zeros((len(names), 3, 3))
    dists = np.zeros((len(names), 5))

    def init_one(j: int) -> tuple[np.ndarray, np.ndarray, float] | None:
        try:
            K, d, rms = _init_intrinsics(target, by_cam[j], sizes[j])
        except Exception:  # noqa: BLE001 - cv2.error and numerical failures: use the fallback
            return None
        w, hh = sizes[j]
        if not (np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0 and rms < 5.0
                and -w < K[0, 2] < 2 * w and -hh < K[1, 2] < 2 * hh):
            return None
        return K, d, rms

    from inspector.kernels.threads import map_threads

    inits = map_threads(init_one, range(len(names)))
    for j, init in enumerate(inits):
        if init is not None:
            Ks[j], dists[j] = init[0], init[1]
            continue
        fallback = _fallback_rig(folders) if fallback is None else fallback
        cam = fallback.get(names[j])
        if cam is None:
            raise RecipeError(f"camera {names[j]}: its intrinsics cannot be estimated from {len(by_cam[j])} boards: "
                              f"show the target to {names[j]} in more poses, tilted")
        Ks[j], dists[j] = np.asarray(cam.K, float), np.asarray(cam.dist, float)
        notes.append(f"{names[j]}: its own first guess of the intrinsics failed; started from the rig.json of the captures")

    # --- target pose in each view
    obj_all = target.object_points()
    by_view: dict[tuple[int, int], list[BoardView]] = {}
    for v in views:
        by_view.setdefault((v.camera, v.capture), []).append(v)
    keys = sorted(by_view)

    def pnp(key: tuple[int, int]) -> tuple[np.ndarray, float] | None:
        j = key[0]
        return _solve_view(target, obj_all, by_view[key], Ks[j], dists[j])

    solved = dict(zip(keys, map_threads(pnp, keys)))
    rms_views = np.array([s[1] for s in solved.values() if s is not None])
    limit = max(5.0, 10.0 * float(np.median(rms_views))) if len(rms_views) else 5.0
    view_T = {k: s[0] for k, s in solved.items() if s is not None and s[1] <= limit}
    edges = {k: float(sum(len(v.ids) for v in by_view[k])) for k in view_T}
    cams_of_pose: dict[int, int] = {}
    for (_, p) in edges:
        cams_of_pose[p] = cams_of_pose.get(p, 0) + 1
    if not cams_of_pose:
        raise RecipeError(f"{root}: the target's pose could not be found in any view")
    anchor = max(cams_of_pose, key=lambda p: (cams_of_pose[p], sum(w for (c, q), w in edges.items() if q == p)))
    order = _spanning_tree(len(names), n_caps, edges, anchor)
    cam_T: dict[int, np.ndarray] = {}  # world -> camera
    pose_T: dict[int, np.ndarray] = {anchor: np.eye(4)}  # body -> world (world: the anchor's body)
    for kind, node, via in order:
        if kind == "cam":
            cam_T[node] = view_T[(node, via)] @ _inv(pose_T[via])
        else:
            pose_T[node] = _inv(cam_T[via]) @ view_T[(via, node)]
    missing = [names[j] for j in range(len(names)) if j not in cam_T]
    if missing:
        raise RecipeError(f"camera {missing[0]} shares no target pose with the other cameras: show the target to "
                          f"{missing[0]} and its neighbours at once")
    # each board's obliquity at its view's initial pose
    normals = target.board_normals()
    w_b, h_b = target.board_size_mm
    for v in views:
        T = view_T.get((v.camera, v.capture))
        if T is None:
            continue
        centre = target.faces[v.board] @ np.array([w_b / 2.0, h_b / 2.0, 0.0, 1.0])
        Xc = T[:3, :3] @ centre[:3] + T[:3, 3]
        cos = float(T[:3, :3] @ normals[v.board] @ (-Xc) / np.linalg.norm(Xc))
        v.angle_deg = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    timings["initialise_s"] = time.perf_counter() - t1
    progress(f"initialised {len(names)} cameras and {len(pose_T)} target poses ({timings['initialise_s']:.1f} s)")

    # --- the bundle adjustment
    t2 = time.perf_counter()
    pose_list = sorted(pose_T)
    pose_index = {p: k for k, p in enumerate(pose_list)}
    use = [k for k, v in enumerate(views) if v.capture in pose_index and (v.camera, v.capture) in view_T]
    steep = [k for k in use if views[k].angle_deg > max_angle_deg]
    # keep at least one board per camera whatever its angle
    for j in range(len(names)):
        mine = [k for k in use if views[k].camera == j]
        if mine and all(k in steep for k in mine):
            steep.remove(min(mine, key=lambda k: views[k].angle_deg))
    steep_set = set(steep)
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
    rejected_groups: list[int] = []
    thr = 0.0
    iterations = 0
    res: kc.BundleResult | None = None
    prob: kc.BundleProblem | None = None
    with _one_blas_thread():
        for rnd in range(reject_rounds + 1):
            t_round = time.perf_counter()
            used_poses = set(pose_idx[keep].tolist())
            fixed = [pose_index[anchor]] + [q for q in range(len(pose_list)) if q not in used_poses]
            free = _free_mask(len(names), len(pose_list), fixed, per_cam)
            prob = kc.BundleProblem(obj_all, cam_idx[keep], pose_idx[keep], pt_idx[keep], uv[keep], len(names),
                                    len(pose_list), params, free, weight[keep])
            res = kc.bundle_adjust(prob, loss=LOSS, f_scale=F_SCALE)
            iterations += res.njev
            params = res.params
            progress(f"adjusting: {len(names)} cameras, {len(used_poses)} poses, {int(keep.sum())} corners: "
                     f"{res.njev} iterations, RMS {res.rms_px:.3f} px ({time.perf_counter() - t_round:.1f} s)")
            if rnd == reject_rounds:
                break
            bad_ids, thr_r = kc.reject_groups(res.residuals, group[keep], reject_factor)
            # never leave a camera without boards
            bad = [int(g) for g in bad_ids]
            for g in list(bad):
                c = views[g].camera
                others = set(group[keep & (cam_idx == c)].tolist()) - set(bad)
                if not others:
                    bad.remove(g)
            if not bad:
                thr = thr if rejected_groups else thr_r
                break
            thr = thr_r
            rejected_groups += bad
            keep &= ~np.isin(group, bad)
            progress(f"rejected {len(bad)} board{'s' * (len(bad) != 1)} whose residual RMS exceeds {thr_r:.3f} px "
                     f"({reject_factor:g} x the median)")
    assert res is not None and prob is not None
    timings["adjust_s"] = time.perf_counter() - t2

    # --- uncertainty
    t3 = time.perf_counter()
    J = prob.jacobian(params[prob.free])
    cov, sigma = kc.normal_covariance(J, prob.residuals(params[prob.free]))  # weighted, as J
    col = np.cumsum(prob.free) - 1
    ext_idx = [int(col[j * kc.N_CAM + 9 + k]) for j in range(len(names)) for k in range(6)]
    ext_free = all(prob.free[j * kc.N_CAM + 9 + k] for j in range(len(names)) for k in range(6))
    cb = prob.cam_block(params)
    if ext_free:
        cen_std, ang_std, _ = kc.camera_uncertainty(cb[:, 9:12], cb[:, 12:15], cov[np.ix_(ext_idx, ext_idx)])
    else:  # pragma: no cover - every camera's extrinsics are free
        cen_std = ang_std = np.full(len(names), np.nan)
    intr_std = np.zeros((len(names), 9))
    for j in range(len(names)):
        for k in range(9):
            i = j * kc.N_CAM + k
            if prob.free[i]:
                intr_std[j, k] = float(np.sqrt(max(cov[col[i], col[i]], 0.0)))
    timings["covariance_s"] = time.perf_counter() - t3
    progress(f"uncertainty of every camera's position and orientation ({timings['covariance_s']:.1f} s)")

    # --- output frame: origin nearest the optical axes, axes of the body at the first pose
    Rc = kc.rodrigues(cb[:, 9:12])
    tc = cb[:, 12:15]
    pb = prob.pose_block(params)
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
    K_out = np.zeros((len(names), 3, 3))
    K_out[:, 0, 0], K_out[:, 1, 1], K_out[:, 0, 2], K_out[:, 1, 2], K_out[:, 2, 2] = cb[:, 0], cb[:, 1], cb[:, 2], cb[:, 3], 1.0

    # --- residuals of every view at the solution (rejected ones too)
    full = kc.BundleProblem(obj_all, cam_idx, pose_idx, pt_idx, uv, len(names), len(pose_list), params, prob.free)
    r_all = full.project(params) - uv
    residuals: list[np.ndarray] = [np.zeros((0, 2)) for _ in views]
    kept_views = np.zeros(len(views), bool)
    for k in use:
        residuals[k] = r_all[group == k]
        kept_views[k] = True
    for g in list(steep_set) + rejected_groups:
        kept_views[g] = False
    rejected = []
    for g in sorted(steep_set) + rejected_groups:
        v = views[g]
        r = residuals[g]
        rejected.append({"camera": names[v.camera], "capture": folders[v.capture].name, "board": int(v.board),
                         "corners": int(len(v.ids)), "rms_px": round(float(np.sqrt(np.mean(np.sum(r * r, axis=1)))), 4),
                         "angle_deg": round(v.angle_deg, 1),
                         "reason": "steep" if g in steep_set else "residual"})
    timings["total_s"] = time.perf_counter() - t0
    return Calibration(
        names=names, sizes=sizes, captures=[f.name for f in folders], K=K_out, dist=cb[:, 4:9].copy(), R=R_out, t=t_out,
        poses=poses_out, views=views, kept=kept_views, residuals=residuals, rejected=rejected, reject_threshold_px=thr,
        rms_px=res.rms_px, iterations=iterations, sigma_px=sigma, centre_std_mm=cen_std, angle_std_deg=ang_std,
        intrinsic_std=intr_std, notes=notes, timings=timings, target=target,
        max_angle_deg=max_angle_deg)


# --------------------------------------------------------------------------- the command


#: The stages of :attr:`Calibration.timings` in the order the command runs them, and their words.
STAGES = (("detect_s", "detection"), ("initialise_s", "initialisation"), ("adjust_s", "adjustment"),
          ("covariance_s", "uncertainty"), ("write_s", "writing"))


def timing_line(timings: dict[str, float]) -> str:
    """``"done in 18.4 s (31.0 s of CPU): detection 6.1 s, initialisation 0.9 s, ..., machine
    load 1.2"``: the command's own benchmark line (seconds of wall time per stage; the CPU
    seconds of all the command's threads and the 1-minute load average beside them, since a
    machine loaded by other work stretches the wall time, not the CPU time)."""
    parts = [f"{word} {timings[key]:.1f} s" for key, word in STAGES if key in timings]
    load = f", machine load {os.getloadavg()[0]:.1f}" if hasattr(os, "getloadavg") else ""
    total = timings.get("command_s", timings.get("total_s", 0.0))
    cpu = f" ({timings['cpu_s']:.1f} s of CPU)" if "cpu_s" in timings else ""
    return f"done in {total:.1f} s{cpu}: {', '.join(parts)}{load}"


def run_calibrate(args: argparse.Namespace) -> int:
    """``inspector calibrate TARGET.toml --captures DIR --out RIG.json [--force] [--report DIR] [--json]``."""
    import json

    from inspector.calibration import report as rep
    from inspector.calibration.command import check_new_file, write_rig
    from inspector.model import Camera, Rig

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
    progress(timing_line(cal.timings))
    summary["timings_s"] = {k: round(v, 3) for k, v in cal.timings.items()}
    summary["load_1min"] = round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None
    (report_dir / "report.json").write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    if getattr(args, "json", False):
        print(json.dumps(summary, indent=1))
    else:
        print(rep.text(summary))
    return 0
