"""Bounds on what an input file may ask of the program, checked before it is parsed or built.

Capture folders, hot-folder drops, reference meshes and dataset files are written by other
programs, so their size must not decide how much memory or time a read takes: a JSON file is
measured before it is read, its nesting depth before it is parsed, a rig's camera count and
image sizes before any camera is built, a PNG's header and file size before it is decoded,
and a reference mesh's size before it is parsed. Each bound is a documented default that an
environment variable overrides:

==========================  ================================  ========================================
bound                       default                           environment variable
==========================  ================================  ========================================
JSON input file size        16 MiB (a 256-camera rig.json     ``INSPECTOR_MAX_JSON_BYTES``
                            is about 0.2 MB)
JSON nesting depth          64 levels (rig.json needs 5)      ``INSPECTOR_MAX_JSON_DEPTH``
cameras in one rig          1024 (the full Middlebury         ``INSPECTOR_MAX_CAMERAS``
                            temple and dino sets: 312, 363)
pixels of one camera        2**26 (64 Mpx, 8192 x 8192)       ``INSPECTOR_MAX_IMAGE_PIXELS``
pixels of one capture       2**30 (sixteen 64-Mpx cameras)    ``INSPECTOR_MAX_CAPTURE_PIXELS``
PNG bytes beyond its        16 MiB (ICC profile, EXIF, text   ``INSPECTOR_MAX_IMAGE_METADATA_BYTES``
largest pixel data          chunks)
reference mesh triangles    1 000 000 (about 2.5 GB and two   ``INSPECTOR_MAX_REFERENCE_TRIANGLES``
                            minutes to load and index)
reference mesh file size    512 MiB (an ASCII STL of a        ``INSPECTOR_MAX_REFERENCE_BYTES``
                            million triangles: about 250 MB)
==========================  ================================  ========================================

Images are bounded by the rig: a camera declares its width and height in ``rig.json``
(within the pixel bounds above), an image's PNG header must declare exactly that size and a
valid bit depth and colour type (8 or 16 bits; grey, grey + alpha, RGB, RGBA or palette),
and its file may be at most :func:`image_file_bytes` of that size (the pixel data of a
16-bit RGBA image stored uncompressed, plus the metadata allowance), all checked before a
byte of pixel data is decoded: a small file declaring 30000 x 30000 pixels, or a link to a
3 GiB file, costs nothing to refuse.

A capture must also fit in memory: before a capture's images are read, :func:`check_memory`
estimates what inspecting it will take from its cameras' sizes (:func:`inspection_bytes`, a
model measured on the default recipe) and refuses, in one line, a capture that needs more than
the machine's memory budget (:func:`memory_budget`: half the physical memory, or of the
cgroup's limit when lower; ``INSPECTOR_MEMORY_BUDGET_MB`` sets it). The pixel bounds above
are a hard cap; the budget is what a cell PC of 8-16 GB can actually hold (16 x 8192² is
within the pixel bound and needs about 16.5 GB).

Every refusal is one line naming the file and the variable that raises the bound.
"""

from __future__ import annotations

import json
import os
import stat
from collections.abc import Callable
from typing import Any

from inspector.errors import InputError

__all__ = [
    "MAX_JSON_BYTES",
    "MAX_JSON_DEPTH",
    "MAX_CAMERAS",
    "MAX_IMAGE_PIXELS",
    "MAX_CAPTURE_PIXELS",
    "MAX_IMAGE_METADATA_BYTES",
    "MAX_REFERENCE_TRIANGLES",
    "MAX_REFERENCE_BYTES",
    "limit",
    "memory_budget",
    "inspection_bytes",
    "check_memory",
    "read_bounded",
    "image_file_bytes",
    "json_depth",
    "load_json",
]

#: Largest JSON input file, bytes.
MAX_JSON_BYTES = 16 * 2**20
#: Deepest nesting of arrays and objects in a JSON input file. Deeper documents parse, but
#: every recursive walk of them later (result.json, history metadata) risks RecursionError.
MAX_JSON_DEPTH = 64
#: Most cameras in one rig.json (a rig.json of 10^6 cameras took minutes and over 2 GB to refuse).
MAX_CAMERAS = 1024

#: Most pixels one camera may declare (a 30000 x 30000 PNG once took 15.6 GB to refuse).
MAX_IMAGE_PIXELS = 2**26
#: Most pixels of all the cameras of one rig together (what a capture's images hold in memory).
MAX_CAPTURE_PIXELS = 2**30
#: Bytes a PNG file may hold beyond its largest possible pixel data (metadata chunks).
MAX_IMAGE_METADATA_BYTES = 16 * 2**20
#: Most triangles of a reference mesh: 330k took 29 s and 1 GB to load and index here, 5.24M once
#: took 8.9 GB and 233 s (unwarned); a million is about 2.5 GB and two minutes.
MAX_REFERENCE_TRIANGLES = 1_000_000
#: Largest reference mesh file (an ASCII STL of a million triangles is about 250 MB).
MAX_REFERENCE_BYTES = 512 * 2**20

