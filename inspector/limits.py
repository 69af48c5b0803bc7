"""Bounds on what an input file may ask of the program, checked before it is parsed or built.

Capture folders, hot-folder drops and dataset files are written by other programs, so their
size must not decide how much memory or time a read takes: a JSON file is measured before it
is read, its nesting depth before it is parsed, and a rig's camera count before any camera is
built. Each bound is a documented default that an environment variable overrides:

==========================  ================================  ============================
bound                       default                           environment variable
==========================  ================================  ============================
JSON input file size        16 MiB (a 256-camera rig.json     ``INSPECTOR_MAX_JSON_BYTES``
                            is about 0.2 MB)
JSON nesting depth          64 levels (rig.json needs 5)      ``INSPECTOR_MAX_JSON_DEPTH``
cameras in one rig          1024 (the full Middlebury         ``INSPECTOR_MAX_CAMERAS``
                            temple and dino sets: 312, 363)
==========================  ================================  ============================

Every refusal is one line naming the file and the variable that raises the bound.
"""

from __future__ import annotations

import json
import os
import stat
from collections.abc import Callable
from typing import Any

from inspector.errors import InputError

__all__ = ["MAX_JSON_BYTES", "MAX_JSON_DEPTH", "MAX_CAMERAS", "limit", "json_depth", "load_json"]

#: Largest JSON input file, bytes.
MAX_JSON_BYTES = 16 * 2**20
#: Deepest nesting of arrays and objects in a JSON input file. Deeper documents parse, but
#: every recursive walk of them later (result.json, history metadata) risks RecursionError.
MAX_JSON_DEPTH = 64
#: Most cameras in one rig.json (a rig.json of 10^6 cameras took minutes and over 2 GB to refuse).
MAX_CAMERAS = 1024

_DEFAULTS = {"MAX_JSON_BYTES": MAX_JSON_BYTES, "MAX_JSON_DEPTH": MAX_JSON_DEPTH, "MAX_CAMERAS": MAX_CAMERAS}


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


def _too_big(label: str, size: int, most: int) -> str:
    return f"{label}: {size} bytes, more than the {most} a JSON input may have (INSPECTOR_MAX_JSON_BYTES)"


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
    most = limit("MAX_JSON_BYTES")
    try:
        # Non-blocking: a FIFO named rig.json must not hang a watcher (refused below).
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
        with os.fdopen(fd, "rb") as f:
            st = os.fstat(f.fileno())
            if not stat.S_ISREG(st.st_mode):
                raise error(f"{label}: not a file")
            if st.st_size > most:
                raise error(_too_big(label, st.st_size, most))
            raw = f.read(most + 1)
    except OSError as exc:
        raise error(f"{label}: cannot be read ({exc.strerror or exc})") from None
    if len(raw) > most:  # grew while it was read
        raise error(_too_big(label, len(raw), most))
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

