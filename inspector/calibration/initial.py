"""The first guess of ``inspector calibrate`` (stage 3 of :mod:`inspector.calibration.solve`).

Each camera's intrinsics by ``cv2.calibrateCamera`` over its boards (each board of a view a
planar view, at most 60, k2 = k3 = 0, no tangential terms), else from the first ``rig.json`` of
the captures; then each view's target pose (body -> camera) by ``solvePnP`` over all its
corners. Cameras and target poses form a graph whose edges are the views; a maximum spanning
tree (weights: corners) from the pose seen by most cameras chains the cameras' extrinsics
through the poses they share.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from inspector.calibration.detect import MIN_CORNERS, BoardView, _fallback_rig
from inspector.calibration.target import Target
from inspector.errors import RecipeError
from inspector.kernels import calibration as kc
from inspector.kernels.threads import map_threads


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


def _initial_intrinsics(target: Target, folders: Sequence[Path], names: list[str], sizes: list[tuple[int, int]],
                        views: list[BoardView], markers: dict[tuple[int, int], int], progress: Callable[[str], None]
                        ) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Each camera's first intrinsics (stage 3 of :func:`calibrate`), from its own boards, else
    from the first ``rig.json`` of the captures.

    Parameters
    ----------
    target : Target
        The calibration target.
    folders : sequence of Path
        The capture folders (their ``rig.json``: the fallback).
    names, sizes : list
        The cameras and their ``(width, height)``.
    views : list of BoardView
        The boards seen.
    markers : dict
        Markers found per ``(capture, camera)`` (the error of a camera that sees no board).
    progress : callable
        Receives the progress lines.

    Returns
    -------
    Ks : (C, 3, 3) array
        Camera matrices.
    dists : (C, 5) array
        Distortion coefficients.
    notes : list of str
        The cameras started from the fallback, for the report.

    Raises
    ------
    RecipeError
        A camera never sees the target, or neither way gives its intrinsics.
    """
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
    return Ks, dists, notes


def _initial_poses(target: Target, names: list[str], n_caps: int, views: list[BoardView], Ks: np.ndarray,
                   dists: np.ndarray, root: Path
                   ) -> tuple[np.ndarray, dict[tuple[int, int], np.ndarray], dict[int, np.ndarray],
                              dict[int, np.ndarray], int]:
    """The target's pose in each view, the cameras and target poses chained through them
    (stage 3 of :func:`calibrate`), and each board's obliquity (``angle_deg``, set in ``views``).

    Parameters
    ----------
    target : Target
        The calibration target.
    names : list of str
        The cameras.
    n_caps : int
        The number of capture folders (target poses).
    views : list of BoardView
        The boards seen; their ``angle_deg`` is set.
    Ks, dists : array
        The cameras' first intrinsics (:func:`_initial_intrinsics`).
    root : Path
        The captures' folder, named in the error.

    Returns
    -------
    obj_all : (P, 3) array
        The target's corners, body frame.
    view_T : dict
        Body -> camera of each ``(camera, capture)`` view kept.
    cam_T : dict
        World -> camera of each camera.
    pose_T : dict
        Body -> world of each target pose reached (world: the anchor's body).
    anchor : int
        The target pose seen by most cameras (the gauge).

    Raises
    ------
    RecipeError
        No view's pose found, or a camera shares no target pose with the others.
    """
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
    return obj_all, view_T, cam_T, pose_T, anchor


