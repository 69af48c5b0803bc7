"""Capture folders (CONTRACT): read and write one trigger of the rig.

Layout (see ``docs/architecture.md``, "Capture folder")::

    <capture>/
      rig.json              the cameras
      images/<name>.png     one image per camera, 8- or 16-bit, grey or colour
      background/<name>.png optional: the empty rig, for background subtraction
      capture.json          optional: {"part_id", "timestamp", "polarity", extra keys...}
      truth/                optional (simulator only): part.ply, truth.json

Outside programs write these folders, so :func:`read_capture` trusts nothing: it checks
the whole folder before it returns, and every problem becomes a
:class:`~inspector.errors.CaptureError` whose one-line message names the file, the camera
or the key (``"rig.json: camera cam03: R is not a rotation matrix (det=-1)"``,
``"images/cam02.png: size 1000x1024, rig.json says 1024x1024"``). No json, numpy or cv2
exception escapes.

Nothing is decoded before it passes the input bounds (:mod:`inspector.limits`): JSON files
are measured before they are parsed; a camera may declare at most ``INSPECTOR_MAX_IMAGE_PIXELS``
pixels and a rig ``INSPECTOR_MAX_CAPTURE_PIXELS`` together; an image file is measured before
it is read (at most :func:`~inspector.limits.image_file_bytes` of its camera's size) and its
PNG header (:func:`png_header`) must declare the camera's size and a valid bit depth and
colour type. An image that is a link, or lies behind one, leading out of the capture folder
is refused (``"images/cam03.png: camera cam03's image is a link to /x/other/images/cam03.png,
outside the capture folder ..."``): another capture's image would be inspected as this one's.

What :func:`read_capture` returns
---------------------------------
- ``Capture.rig``: cameras in the order of ``rig.json``, in mm (``"units": "m"`` multiplies
  ``t`` by 1000; ``K`` is in pixels and ``dist`` is unitless, both unchanged). ``dist``
  is always 5 values ``[k1, k2, p1, p2, k3]``: absent or ``null`` -> zeros, 4 values ->
  ``k3 = 0`` appended; longer OpenCV vectors (8, 12 or 14 values) are accepted only when
  the extra coefficients are all zero.
- ``Capture.images`` / ``Capture.backgrounds``: camera name -> array, in rig order, as
  stored in the file: ``uint8`` or ``uint16``; grey is ``(H, W)``; colour is **RGB**
  ``(H, W, 3)`` or **RGBA** ``(H, W, 4)`` (cv2's BGR order is converted on read and back
  on write, so downstream code is library-neutral). No conversion to grey or to float:
  that is the segment stage's job. Arrays are read-only. Backgrounds may cover only some
  cameras.
- ``Capture.polarity``: from ``capture.json``, default ``"dark-object"``.
- ``Capture.metadata``: every key of ``capture.json`` except ``polarity`` (so
  ``part_id``, ``timestamp`` and any extra keys).
- ``Capture.truth``: ``None`` without ``truth/``; else ``Truth(mesh_path=truth/part.ply
  or None, info=<truth.json or {}>)``. The mesh is not loaded here.
- ``Capture.name`` is the folder's name, ``Capture.source`` its path.

:func:`write_capture` writes the same layout (rig.json in mm, lossless PNG) and writes
``rig.json`` last, so a hot-folder watcher that waits for ``rig.json``
(:func:`is_capture_folder`) never sees a half-written capture.

The PNG format's own checks (:func:`png_header`, :func:`is_complete_png`) are
:mod:`inspector.png`'s, also importable from here.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from inspector.errors import CaptureError
from inspector.jsonio import json_default
from inspector.kernels.camera import is_rotation
from inspector.limits import check_memory, image_file_bytes, limit, load_json, read_bounded
from inspector.model import Camera, Capture, Rig, Truth
from inspector.names import check_name, folder_name, name_problem, printable, text_problem
from inspector.png import PNG_IEND, PNG_SIGNATURE, decode_grey, is_complete_png, png_header
from inspector.registry import Acquisition

if TYPE_CHECKING:  # pragma: no cover
    import trimesh

__all__ = [
    "RIG_FILE",
    "CAPTURE_FILE",
    "IMAGES_DIR",
    "BACKGROUND_DIR",
    "TRUTH_DIR",
    "POLARITIES",
    "ROTATION_TOL",
    "read_rig",
    "parse_rig",
    "read_capture",
    "write_capture",
    "is_capture_folder",
    "to_rgb_order",
    "decode_image",
    "png_header",
    "is_complete_png",
    "save_capture",
]

RIG_FILE = "rig.json"
CAPTURE_FILE = "capture.json"
IMAGES_DIR = "images"
BACKGROUND_DIR = "background"
TRUTH_DIR = "truth"
TRUTH_MESH = "part.ply"
TRUTH_INFO = "truth.json"
POLARITIES = ("dark-object", "bright-object")
DEFAULT_POLARITY = "dark-object"
#: Tolerance on ``R @ R.T == I`` and ``det(R) == 1`` for a camera rotation.
ROTATION_TOL = 1e-4

_UNIT_SCALE = {"mm": 1.0, "m": 1000.0}
_CAMERA_KEYS = ("name", "width", "height", "K", "R", "t")
_BAD_NAME = re.compile(r"[/\\\x00-\x1f]")


# --------------------------------------------------------------------------- helpers


def _fmt(x: float) -> str:
    return f"{x:.6g}"


class _DuplicateKey(Exception):
    def __init__(self, key: str) -> None:
        self.key = key


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(k)
        out[k] = v
    return out


def _load_json(path: Path, label: str) -> Any:
    """Parse a JSON file within the input bounds (size and nesting depth checked before it
    is parsed, :mod:`inspector.limits`); every failure is a CaptureError naming ``label``."""
    try:
        return load_json(path, label, CaptureError, object_pairs_hook=_no_duplicates)
    except _DuplicateKey as exc:
        raise CaptureError(f"{label}: duplicate key {exc.key!r}") from None


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _numbers(value: Any, where: str, key: str, shapes: tuple[tuple[int, ...], ...]) -> np.ndarray:
    """A nested list of JSON numbers with one of ``shapes`` -> float array (finite)."""

    def walk(v: Any) -> bool:
        if isinstance(v, list):
            return all(walk(x) for x in v)
        return _is_number(v)

    want = " or ".join("x".join(map(str, s)) if s else "a number" for s in shapes)
    if not isinstance(value, list) or not walk(value):
        raise CaptureError(f"{where}: {key} must be a list of numbers ({want})")
    try:
        arr = np.array(value, dtype=float)
    except (ValueError, OverflowError):
        raise CaptureError(f"{where}: {key} must be {want} numbers (ragged list)") from None
    if arr.shape not in shapes:
        raise CaptureError(f"{where}: {key} has shape {'x'.join(map(str, arr.shape)) or '()'}, expected {want}")
    if not np.all(np.isfinite(arr)):
        raise CaptureError(f"{where}: {key} has non-finite values")
    return arr


def _positive_int(value: Any, where: str, key: str) -> int:
    if _is_number(value) and math.isfinite(value) and float(value) == int(value) and int(value) > 0:
        return int(value)
    raise CaptureError(f"{where}: {key} must be a positive integer, got {json.dumps(value)}")


def _check_name(name: Any, where: str) -> str:
    if not isinstance(name, str) or not name.strip():
        raise CaptureError(f"{where}: name must be a non-empty string, got {json.dumps(name)}")
    if _BAD_NAME.search(name) or name in (".", "..") or name != name.strip():
        raise CaptureError(f"{where}: name {name!r} cannot be used as a file name")
    return name


# --------------------------------------------------------------------------- rig.json


def _parse_dist(value: Any, where: str) -> np.ndarray:
    if value is None:
        return np.zeros(5)
    d = _numbers(value, where, "dist", ((4,), (5,), (8,), (12,), (14,), (1, 4), (1, 5), (4, 1), (5, 1)))
    d = d.ravel()
    if d.size == 4:
        return np.concatenate([d, [0.0]])
    if d.size > 5 and np.any(d[5:]):
        raise CaptureError(
            f"{where}: dist has {d.size} coefficients with non-zero k4..; "
            "only [k1, k2, p1, p2, k3] is supported"
        )
    return d[:5].copy()


def _parse_camera(cam: Any, index: int, label: str, scale: float) -> Camera:
    where = f"{label}: cameras[{index}]"
    if not isinstance(cam, dict):
        raise CaptureError(f"{where}: must be an object, got {type(cam).__name__}")
    if "name" in cam:
        name = _check_name(cam["name"], where)
        where = f"{label}: camera {name}"
    for key in _CAMERA_KEYS:
        if key not in cam:
            raise CaptureError(f"{where}: missing key {key!r}")
    name = cam["name"]
    width = _positive_int(cam["width"], where, "width")
    height = _positive_int(cam["height"], where, "height")
    most = limit("MAX_IMAGE_PIXELS")
    if width * height > most:  # before any image is read: its decoded size follows from this
        raise CaptureError(f"{where}: {width}x{height} is {width * height} pixels, more than the {most} "
                           "a camera may have (INSPECTOR_MAX_IMAGE_PIXELS)")
    K = _numbers(cam["K"], where, "K", ((3, 3),))
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise CaptureError(f"{where}: K has fx={_fmt(K[0, 0])}, fy={_fmt(K[1, 1])}; both must be > 0")
    if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or not math.isclose(K[2, 2], 1.0, abs_tol=1e-9):
        raise CaptureError(f"{where}: K must have the form [[fx, s, cx], [0, fy, cy], [0, 0, 1]]")
    R = _numbers(cam["R"], where, "R", ((3, 3),))
    with np.errstate(over="ignore", invalid="ignore"):
        if not is_rotation(R, tol=ROTATION_TOL):
            err = float(np.max(np.abs(R @ R.T - np.eye(3))))
            raise CaptureError(
                f"{where}: R is not a rotation matrix (det={_fmt(float(np.linalg.det(R)))}, "
                f"max|R R^T - I|={err:.2g}, tolerance {ROTATION_TOL:g})"
            )
        t = _numbers(cam["t"], where, "t", ((3,), (3, 1), (1, 3))).ravel() * scale
    if not np.all(np.isfinite(t)):
        raise CaptureError(f"{where}: t is too large once converted to mm")
    dist = _parse_dist(cam.get("dist"), where)
    return Camera(name=name, width=width, height=height, K=K, dist=dist, R=R, t=t)


def parse_rig(data: Any, label: str = RIG_FILE) -> Rig:
    """Validate the parsed content of a ``rig.json`` and build the :class:`Rig` (mm).

    Raises :class:`CaptureError` with a message starting with ``label``.
    """
    if not isinstance(data, dict):
        raise CaptureError(f"{label}: must be a JSON object, got {type(data).__name__}")
    if "units" not in data:
        raise CaptureError(f'{label}: missing key "units" ("mm" or "m")')
    units = data["units"]
    if not isinstance(units, str) or units not in _UNIT_SCALE:
        raise CaptureError(f'{label}: units must be "mm" or "m", got {json.dumps(units)}')
    cams = data.get("cameras")
    if cams is None:
        raise CaptureError(f'{label}: missing key "cameras"')
    if not isinstance(cams, list):
        raise CaptureError(f"{label}: cameras must be a list, got {type(cams).__name__}")
    if not cams:
        raise CaptureError(f"{label}: cameras is empty")
    # Counted before any camera is built: a rig of 10^6 cameras took minutes and GBs to refuse.
    most = limit("MAX_CAMERAS")
    if len(cams) > most:
        raise CaptureError(f"{label}: {len(cams)} cameras, more than the {most} a rig may have (INSPECTOR_MAX_CAMERAS)")
    cameras = [_parse_camera(c, i, label, _UNIT_SCALE[units]) for i, c in enumerate(cams)]
    total, most = sum(c.width * c.height for c in cameras), limit("MAX_CAPTURE_PIXELS")
    if total > most:
        raise CaptureError(f"{label}: its {len(cameras)} cameras have {total} pixels together, more than the "
                           f"{most} a capture may have (INSPECTOR_MAX_CAPTURE_PIXELS)")
    check_memory(label, len(cameras), total, CaptureError)
    seen: dict[str, int] = {}
    for i, c in enumerate(cameras):
        if c.name in seen:
            raise CaptureError(f"{label}: duplicate camera name {c.name!r} (cameras[{seen[c.name]}] and cameras[{i}])")
        seen[c.name] = i
    return Rig(tuple(cameras))


def read_rig(path: str | os.PathLike[str]) -> Rig:
    """Read and validate a ``rig.json`` file; lengths converted to mm.

    Messages start with the file's name (``"rig.json: camera cam03: ..."``).
    """
    path = Path(path)
    label = path.name or str(path)
    if not path.exists():
        raise CaptureError(f"{label}: missing ({path})")
    if not path.is_file():
        raise CaptureError(f"{label}: not a file ({path})")
    return parse_rig(_load_json(path, label), label)


# --------------------------------------------------------------------------- capture.json, truth/


def _parse_capture_json(folder: Path) -> tuple[str, dict[str, Any]]:
    path = folder / CAPTURE_FILE
    if not path.exists():
        return DEFAULT_POLARITY, {}
    if not path.is_file():
        raise CaptureError(f"{CAPTURE_FILE}: not a file")
    data = _load_json(path, CAPTURE_FILE)
    if not isinstance(data, dict):
        raise CaptureError(f"{CAPTURE_FILE}: must be a JSON object, got {type(data).__name__}")
    polarity = data.get("polarity")
    if polarity is None:
        polarity = DEFAULT_POLARITY
    elif polarity not in POLARITIES:
        raise CaptureError(
            f'{CAPTURE_FILE}: polarity must be "dark-object" or "bright-object", got {json.dumps(polarity)}'
        )
    part_id = data.get("part_id")
    if part_id is not None and not isinstance(part_id, str):
        raise CaptureError(f"{CAPTURE_FILE}: part_id must be a string, got {json.dumps(part_id)}")
    for key, value in data.items():
        why = text_problem(key) or text_problem(value)
        if why is not None:
            raise CaptureError(f"{CAPTURE_FILE}: {printable(key)} {why}")
    ts = data.get("timestamp")
    if ts is not None:
        ok = isinstance(ts, str)
        if ok:
            try:
                datetime.fromisoformat(ts)
            except ValueError:
                ok = False
        if not ok:
            raise CaptureError(f"{CAPTURE_FILE}: timestamp must be an ISO-8601 string, got {json.dumps(ts)}")
    metadata = {k: v for k, v in data.items() if k != "polarity"}
    return polarity, metadata


def _parse_truth(folder: Path) -> Truth | None:
    tdir = folder / TRUTH_DIR
    if not tdir.exists():
        return None
    if not tdir.is_dir():
        raise CaptureError(f"{TRUTH_DIR}: not a folder")
    mesh = tdir / TRUTH_MESH
    info_path = tdir / TRUTH_INFO
    info: dict[str, Any] = {}
    label = f"{TRUTH_DIR}/{TRUTH_INFO}"
    if info_path.exists():
        if not info_path.is_file():
            raise CaptureError(f"{label}: not a file")
        data = _load_json(info_path, label)
        if not isinstance(data, dict):
            raise CaptureError(f"{label}: must be a JSON object, got {type(data).__name__}")
        info = data
    return Truth(mesh_path=mesh if mesh.is_file() else None, info=info)


# --------------------------------------------------------------------------- images


def _list_pngs(folder: Path, sub: str, rig: Rig) -> dict[str, Path]:
    """``sub/<name>.png`` files -> {camera: path}; unknown cameras are an error."""
    d = folder / sub
    if not d.exists():
        return {}
    if not d.is_dir():
        raise CaptureError(f"{sub}: not a folder")
    known = set(rig.names)
    found: dict[str, Path] = {}
    try:
        entries = sorted(d.iterdir())
    except OSError as exc:
        raise CaptureError(f"{sub}: cannot be listed ({exc.strerror or exc})") from None
    for p in entries:
        if p.name.startswith(".") or p.suffix.lower() != ".png":
            continue  # hidden files, thumbnails, notes...
        if p.suffix != ".png":
            raise CaptureError(f"{sub}/{p.name}: extension must be lower-case .png")
        stem = p.stem
        if stem not in known:
            raise CaptureError(f"{sub}/{p.name}: camera {stem} is not in {RIG_FILE}")
        found[stem] = p
    return found


def _inside(path: Path, root: str, label: str, camera: str) -> None:
    """Refuse an image that is, or lies behind, a link leading out of the capture folder
    ``root`` (resolved): another capture's image would be inspected as this camera's."""
    real = os.path.realpath(path)
    if os.path.commonpath([real, root]) != root:
        raise CaptureError(f"{label}: camera {camera}'s image is a link to {real}, outside the capture folder "
                           "(copy the file into the capture)")


def decode_image(
    path: Path,
    label: str,
    error: type[Exception] = CaptureError,
    *,
    png_only: bool = True,
    size: tuple[int, int] | None = None,
    camera: str | None = None,
) -> np.ndarray:
    """Read and decode one image file strictly; raises ``error`` naming ``label``.

    Returns cv2's array (BGR order, any dtype): callers check the pixel type.

    Nothing is decoded before the file passes the input bounds (:mod:`inspector.limits`): its
    size is measured before it is read (at most :func:`~inspector.limits.image_file_bytes`
    of ``size``, the ``(width, height)`` a rig declares for it, or of the largest image
    allowed), and a PNG's header (:func:`png_header`) must declare exactly ``size`` (else at
    most ``INSPECTOR_MAX_IMAGE_PIXELS`` pixels) with a valid bit depth and colour type
    (``camera``: the camera the message names). A PNG
    must be complete (cv2 may return a partly decoded image for a cut file, so any PNG whose
    IEND chunk, the last chunk of every complete PNG, is missing is refused).
    """
    import cv2

    if not path.is_file():
        raise error(f"{label}: {'missing image' if not path.exists() else 'not a file'}")
    if size is not None:
        most, what = image_file_bytes(*size), f"a {size[0]}x{size[1]} image"
    else:
        most, what = image_file_bytes(limit("MAX_IMAGE_PIXELS"), 1), "an image"
    data = read_bounded(path, label, most, error, what=what, variable="INSPECTOR_MAX_IMAGE_METADATA_BYTES")
    if not data:
        raise error(f"{label}: empty file")
    is_png = data.startswith(PNG_SIGNATURE)
    if png_only and not is_png:
        raise error(f"{label}: not a PNG file")
    if is_png:
        width, height, _, _ = png_header(data, label, error)
        if size is not None and (width, height) != tuple(size):
            for_camera = f" for camera {camera}" if camera else ""
            raise error(f"{label}: size {width}x{height}, {RIG_FILE} says {size[0]}x{size[1]}{for_camera}")
        most = limit("MAX_IMAGE_PIXELS")
        if size is None and width * height > most:
            raise error(f"{label}: {width}x{height} is {width * height} pixels, more than the {most} "
                        "an image may have (INSPECTOR_MAX_IMAGE_PIXELS)")
        if data.rfind(PNG_IEND, max(0, len(data) - 1024)) < 0:
            raise error(f"{label}: truncated PNG (no IEND chunk)")
    img = decode_grey(data) if is_png else None  # the camera's grey PNGs without OpenCV's slower inflate
    if img is None:
        try:
            img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        except cv2.error:
            img = None
    if img is None:
        raise error(f"{label}: unreadable {'PNG (corrupt data)' if png_only else 'image (corrupt or unknown format)'}")
    return img


def _decode_png(path: Path, label: str, cam: Camera, root: str) -> np.ndarray:
    """Read one PNG strictly; returns uint8/uint16 grey (H, W), RGB or RGBA. Read-only."""
    _inside(path, root, label, cam.name)
    img = decode_image(path, label, size=(cam.width, cam.height), camera=cam.name)
    if img.dtype not in (np.uint8, np.uint16):
        raise CaptureError(f"{label}: unsupported pixel type {img.dtype}, expected 8- or 16-bit")
    h, w = img.shape[:2]
    if (w, h) != (cam.width, cam.height):
        raise CaptureError(f"{label}: size {w}x{h}, {RIG_FILE} says {cam.width}x{cam.height} for camera {cam.name}")
    img = to_rgb_order(img, label, CaptureError)
    img.setflags(write=False)
    return img


def _decode_all(jobs: list[tuple[Path, str, Camera, str]]) -> list[np.ndarray]:
    """Decode in a small thread pool (cv2 releases the GIL); first error in job order."""
    if not jobs:
        return []
    workers = min(len(jobs), 8, os.cpu_count() or 1)
    if workers <= 1:
        return [_decode_png(*j) for j in jobs]
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="capture-read") as pool:
        futures = [pool.submit(_decode_png, *j) for j in jobs]
        return [f.result() for f in futures]  # re-raises the first CaptureError in order


# --------------------------------------------------------------------------- public API


def is_capture_folder(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` is a folder holding a ``rig.json`` file (cheap, never raises)."""
    try:
        return (Path(path) / RIG_FILE).is_file()
    except (OSError, TypeError, ValueError):
        return False


