"""The capture folders of ``inspector calibrate``, their cameras, and the target found in their images.

Stages 1 and 2 of :mod:`inspector.calibration.solve`: :func:`capture_folders` and
:func:`find_cameras` read what ``--captures DIR`` holds (one capture folder per target pose,
each ``images/<camera>.png`` a camera, its size read from the PNG header); :func:`detect`
finds every board's ChArUco corners in every image (threads, OpenCV releases the GIL) and
:func:`_diagnose_nothing` says why nothing was found.
"""

from __future__ import annotations

import json
import os
import re
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from inspector.calibration.target import Target
from inspector.capture_folder import decode_image, read_rig
from inspector.errors import CaptureError, RecipeError
from inspector.png import png_header

__all__ = ["capture_folders", "find_cameras", "detect", "BoardView", "MIN_CORNERS"]

#: A board is kept in a view only with this many corners.
MIN_CORNERS = 6
#: Dictionaries looked for when the target's finds nothing (the largest of each family: the
#: smaller ones are their first ids).
_OTHER_DICTIONARIES = ("DICT_4X4_1000", "DICT_5X5_1000", "DICT_6X6_1000", "DICT_7X7_1000", "DICT_ARUCO_ORIGINAL",
                       "DICT_APRILTAG_36h11", "DICT_ARUCO_MIP_36h12")



def _natural_key(name: str) -> tuple[Any, ...]:
    """``name`` as a sort key whose runs of digits compare as numbers (``cap2`` before ``cap10``)."""
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
    """The camera names of ``folder``'s ``rig.json``, in its order; None without a readable one."""
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


