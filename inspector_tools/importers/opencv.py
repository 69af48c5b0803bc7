"""Importer ``opencv``: one ``cv2.FileStorage`` calibration per camera + same-stem images -> capture folder."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from inspector.errors import InputError
from inspector.model import Camera, Rig
from inspector_tools.importers.common import (
    _check_size,
    _find_image,
    _label,
    _read_image,
    _read_text,
    _rotation,
    _scale_of,
    _unique_names,
    _units_note,
    _write,
)

__all__ = ["import_opencv"]

_K_KEYS = ("camera_matrix", "K", "cameraMatrix", "camera_matrix_K", "intrinsic", "intrinsics", "intrinsic_matrix", "M", "mtx", "A")
_D_KEYS = ("distortion_coefficients", "dist", "D", "dist_coeffs", "distCoeffs", "distortion", "dist_coeff", "distortion_coeffs")
_R_KEYS = ("R", "rotation", "rotation_matrix", "Rot", "R_mat", "rmat")
_RVEC_KEYS = ("rvec", "rvecs", "rotation_vector", "rodrigues", "om")
_T_KEYS = ("t", "T", "tvec", "tvecs", "translation", "translation_vector", "trans")
_W_KEYS = ("image_width", "width", "imageWidth", "img_width", "w", "cols")
_H_KEYS = ("image_height", "height", "imageHeight", "img_height", "h", "rows")
_SIZE_KEYS = ("image_size", "imageSize", "size", "resolution")
_OPENCV_EXTS = (".yml", ".yaml", ".xml", ".json")


def _fs_read(path: Path) -> dict[str, Any]:
    """All top-level nodes of a FileStorage file -> {name: ndarray | float | str}."""
    import cv2

    _read_text(path)  # existence, readability
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # cv2 5 raises SystemError around its parse errors
        cause = exc.__cause__ or exc.__context__ or exc
        text = str(cause).strip()
        msg = text.splitlines()[-1][-160:] if text else "parse error"
        raise InputError(f"{_label(path)}: not a readable OpenCV FileStorage file ({msg})") from None
    if not fs.isOpened():
        raise InputError(f"{_label(path)}: not a readable OpenCV FileStorage file")
    out: dict[str, Any] = {}
    try:
        root = fs.root()
        for key in root.keys():
            node = fs.getNode(key)
            if node.isMap():  # !!opencv-matrix / !!opencv-nd-matrix; other maps are skipped
                try:
                    m = node.mat()
                except cv2.error:
                    m = None
                if m is not None:
                    out[key] = np.asarray(m, float)
            elif node.isSeq():
                vals = [node.at(i) for i in range(node.size())]
                if all(v.isReal() or v.isInt() for v in vals):
                    out[key] = np.array([v.real() for v in vals], float)
                elif all(v.isSeq() for v in vals):
                    try:
                        out[key] = np.array([[v.at(j).real() for j in range(v.size())] for v in vals], float)
                    except Exception:  # noqa: BLE001 - ragged or not numbers: the key is left out
                        pass
            elif node.isReal() or node.isInt():
                out[key] = float(node.real())
            elif node.isString():
                out[key] = node.string()
    finally:
        fs.release()
    return out


def _first(d: Mapping[str, Any], keys: Sequence[str]) -> tuple[str, Any] | tuple[None, None]:
    low = {k.lower(): k for k in d}
    for k in keys:
        if k in d:
            return k, d[k]
    for k in keys:  # case-insensitive, but never for one-letter keys (K is not k)
        if len(k) > 1 and k.lower() in low:
            return low[k.lower()], d[low[k.lower()]]
    return None, None


def import_opencv(
    src: Path, out: Path, *, scale: float | None = None, polarity: str | None = None, overwrite: bool = False
) -> list[Path]:
    """A folder of OpenCV FileStorage calibrations (one per camera) + same-stem images -> one capture."""
    src = Path(src)
    if not src.is_dir():
        raise InputError(f"{_label(src)}: not a folder (expected one OpenCV calibration file per camera)")
    files = sorted(p for p in src.iterdir() if p.is_file() and p.suffix.lower() in _OPENCV_EXTS and not p.name.startswith("."))
    if not files:
        raise InputError(f"{_label(src)}: no OpenCV calibration files ({', '.join(_OPENCV_EXTS)})")
    pol = polarity or "dark-object"
    if pol not in ("dark-object", "bright-object"):
        raise InputError(f"polarity must be 'dark-object' or 'bright-object', got {polarity!r}")
    cam_names = _unique_names([p.stem for p in files])
    cams, images = [], {}
    units_seen: set[str] = set()
    for path, cname in zip(files, cam_names):
        cam, img = _opencv_camera(src, path, cname)
        units_seen.add(cam[-1])
        cams.append(cam)
        images[cname] = img
    if len(units_seen) > 1:
        raise InputError(f"{_label(src)}: the calibration files disagree on units ({', '.join(sorted(units_seen))})")
    native = units_seen.pop()
    s = _scale_of(scale, {"mm": 1.0, "m": 1000.0}.get(native, 1.0))
    rig = Rig(tuple(Camera(n, w, h, K, dist, R, T * s) for (n, w, h, K, dist, R, T, _) in cams))
    info = {
        "format": "opencv",
        "source": str(src.resolve()),
        "units": _units_note(native, s),
        "scale_to_mm": s,
        "world_frame": "the calibration's world frame",
        "pixel_convention": "OpenCV ((0, 0) the centre of the top-left pixel)",
        "images": "the images, unchanged",
        "segment": {"polarity": pol},
        "fill_holes": False,
    }
    return [_write(Path(out), rig, images, polarity=pol, part_id=src.name, info=info, overwrite=overwrite)]


def _opencv_camera(src: Path, path: Path, cname: str) -> tuple[tuple[Any, ...], np.ndarray]:
    """One calibration file and its image: ((name, w, h, K, dist, R, t, units), image)."""
    import cv2

    where = _label(path)
    d = _fs_read(path)
    kk, K = _first(d, _K_KEYS)
    if K is None:
        raise InputError(f"{where}: no camera matrix (keys {', '.join(_K_KEYS[:4])}...)")
    K = np.asarray(K, float)
    if K.size == 9:
        K = K.reshape(3, 3)
    elif K.size == 4:  # fx, fy, cx, cy
        fx, fy, cx, cy = K.ravel()
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    else:
        raise InputError(f"{where}: {kk} must be 3x3, got {K.size} values")
    if abs(K[2, 2]) < 1e-12 or np.any(np.abs(K[2, :2]) > 1e-12) or abs(K[1, 0]) > 1e-12:
        raise InputError(f"{where}: {kk} must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
    K = K / K[2, 2]
    K[1, 0] = K[2, 0] = K[2, 1] = 0.0
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError(f"{where}: {kk} has non-positive focal lengths")
    dk, D = _first(d, _D_KEYS)
    dist = np.zeros(5)
    if D is not None:
        D = np.ravel(np.asarray(D, float))
        if D.size > 5 and np.any(D[5:]):
            raise InputError(f"{where}: {dk} has {D.size} coefficients with non-zero k4..; only [k1, k2, p1, p2, k3] is supported")
        dist[: min(5, D.size)] = D[:5]  # OpenCV order; missing terms are zero
    rk, Rm = _first(d, _R_KEYS)
    if Rm is not None and np.size(Rm) == 3:  # a rotation vector stored under "R"
        Rm = cv2.Rodrigues(np.asarray(Rm, float).reshape(3, 1))[0]
    if Rm is None:
        rk, rv = _first(d, _RVEC_KEYS)
        if rv is None:
            raise InputError(f"{where}: no rotation (R, rotation_matrix or rvec)")
        rv = np.ravel(np.asarray(rv, float))
        if rv.size != 3:
            raise InputError(f"{where}: {rk} must have 3 values, got {rv.size}")
        Rm = cv2.Rodrigues(rv.reshape(3, 1))[0]
    Rm = np.asarray(Rm, float)
    if Rm.size != 9:
        raise InputError(f"{where}: {rk} must be 3x3, got {Rm.size} values")
    R = _rotation(Rm.reshape(3, 3), f"{where}: {rk}")
    tk, T = _first(d, _T_KEYS)
    if T is None:
        raise InputError(f"{where}: no translation (t, T or tvec)")
    T = np.ravel(np.asarray(T, float))
    if T.size != 3:
        raise InputError(f"{where}: {tk} must have 3 values, got {T.size}")
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(dist)) and np.all(np.isfinite(T))):
        raise InputError(f"{where}: non-finite camera parameters")
    _, units = _first(d, ("units", "unit"))
    u = str(units).strip().lower() if isinstance(units, str) else "unknown"
    if u in ("millimeter", "millimetre", "millimeters", "millimetres"):
        u = "mm"
    if u in ("meter", "metre", "meters", "metres"):
        u = "m"
    if u not in ("mm", "m"):
        u = "unknown"
    ipath = _find_image(src, path.stem) or _find_image(src / "images", path.stem)
    if ipath is None:
        raise InputError(f"{where}: no image {path.stem}.<png|jpg|...> next to it (or in images/)")
    img = _read_image(ipath)
    h, w = img.shape[:2]
    _, W = _first(d, _W_KEYS)
    _, H = _first(d, _H_KEYS)
    if W is None or H is None:
        _, size = _first(d, _SIZE_KEYS)
        if size is not None and np.size(size) == 2:
            W, H = np.ravel(size)
    if isinstance(W, (int, float, np.floating)) and isinstance(H, (int, float, np.floating)):
        _check_size(img, int(W), int(H), ipath)
    return (cname, w, h, K, dist, R, T, u), img
