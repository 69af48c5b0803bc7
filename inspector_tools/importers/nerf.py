"""Importer ``nerf``: ``transforms*.json`` (Blender / NeRF synthetic, instant-ngp) -> capture folder(s)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from inspector.errors import InputError
from inspector.model import Camera, Rig
from inspector_tools.importers.common import (
    _alpha_to_grey,
    _check_size,
    _find_image,
    _label,
    _load_json_file,
    _pick_sources,
    _read_image,
    _rotation,
    _scale_of,
    _targets,
    _unique_names,
    _units_note,
    _write,
)

__all__ = ["import_nerf"]

_GL_TO_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def _num(d: Mapping[str, Any], key: str, where: str) -> float | None:
    if key not in d or d[key] is None:
        return None
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise InputError(f"{where}: {key} must be a number, got {json.dumps(v)}")
    return float(v)


def _nerf_intrinsics(meta: Mapping[str, Any], frame: Mapping[str, Any], w: int, h: int, where: str) -> tuple[np.ndarray, np.ndarray]:
    """K (OpenCV pixel-centre convention) and dist for one frame (frame keys override)."""

    def get(key: str) -> float | None:
        v = _num(frame, key, where)
        return v if v is not None else _num(meta, key, where)

    fx, fy = get("fl_x"), get("fl_y")
    ax, ay = get("camera_angle_x"), get("camera_angle_y")
    if fx is None and ax is not None:
        if not 0 < ax < math.pi:
            raise InputError(f"{where}: camera_angle_x must be in (0, pi) radians, got {ax}")
        fx = 0.5 * w / math.tan(0.5 * ax)
    if fy is None and ay is not None:
        if not 0 < ay < math.pi:
            raise InputError(f"{where}: camera_angle_y must be in (0, pi) radians, got {ay}")
        fy = 0.5 * h / math.tan(0.5 * ay)
    if fx is None and fy is None:
        raise InputError(f"{where}: no focal length (camera_angle_x or fl_x)")
    fx = fy if fx is None else fx
    fy = fx if fy is None else fy
    assert fx is not None and fy is not None  # one of them is given (checked above)
    if fx <= 0 or fy <= 0:
        raise InputError(f"{where}: focal lengths must be > 0 (fx={fx}, fy={fy})")
    cx, cy = get("cx"), get("cy")
    cx = 0.5 * w if cx is None else cx
    cy = 0.5 * h if cy is None else cy
    # NeRF / Blender / instant-ngp: (0, 0) is the top-left pixel's corner; OpenCV: its centre.
    K = np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])
    dist = np.array([get(k) or 0.0 for k in ("k1", "k2", "p1", "p2", "k3")])
    return K, dist



def _nerf_image_path(base: Path, file_path: str) -> Path:
    p = base / file_path
    if p.is_file():
        return p
    found = _find_image(p.parent, p.name)  # Blender synthetic: "./train/r_0" without ".png"
    return found if found is not None else p


def import_nerf(src: Path, out: Path, *, scale: float | None = None, overwrite: bool = False) -> list[Path]:
    """NeRF ``transforms*.json`` (file, or a folder: one capture per file) -> capture folder(s).

    Lengths are in unknown scene units: kept unless ``scale`` is given.
    """
    files = _pick_sources(Path(src), "transforms*.json", "NeRF transforms file")
    s = _scale_of(scale, 1.0)
    names = []
    for f in files:
        n = f.stem[len("transforms"):].lstrip("_-") if f.stem.startswith("transforms") else f.stem
        names.append(n or f.stem)
    written = []
    for path, name, target in zip(files, names, _targets(Path(out), names)):
        meta = _load_json_file(path)
        if not isinstance(meta, dict):
            raise InputError(f"{_label(path)}: must be a JSON object")
        frames = meta.get("frames")
        if not isinstance(frames, list) or not frames:
            raise InputError(f"{_label(path)}: no frames (expected a non-empty list 'frames')")
        stems = []
        for i, fr in enumerate(frames):
            if not isinstance(fr, dict) or not isinstance(fr.get("file_path"), str):
                raise InputError(f"{_label(path)}: frames[{i}]: missing file_path")
            stems.append(Path(fr["file_path"]).stem)
        cam_names = _unique_names(stems)
        cams, images = [], {}
        for i, (fr, cname) in enumerate(zip(frames, cam_names)):
            where = f"{_label(path)}: frames[{i}] ({fr['file_path']})"
            try:
                M = np.array(fr.get("transform_matrix"), dtype=float)
            except (TypeError, ValueError):
                raise InputError(f"{where}: transform_matrix must be a 4x4 list of numbers") from None
            if M.shape == (3, 4):
                M = np.vstack([M, [0.0, 0.0, 0.0, 1.0]])
            if M.shape != (4, 4) or not np.all(np.isfinite(M)):
                raise InputError(f"{where}: transform_matrix must be a 4x4 list of numbers")
            ipath = _nerf_image_path(path.parent, fr["file_path"])
            img = _read_image(ipath)
            h, w = img.shape[:2]
            wj, hj = _num(fr, "w", where) or _num(meta, "w", where), _num(fr, "h", where) or _num(meta, "h", where)
            if wj is not None and hj is not None:
                _check_size(img, int(wj), int(hj), ipath)
            if img.ndim != 3 or img.shape[2] != 4:
                raise InputError(f"{_label(ipath)}: no alpha channel (the nerf importer takes the silhouette from RGBA images)")
            K, dist = _nerf_intrinsics(meta, fr, w, h, where)
            c2w = M @ _GL_TO_CV
            Rc2w = _rotation(c2w[:3, :3], f"{where}: transform_matrix")
            R = Rc2w.T
            t = -R @ (c2w[:3, 3] * s)
            cams.append(Camera(cname, w, h, K, dist, R, t))
            images[cname] = _alpha_to_grey(img[:, :, 3])
        info = {
            "format": "nerf",
            "source": str(path.resolve()),
            "units": _units_note("unknown", s),
            "scale_to_mm": s,
            "world_frame": "the dataset's world frame (camera->world OpenGL matrices converted to OpenCV world->camera)",
            "pixel_convention": "NeRF/Blender (0, 0) = corner of the top-left pixel; cx, cy shifted by -0.5 px",
            "images": "silhouettes: grey = full scale * (1 - alpha), dark object on white; the colour is dropped",
            "segment": {"polarity": "dark-object", "threshold": "fixed", "level": 127.5, "median": "off"},
            "fill_holes": False,
        }
        written.append(
            _write(
                target,
                Rig(tuple(cams)),
                images,
                polarity="dark-object",
                part_id=f"{path.parent.resolve().name}-{name}",
                info=info,
                overwrite=overwrite,
            )
        )
    return written


# ===================================================================== idr
