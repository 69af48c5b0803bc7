"""Importers: the helpers every dataset format shares (reading files and images within
the limits, names, rotations, writing the capture folder, filling silhouette holes)."""

from __future__ import annotations

import math
import re
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from inspector.errors import InputError
from inspector.limits import limit, load_json, read_bounded
from inspector.model import Rig

#: Tolerance on ``R R^T = I`` for an imported rotation (re-orthonormalised below it).
_ROT_TOL = 1e-4
_IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".exr", ".webp", ".ppm", ".pgm")
_BAD_NAME = re.compile(r"[^A-Za-z0-9_.+-]")


def _label(path: Path) -> str:
    return str(path)


def _read_text(path: Path) -> str:
    """A dataset's text file (camera list, calibration), measured before it is read and
    never read past ``INSPECTOR_MAX_JSON_BYTES`` (a 2 GiB file was an internal MemoryError)."""
    if not path.exists():
        raise InputError(f"{_label(path)}: missing")
    raw = read_bounded(path, _label(path), limit("MAX_JSON_BYTES"), InputError, what="a dataset text file",
                       variable="INSPECTOR_MAX_JSON_BYTES")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"{_label(path)}: not a text file (byte {exc.start})") from None


def _read_image(path: Path) -> np.ndarray:
    """Any image cv2 reads -> uint8/uint16 array, grey (H, W), RGB or RGBA (cv2's BGR swapped)."""
    from inspector.capture_folder import decode_image, to_rgb_order

    img = decode_image(path, _label(path), InputError, png_only=False)
    if img.dtype not in (np.uint8, np.uint16):
        if img.dtype.kind == "f":  # EXR & co.: [0, 1] floats -> 16 bit
            img = np.clip(np.rint(np.nan_to_num(img) * 65535.0), 0, 65535).astype(np.uint16)
        else:
            raise InputError(f"{_label(path)}: unsupported pixel type {img.dtype}")
    return to_rgb_order(img, _label(path), InputError)


def _image_size(path: Path) -> tuple[int, int]:
    """``(width, height)`` of an image from its header (Pillow reads no pixel), so a
    photograph whose size is all an importer needs is never decoded (a 3 MB PNG bomb took
    6.2 GB); more than ``INSPECTOR_MAX_IMAGE_PIXELS`` is refused in one line."""
    from PIL import Image, UnidentifiedImageError

    most = limit("MAX_IMAGE_PIXELS")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                w, h = im.size
    except Image.DecompressionBombError as exc:  # its own bound, far above ours: say ours
        m = re.search(r"\((\d+) pixels\)", str(exc))
        raise InputError(f"{_label(path)}: {m.group(1) if m else 'too many'} pixels, more than the {most} an image may "
                         "have (INSPECTOR_MAX_IMAGE_PIXELS)") from None
    except (OSError, UnidentifiedImageError, ValueError) as exc:
        raise InputError(f"{_label(path)}: unreadable image ({type(exc).__name__})") from None
    if w * h > most:
        raise InputError(f"{_label(path)}: {w}x{h} is {w * h} pixels, more than the {most} an image may have "
                         "(INSPECTOR_MAX_IMAGE_PIXELS)")
    return int(w), int(h)


def _load_npz(npz: Path, wanted: Callable[[str], bool]) -> dict[str, np.ndarray]:
    """The arrays of ``npz`` whose names ``wanted`` accepts, each sized from its ``.npy``
    header before it is decompressed (a 4 MB npz inflating to 4 GB is refused in one line);
    the others are never read."""
    import zipfile

    most = limit("MAX_JSON_BYTES")
    out: dict[str, np.ndarray] = {}
    try:
        with zipfile.ZipFile(npz) as zf:
            for info in zf.infolist():
                name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
                if not wanted(name):
                    continue
                with zf.open(info) as f:
                    version = np.lib.format.read_magic(f)
                    if version == (1, 0):
                        shape, _, dtype = np.lib.format.read_array_header_1_0(f)
                    elif version == (2, 0):
                        shape, _, dtype = np.lib.format.read_array_header_2_0(f)
                    else:
                        raise InputError(f"{_label(npz)}: array {name}: unsupported .npy version {version}")
                    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
                    if nbytes > most or dtype.hasobject:
                        raise InputError(f"{_label(npz)}: array {name} is {shape} {dtype} ({nbytes} bytes), more than the "
                                         f"{most} bytes a camera array may have (INSPECTOR_MAX_JSON_BYTES)")
                with zf.open(info) as f:
                    out[name] = np.asarray(np.lib.format.read_array(f, allow_pickle=False))
    except InputError:
        raise
    except (OSError, ValueError, EOFError) as exc:
        raise InputError(f"{_label(npz)}: unreadable npz ({exc})") from None
    except Exception as exc:  # noqa: BLE001 - zipfile.BadZipFile and friends
        raise InputError(f"{_label(npz)}: unreadable npz ({type(exc).__name__}: {exc})") from None
    return out


def _find_image(folder: Path, stem: str) -> Path | None:
    for ext in _IMAGE_EXTS:
        for e in (ext, ext.upper()):
            p = folder / f"{stem}{e}"
            if p.is_file():
                return p
    return None