_DEFAULTS = {
    "MAX_JSON_BYTES": MAX_JSON_BYTES,
    "MAX_JSON_DEPTH": MAX_JSON_DEPTH,
    "MAX_CAMERAS": MAX_CAMERAS,
    "MAX_IMAGE_PIXELS": MAX_IMAGE_PIXELS,
    "MAX_CAPTURE_PIXELS": MAX_CAPTURE_PIXELS,
    "MAX_IMAGE_METADATA_BYTES": MAX_IMAGE_METADATA_BYTES,
    "MAX_REFERENCE_TRIANGLES": MAX_REFERENCE_TRIANGLES,
    "MAX_REFERENCE_BYTES": MAX_REFERENCE_BYTES,
}


def limit(name: str) -> int:
    """The bound ``name`` (``"MAX_CAMERAS"``...): ``$INSPECTOR_<name>`` when set, else the default.

    Read at each call, so a long-running watcher or a test can change it.

    Raises
    ------
    InputError
        The environment variable is set to something other than a positive integer.
    """
    var = f"INSPECTOR_{name}"
    raw = os.environ.get(var, "").strip()
    if not raw:
        return _DEFAULTS[name]
    try:
        value = int(raw)
    except ValueError:
        value = 0
    if value < 1:
        raise InputError(f"${var}: expected a positive integer, got {raw!r}")
    return value


def image_file_bytes(width: int, height: int) -> int:
    """Largest file an image of ``width`` x ``height`` pixels may be, in bytes.

    The pixel data of the largest PNG of that size (16-bit RGBA, 8 bytes a pixel, plus a
    filter byte a row, 7 more for an interlaced one), stored uncompressed (deflate's stored
    blocks add 5 bytes in 65535: 1 % covers it and the chunk headers), plus
    ``INSPECTOR_MAX_IMAGE_METADATA_BYTES`` for metadata chunks. A 1024 x 1024 camera: 24.5 MiB.
    """
    raw = height * (8 * width + 8)
    return raw + raw // 100 + limit("MAX_IMAGE_METADATA_BYTES")


#: Memory model of one inspection with the default recipe, measured as the peak RSS of
#: ``inspector run`` on one simulated cube30 capture of 16 cameras (8-bit grey): 512² 516 MB,
#: 1024² 692 MB, 2048² 1416 MB -> 450 MB of program and reference plus 14.4 bytes a pixel,
#: rounded up. A colour or 16-bit image adds its decoded size beyond one byte a pixel.
INSPECTION_BASE_BYTES = 480 * 2**20
INSPECTION_BYTES_PER_PIXEL = 15


def inspection_bytes(pixels: int, bytes_per_pixel: int = 1) -> int:
    """Estimated peak memory of inspecting a capture of ``pixels`` pixels in all (bytes), whose
    images decode to ``bytes_per_pixel`` bytes a pixel (8-bit grey: 1; 16-bit RGB: 6)."""
    return INSPECTION_BASE_BYTES + pixels * (INSPECTION_BYTES_PER_PIXEL + max(0, bytes_per_pixel - 1))