def read_capture(folder: str | os.PathLike[str]) -> Capture:
    """Read and validate a capture folder (CONTRACT layout); see the module docstring.

    Everything is checked before anything is returned; any problem raises
    :class:`CaptureError` with a one-line message naming the file, camera or key.
    """
    try:
        folder = Path(folder)
    except TypeError:
        raise CaptureError(f"capture folder must be a path, got {type(folder).__name__}") from None
    if not folder.exists():
        raise CaptureError(f"capture folder {folder}: does not exist")
    if not folder.is_dir():
        raise CaptureError(f"capture folder {folder}: not a directory")
    rig_path = folder / RIG_FILE
    if not rig_path.exists():
        raise CaptureError(f"{RIG_FILE}: missing in capture folder {folder}")
    if not rig_path.is_file():
        raise CaptureError(f"{RIG_FILE}: not a file")
    rig = parse_rig(_load_json(rig_path, RIG_FILE), RIG_FILE)

    polarity, metadata = _parse_capture_json(folder)

    if not (folder / IMAGES_DIR).exists():
        raise CaptureError(f"{IMAGES_DIR}: folder missing (one {IMAGES_DIR}/<camera>.png per camera)")
    image_files = _list_pngs(folder, IMAGES_DIR, rig)
    for name in rig.names:
        if name not in image_files:
            raise CaptureError(f"camera {name} has no image ({IMAGES_DIR}/{name}.png)")
    bg_files = _list_pngs(folder, BACKGROUND_DIR, rig)
    truth = _parse_truth(folder)

    root = os.path.realpath(folder)  # every image must lie in it, links resolved
    jobs = [(image_files[c.name], f"{IMAGES_DIR}/{c.name}.png", c, root) for c in rig]
    jobs += [(bg_files[c.name], f"{BACKGROUND_DIR}/{c.name}.png", c, root) for c in rig if c.name in bg_files]
    arrays = _decode_all(jobs)
    n = len(rig)
    images = dict(zip(rig.names, arrays[:n]))
    bg_names = [c.name for c in rig if c.name in bg_files]
    backgrounds = dict(zip(bg_names, arrays[n:]))

    return Capture(
        name=Path(os.path.abspath(folder)).name or str(folder),  # no symlink resolution
        rig=rig,
        images=images,
        backgrounds=backgrounds,
        polarity=polarity,
        metadata=metadata,
        source=folder,
        truth=truth,
    )