def _list_images(folder: Path) -> list[Path]:
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in _IMAGE_EXTS and not p.name.startswith("."))


def _rotation(R: Any, where: str) -> np.ndarray:
    """A 3x3 rotation, re-orthonormalised (nearest rotation) when within ``_ROT_TOL``."""
    R = np.asarray(R, float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise InputError(f"{where}: rotation must be 3x3 finite numbers, got shape {R.shape}")
    err = float(np.max(np.abs(R @ R.T - np.eye(3))))
    det = float(np.linalg.det(R))
    if err > _ROT_TOL or det <= 0:
        raise InputError(f"{where}: not a rotation matrix (det={det:.6g}, max|R R^T - I|={err:.2g})")
    if err > 1e-12:
        U, _, Vt = np.linalg.svd(R)
        R = U @ Vt
    return R


def _camera_name(raw: str, index: int, used: set[str]) -> str:
    name = _BAD_NAME.sub("_", raw).strip("._") or f"cam{index:03d}"
    if name in used:
        name = f"{name}_{index:03d}"
    used.add(name)
    return name


def _unique_names(stems: Sequence[str]) -> list[str]:
    used: set[str] = set()
    return [_camera_name(s, i, used) for i, s in enumerate(stems)]


def _check_size(img: np.ndarray, w: int, h: int, path: Path) -> None:
    if img.shape[1] != w or img.shape[0] != h:
        raise InputError(f"{_label(path)}: size {img.shape[1]}x{img.shape[0]}, the calibration says {w}x{h}")


def _alpha_to_grey(alpha: np.ndarray) -> np.ndarray:
    """Object coverage (uint8/uint16, 0 = empty) -> grey image dark object on white."""
    top = np.iinfo(alpha.dtype).max
    return (top - alpha).astype(alpha.dtype)


def _mask_to_coverage(mask: np.ndarray) -> np.ndarray:
    """A mask image (grey or colour, object bright) -> single-channel coverage, same dtype."""
    if mask.ndim == 3:
        if mask.shape[2] == 4:  # an RGBA mask: its alpha if used, else its colour
            a = mask[:, :, 3]
            if int(a.min()) != int(a.max()):
                return np.ascontiguousarray(a)
            mask = mask[:, :, :3]
        mask = mask.max(axis=2)
    return np.ascontiguousarray(mask)


def _write(
    out: Path,
    rig: Rig,
    images: Mapping[str, np.ndarray],
    *,
    polarity: str,
    part_id: str,
    info: dict[str, Any],
    overwrite: bool,
) -> Path:
    from inspector.capture_folder import write_capture

    try:
        return write_capture(
            out,
            rig,
            images,
            metadata={"part_id": part_id, "import": info},
            polarity=polarity,
            overwrite=overwrite,
        )
    except FileExistsError:
        raise InputError(f"{_label(out)}: folder exists and is not empty (overwrite it with --force)") from None
    except ValueError as exc:
        raise InputError(f"{_label(out)}: cannot write the capture ({exc})") from None
    except OSError as exc:
        raise InputError(f"{_label(out)}: cannot write the capture ({exc.strerror or exc})") from None


def _targets(out: Path, names: Sequence[str]) -> list[Path]:
    """One capture: ``out`` itself; several: ``out/<name>``."""
    return [out] if len(names) == 1 else [out / n for n in names]


def _scale_of(scale: float | None, default: float) -> float:
    s = default if scale is None else float(scale)
    if not (math.isfinite(s) and s > 0):
        raise InputError(f"scale must be a positive number, got {scale!r}")
    return s


def _units_note(native: str, s: float) -> str:
    if native == "unknown":
        return "unknown: lengths kept as in the dataset (scene units written as mm)" if s == 1.0 else f"unknown: lengths multiplied by {s:g}"
    return f"{native}: lengths multiplied by {s:g} to mm"


def _pick_sources(src: Path, pattern: str, what: str) -> list[Path]:
    src = Path(src)
    if not src.exists():
        raise InputError(f"{_label(src)}: does not exist")
    if src.is_file():
        return [src]
    found = sorted(p for p in src.glob(pattern) if p.is_file())
    if not found:
        raise InputError(f"{_label(src)}: no {what} ({pattern}) in this folder")
    return found


def _load_json_file(path: Path) -> Any:
    """A dataset's JSON file, within the input bounds (size and depth, :mod:`inspector.limits`)."""
    if not path.exists():
        raise InputError(f"{_label(path)}: missing")
    if not path.is_file():
        raise InputError(f"{_label(path)}: not a file")
    return load_json(path, _label(path), InputError)



def fill_holes(mask: np.ndarray) -> np.ndarray:
    """Background regions (4-connected) not reaching the image border become object."""
    import cv2

    bg = (~np.asarray(mask, bool)).astype(np.uint8)
    n, labels = cv2.connectedComponents(bg, connectivity=4)
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    keep = np.zeros(n, bool)
    keep[border] = True
    keep[0] = True  # label 0 is the object itself
    return np.asarray(mask, bool) | ~keep[labels]