def _physical_memory() -> int:
    """Bytes of memory this process may use: the physical memory, or the cgroup's limit."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        total = 8 * 2**30
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            with open(path) as f:
                text = f.read().strip()
        except OSError:
            continue
        if text.isdigit() and 0 < int(text) < total:
            total = int(text)
    return int(total)


def memory_budget() -> tuple[int, str]:
    """The memory one inspection may take, bytes, and where it comes from (for messages):
    ``INSPECTOR_MEMORY_BUDGET_MB`` when set, else half the memory of this machine (or of its
    cgroup's limit)."""
    raw = os.environ.get("INSPECTOR_MEMORY_BUDGET_MB", "").strip()
    if raw:
        try:
            mb = int(raw)
        except ValueError:
            mb = 0
        if mb < 1:
            raise InputError(f"$INSPECTOR_MEMORY_BUDGET_MB: expected a positive integer, got {raw!r}")
        return mb * 2**20, "INSPECTOR_MEMORY_BUDGET_MB"
    total = _physical_memory()
    return total // 2, f"half of this machine's {total / 2**30:.1f} GB; INSPECTOR_MEMORY_BUDGET_MB sets it"


def check_memory(label: str, cameras: int, pixels: int, error: type[Exception] = InputError,
                 bytes_per_pixel: int = 1) -> None:
    """Refuse (``error``, one line starting with ``label``) a capture of ``cameras`` cameras
    and ``pixels`` pixels whose inspection would need more than :func:`memory_budget`."""
    need = inspection_bytes(pixels, bytes_per_pixel)
    budget, where = memory_budget()
    if need > budget:
        raise error(f"{label}: its {cameras} cameras ({pixels} pixels) would need about {need / 2**30:.1f} GB to "
                    f"inspect, more than the memory budget of {budget / 2**30:.1f} GB ({where})")


def json_depth(raw: bytes) -> int:
    """Deepest nesting of arrays and objects in the JSON text ``raw`` (0 for a scalar).

    Brackets inside strings do not count. Linear in the size and vectorised (16 MiB of the
    worst input, brackets or quotes, in about a second), never recursive, so it can measure a
    document before :func:`json.loads`, whose recursion a deep one exhausts. On text that
    is not JSON (an unterminated string) the count is of no use, and the parser refuses it.
    """
    import numpy as np

    # Escaped backslashes, then escaped quotes (left to right, as JSON pairs them): every
    # quote left opens or closes a string, so a character is inside a string exactly when an
    # odd number of quotes precede it (uint8 running count: it wraps, its parity does not).
    text = raw.replace(b"\\\\", b"").replace(b'\\"', b"")
    a = np.frombuffer(text, np.uint8)
    outside = (np.cumsum(a == ord('"'), dtype=np.uint8) & 1) == 0
    opening = ((a == ord("[")) | (a == ord("{"))) & outside
    closing = ((a == ord("]")) | (a == ord("}"))) & outside
    keep = opening | closing
    if not keep.any():
        return 0
    steps = np.where(opening[keep], 1, -1).astype(np.int32)
    return int(np.cumsum(steps).max())


def _too_big(label: str, size: int, most: int, what: str, variable: str) -> str:
    return f"{label}: {size} bytes, more than the {most} {what} may have ({variable})"


def read_bounded(
    path: str | os.PathLike[str],
    label: str,
    most: int,
    error: type[Exception] = InputError,
    *,
    what: str = "an input file",
    variable: str = "",
) -> bytes:
    """The bytes of the regular file ``path``, measured before it is read and never read
    past ``most`` bytes (a link to a huge file costs nothing; a device or a FIFO is not a
    file, and opening one never blocks).

    Raises ``error`` with a one-line message starting with ``label``: not a file, cannot be
    read, or larger than ``most`` (naming ``what`` and the environment ``variable`` that
    raises the bound).
    """
    try:
        # Non-blocking: a FIFO named rig.json must not hang a watcher (refused below).
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
        with os.fdopen(fd, "rb") as f:
            st = os.fstat(f.fileno())
            if not stat.S_ISREG(st.st_mode):
                raise error(f"{label}: not a file")
            if st.st_size > most:
                raise error(_too_big(label, st.st_size, most, what, variable))
            # The size it has, plus a byte to see it grow: a read of ``most + 1`` bytes
            # reserves that much first (2 ms for a 2 MB image under a 16 MB bound, 0.5 ms so).
            want = st.st_size + 1
            raw = f.read(want)
            if len(raw) == want and want <= most:  # it grew since fstat: the rest, up to the bound
                raw += f.read(most + 1 - want)
    except OSError as exc:
        raise error(f"{label}: cannot be read ({exc.strerror or exc})") from None
    if len(raw) > most:  # grew while it was read
        raise error(_too_big(label, len(raw), most, what, variable))
    return raw


def load_json(
    path: str | os.PathLike[str],
    label: str,
    error: type[Exception] = InputError,
    *,
    object_pairs_hook: Callable[[list[tuple[str, Any]]], Any] | None = None,
    extra_depth: int = 0,
) -> Any:
    """Parse a JSON input file within the size and depth bounds.

    Parameters
    ----------
    path : path-like
        The file; it is measured before it is read, and never read past the bound (a link
        to a huge file costs nothing; a device or a FIFO is not a file).
    label : str
        How messages name the file (``"rig.json"``).
    error : exception class
        Raised, with a one-line message starting with ``label``, for every problem.
    object_pairs_hook : callable, optional
        Passed to :func:`json.loads`; what it raises propagates.
    extra_depth : int
        Levels allowed beyond ``MAX_JSON_DEPTH`` (a result.json nests capture.json's
        metadata two levels down).

    Returns
    -------
    Any
        The parsed document (``NaN`` and ``Infinity`` literals are accepted, as Python
        writes them; callers that need finite numbers check them).
    """
    raw = read_bounded(path, label, limit("MAX_JSON_BYTES"), error, what="a JSON input", variable="INSPECTOR_MAX_JSON_BYTES")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise error(f"{label}: not UTF-8 text (byte {exc.start})") from None
    deepest = limit("MAX_JSON_DEPTH") + extra_depth
    depth = json_depth(raw)
    if depth > deepest:
        raise error(f"{label}: nested {depth} levels deep, more than the {deepest} a JSON input may have (INSPECTOR_MAX_JSON_DEPTH)")
    try:
        return json.loads(text, object_pairs_hook=object_pairs_hook)
    except json.JSONDecodeError as exc:
        raise error(f"{label}: not valid JSON (line {exc.lineno} column {exc.colno}): {exc.msg}") from None
    except (ValueError, RecursionError) as exc:  # e.g. an integer of 5000 digits
        raise error(f"{label}: not valid JSON ({exc})") from None