def _write_bytes_atomic(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def _write_json(path: Path, data: Any) -> None:
    text = json.dumps(data, indent=2, default=json_default, allow_nan=False)
    _write_bytes_atomic(path, (text + "\n").encode("utf-8"))


def _encode_png(img: Any, cam: Camera, what: str) -> bytes:
    import cv2

    a = np.asarray(img)
    if a.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"{what}: dtype {a.dtype}, expected uint8 or uint16")
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] in (3, 4))):
        raise ValueError(f"{what}: shape {a.shape}, expected (H, W), (H, W, 3) RGB or (H, W, 4) RGBA")
    if a.shape[:2] != (cam.height, cam.width):
        raise ValueError(f"{what}: size {a.shape[1]}x{a.shape[0]}, camera says {cam.width}x{cam.height}")
    if a.ndim == 3:
        a = cv2.cvtColor(np.ascontiguousarray(a), cv2.COLOR_RGB2BGR if a.shape[2] == 3 else cv2.COLOR_RGBA2BGRA)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(a))
    if not ok:  # pragma: no cover - cv2 encodes any uint8/uint16 array above
        raise ValueError(f"{what}: PNG encoding failed")
    return buf.tobytes()


def _encode_pngs(sub: str, rig: Rig, arrays: Mapping[str, Any], *, complete: bool) -> dict[str, bytes]:
    """Check and encode ``{camera: array}`` -> ``{camera: PNG bytes}`` (rig order)."""
    unknown = sorted(str(k) for k in set(arrays) - set(rig.names))
    if unknown:
        raise ValueError(f"{sub}: cameras {unknown} are not in the rig")
    if complete:
        missing = [n for n in rig.names if n not in arrays]
        if missing:
            raise ValueError(f"{sub}: no image for cameras {missing}")
    return {c.name: _encode_png(arrays[c.name], c, f"{sub}/{c.name}.png") for c in rig if c.name in arrays}


