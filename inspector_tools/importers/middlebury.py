"""Importer ``middlebury``: ``*_par.txt`` (Middlebury multi-view stereo) -> capture folder(s)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from inspector.errors import InputError
from inspector.model import Camera, Rig
from inspector_tools.importers.common import (
    _label,
    _pick_sources,
    _read_image,
    _read_text,
    _rotation,
    _scale_of,
    _targets,
    _unique_names,
    _units_note,
    _write,
)

__all__ = ["MIDDLEBURY_LEVEL", "MIDDLEBURY_CLOSE_PX", "import_middlebury"]

#: Dataset README (Middlebury): "thresholded at 0.19 (where color values range from 0 to 1)".
MIDDLEBURY_LEVEL = 0.19 * 255.0
#: ... "dilated by 10 pixels, eroded by 7 pixels": a 10 px closing (without the net 3 px growth).
MIDDLEBURY_CLOSE_PX = 10


def _parse_par(path: Path, scale: float) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
    rows = [ln.split() for ln in _read_text(path).splitlines()]
    lines = [(i + 1, ln) for i, ln in enumerate(rows) if ln and not ln[0].startswith("#")]
    if not lines:
        raise InputError(f"{_label(path)}: empty file")
    count = None
    if len(lines[0][1]) == 1:
        try:
            count = int(lines[0][1][0])
        except ValueError:
            raise InputError(f"{_label(path)}: line {lines[0][0]}: expected the number of images, got {lines[0][1][0]!r}") from None
        lines = lines[1:]
    if count is not None and count != len(lines):
        raise InputError(f"{_label(path)}: says {count} images but has {len(lines)} camera lines")
    if not lines:
        raise InputError(f"{_label(path)}: no camera line")
    cams = []
    for lineno, tok in lines:
        where = f"{_label(path)}: line {lineno}"
        if len(tok) != 22:
            raise InputError(f"{where}: expected 'imgname k11..k33 r11..r33 t1 t2 t3' (22 fields), got {len(tok)}")
        try:
            v = np.array([float(x) for x in tok[1:]])
        except ValueError:
            raise InputError(f"{where}: non-numeric camera parameter") from None
        if not np.all(np.isfinite(v)):
            raise InputError(f"{where}: non-finite camera parameter")
        K = v[:9].reshape(3, 3)
        if abs(K[2, 2]) < 1e-12 or np.any(K[2, :2] != 0) or K[1, 0] != 0:
            raise InputError(f"{where}: K must be upper triangular [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
        K = K / K[2, 2]
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise InputError(f"{where}: K has non-positive focal lengths fx={K[0, 0]:.6g}, fy={K[1, 1]:.6g}")
        R = _rotation(v[9:18].reshape(3, 3), f"{where} ({tok[0]})")
        t = v[18:21] * scale
        cams.append((tok[0], K, R, t))
    return cams


def import_middlebury(src: Path, out: Path, *, scale: float | None = None, overwrite: bool = False) -> list[Path]:
    """Middlebury ``*_par.txt`` (file, or a folder holding them) -> capture folder(s).

    Lengths in metres are multiplied by ``scale`` (default 1000: mm).
    """
    pars = _pick_sources(Path(src), "*_par.txt", "Middlebury camera file")
    s = _scale_of(scale, 1000.0)
    names = [p.name[: -len("_par.txt")] if p.name.endswith("_par.txt") else p.stem for p in pars]
    written = []
    for par, name, target in zip(pars, names, _targets(Path(out), names)):
        entries = _parse_par(par, s)
        cam_names = _unique_names([Path(e[0]).stem for e in entries])
        cams, images = [], {}
        for (img_name, K, R, t), cname in zip(entries, cam_names):
            ipath = par.parent / img_name
            img = _read_image(ipath)
            h, w = img.shape[:2]
            cams.append(Camera(cname, w, h, K, np.zeros(5), R, t))
            images[cname] = img
        good_file = par.parent / f"{name}_good_silhouette_images.txt"
        info: dict[str, Any] = {
            "format": "middlebury",
            "source": str(par.resolve()),
            "units": _units_note("m", s),
            "scale_to_mm": s,
            "world_frame": "the dataset's world frame, lengths scaled",
            "pixel_convention": "as in the dataset (P = K [R t] applied to pixel indices: (0, 0) the centre of the top-left pixel)",
            "images": "the photographs, unchanged (bright object on a black background)",
            "segment": {"polarity": "bright-object", "threshold": "fixed", "level": MIDDLEBURY_LEVEL, "median": "full"},
            "fill_holes": True,
            "close_px": MIDDLEBURY_CLOSE_PX,
        }
        if good_file.is_file():
            stems = {Path(x).stem for x in _read_text(good_file).split()}
            by_stem = {Path(e[0]).stem: c for e, c in zip(entries, cam_names)}
            info["good_silhouettes"] = [by_stem[x] for x in by_stem if x in stems]
        written.append(
            _write(target, Rig(tuple(cams)), images, polarity="bright-object", part_id=name, info=info, overwrite=overwrite)
        )
    return written