def write_capture(
    folder: str | os.PathLike[str],
    rig: Rig,
    images: Mapping[str, np.ndarray],
    *,
    backgrounds: Mapping[str, np.ndarray] | None = None,
    metadata: Mapping[str, Any] | None = None,
    polarity: str | None = None,
    truth_mesh: trimesh.Trimesh | None = None,
    truth_info: Mapping[str, Any] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write a capture folder in the CONTRACT layout and return its path.

    Parameters
    ----------
    folder
        Created with its parents. It must be absent or empty unless ``overwrite``;
        with ``overwrite`` the capture entries (rig.json, capture.json, images/,
        background/, truth/) are replaced and other files are left alone.
    rig
        Written as ``rig.json`` in mm (``K``, ``dist``, ``R``, ``t`` as lists).
    images
        One array per camera of the rig: uint8/uint16, ``(H, W)`` grey, ``(H, W, 3)`` RGB
        or ``(H, W, 4)`` RGBA, of the camera's size. Written as lossless PNG.
    backgrounds
        Optional, for any subset of the cameras; same rules.
    metadata, polarity
        ``capture.json`` is ``{"polarity": polarity, **metadata}``, written when either
        is given (``polarity`` may also come in ``metadata``).
    truth_mesh, truth_info
        ``truth/part.ply`` (trimesh export, world mm) and ``truth/truth.json`` (numpy
        arrays and scalars converted to JSON).

    Raises ``ValueError`` for invalid arguments (nothing is written then) and
    ``FileExistsError`` for a non-empty folder without ``overwrite``. ``rig.json`` is
    written last, so :func:`is_capture_folder` is true only for a complete folder.
    """
    import shutil

    folder = Path(folder)
    # Validate everything before writing anything.
    try:
        rig_json = rig.to_json()
        parse_rig(rig_json, "rig")
    except CaptureError as exc:
        raise ValueError(str(exc)) from None
    meta = dict(metadata or {})
    if polarity is not None:
        if "polarity" in meta and meta["polarity"] != polarity:
            raise ValueError(f"polarity {polarity!r} contradicts metadata polarity {meta['polarity']!r}")
        meta["polarity"] = polarity
    if "polarity" in meta and meta["polarity"] not in POLARITIES:
        raise ValueError(f"polarity must be one of {POLARITIES}, got {meta['polarity']!r}")
    capture_text = json.dumps(meta, indent=2, default=json_default, allow_nan=False) if meta else None
    info_text = (
        json.dumps(dict(truth_info), indent=2, default=json_default, allow_nan=False)
        if truth_info is not None
        else None
    )
    encoded_images = _encode_pngs(IMAGES_DIR, rig, images, complete=True)
    encoded_bgs = _encode_pngs(BACKGROUND_DIR, rig, backgrounds or {}, complete=False)

    if folder.exists():
        if not folder.is_dir():
            raise FileExistsError(f"{folder}: exists and is not a folder")
        if any(folder.iterdir()):
            if not overwrite:
                raise FileExistsError(f"{folder}: folder is not empty (pass overwrite=True)")
            for entry in (RIG_FILE, CAPTURE_FILE):
                (folder / entry).unlink(missing_ok=True)
            for entry in (IMAGES_DIR, BACKGROUND_DIR, TRUTH_DIR):
                p = folder / entry
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p)
                elif p.exists() or p.is_symlink():
                    p.unlink()
    folder.mkdir(parents=True, exist_ok=True)

    for sub, encoded in ((IMAGES_DIR, encoded_images), (BACKGROUND_DIR, encoded_bgs)):
        if encoded:
            (folder / sub).mkdir(exist_ok=True)
            for name, data in encoded.items():
                _write_bytes_atomic(folder / sub / f"{name}.png", data)
    if capture_text is not None:
        _write_bytes_atomic(folder / CAPTURE_FILE, (capture_text + "\n").encode("utf-8"))
    if truth_mesh is not None or info_text is not None:
        tdir = folder / TRUTH_DIR
        tdir.mkdir(exist_ok=True)
        if truth_mesh is not None:
            truth_mesh.export(str(tdir / TRUTH_MESH), file_type="ply")
        if info_text is not None:
            _write_bytes_atomic(tdir / TRUTH_INFO, (info_text + "\n").encode("utf-8"))
    _write_json(folder / RIG_FILE, rig_json)
    return folder



def to_rgb_order(img: np.ndarray, label: str, error: type[Exception] = CaptureError) -> np.ndarray:
    """A decoded OpenCV image (H, W[, C]) in library-neutral order: grey, RGB or RGBA.

    Raises ``error`` naming ``label`` for a channel count other than 1, 3 or 4.
    """
    import cv2

    if img.ndim == 3:
        c = img.shape[2]
        if c == 1:
            img = img[:, :, 0]
        elif c == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        elif c == 4:
            img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA)
        else:
            raise error(f"{label}: unsupported number of channels {c}")
    return np.ascontiguousarray(img)


def save_capture(capture: Capture, folder: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write an in-memory :class:`Capture` (from any driver) as a CONTRACT capture folder,
    with its backgrounds, metadata, polarity and, when it has one, its ``truth/``."""
    truth_mesh = truth_info = None
    if capture.truth is not None:
        truth_info = dict(capture.truth.info)
        arrays = capture.truth.mesh_arrays()
        if arrays is not None:
            import trimesh

            truth_mesh = trimesh.Trimesh(arrays[0], arrays[1], process=False)
    meta = {k: v for k, v in dict(capture.metadata).items() if k != "polarity"}
    return write_capture(
        folder,
        capture.rig,
        capture.images,
        backgrounds=dict(capture.backgrounds) or None,
        metadata=meta,
        polarity=capture.polarity,
        truth_mesh=truth_mesh,
        truth_info=truth_info,
        overwrite=overwrite,
    )


# --------------------------------------------------------------------------- folders as acquisitions


def expand(paths: tuple[str, ...] | list[str]) -> list[Path]:
    """Capture folders named by ``paths`` (folders of captures are expanded, sorted)."""
    out: list[Path] = []
    for raw in paths:
        p = Path(raw)
        if p.is_dir() and not is_capture_folder(p):
            subs = sorted(q for q in p.iterdir() if q.is_dir() and is_capture_folder(q))
            if subs:
                out.extend(subs)
                continue
        out.append(p)
    return out


def named_acquisition(folder: Path, read: Callable[[Path], Capture]) -> Acquisition:
    """The acquisition of capture folder ``folder``, named once for every driver that reads
    folders (replay, hotfolder): after the folder, or refused when that name cannot name a
    result folder. A refused one keeps a printable name (control characters escaped, so
    never a valid one: no result folder is written for it) and fails to load with the reason.
    """
    name = folder_name(folder)
    if name_problem(name) is None:
        return Acquisition(name, lambda: read(folder))
    shown = printable(name or str(folder))

    def refuse() -> Capture:
        check_name(name)
        raise AssertionError("unreachable")  # pragma: no cover

    return Acquisition(shown, refuse)
