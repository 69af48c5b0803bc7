"""The PNG file format's own checks, made before an image is decoded (part of :mod:`inspector.capture_folder`).

:func:`png_header` reads and checks the signature and header chunk that start a PNG file (its
size, bit depth and colour type, as the PNG specification defines them);
:func:`is_complete_png` says whether a file is a whole PNG (what a hot folder asks before it
reads a capture). Both are also importable from :mod:`inspector.capture_folder`.
"""

from __future__ import annotations

import os
import stat
import struct
import zlib

from inspector.errors import CaptureError

__all__ = ["PNG_SIGNATURE", "PNG_IEND", "png_header", "is_complete_png"]

#: The eight bytes every PNG file starts with.
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: The type and (constant) CRC of the ``IEND`` chunk that ends every complete PNG file.
PNG_IEND = b"IEND\xaeB`\x82"
#: PNG colour type -> (what it is, the bit depths the PNG specification allows for it).
_PNG_COLOURS = {0: ("grey", (1, 2, 4, 8, 16)), 2: ("RGB", (8, 16)), 3: ("palette", (1, 2, 4, 8)),
                4: ("grey + alpha", (8, 16)), 6: ("RGBA", (8, 16))}


def png_header(data: bytes, label: str, error: type[Exception] = CaptureError) -> tuple[int, int, int, int]:
    """``(width, height, bit depth, colour type)`` from the signature and header chunk that
    start the PNG bytes ``data`` (the first 33 bytes are enough).

    Checked as the PNG specification defines them, before anything is decoded: the
    signature, a first chunk ``IHDR`` of 13 bytes with a correct checksum, a size of at least
    1 x 1, a bit depth allowed for the colour type (grey 1-16, RGB 8/16, palette 1-8, grey +
    alpha 8/16, RGBA 8/16), compression and filter method 0, interlace 0 or 1.

    Raises ``error`` with a one-line message starting with ``label``.
    """
    if not data:
        raise error(f"{label}: empty file")
    if not data.startswith(PNG_SIGNATURE):
        raise error(f"{label}: not a PNG file")
    if len(data) < 33:
        raise error(f"{label}: truncated PNG (its header is cut, {len(data)} bytes)")
    length, kind = struct.unpack(">I4s", data[8:16])
    if length != 13 or kind != b"IHDR":
        raise error(f"{label}: corrupt PNG (its first chunk is not a 13-byte header)")
    if zlib.crc32(data[12:29]) != struct.unpack(">I", data[29:33])[0]:
        raise error(f"{label}: corrupt PNG header (checksum mismatch)")
    width, height, depth, colour, compression, filtering, interlace = struct.unpack(">IIBBBBB", data[16:29])
    if not (0 < width < 2**31 and 0 < height < 2**31):
        raise error(f"{label}: corrupt PNG header (size {width}x{height})")
    if colour not in _PNG_COLOURS:
        raise error(f"{label}: corrupt PNG header (colour type {colour})")
    what, depths = _PNG_COLOURS[colour]
    if depth not in depths:
        raise error(f"{label}: corrupt PNG header ({depth}-bit {what}; {what} is {'/'.join(map(str, depths))}-bit)")
    if compression or filtering or interlace > 1:
        raise error(f"{label}: corrupt PNG header (compression {compression}, filter {filtering}, interlace {interlace})")
    return width, height, depth, colour


def is_complete_png(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a whole PNG file: a valid header (:func:`png_header`) and the
    final ``IEND`` chunk at its end. Reads a few bytes at each end; never raises.

    What a hot folder asks before it reads a capture: a writer that stalls in the middle of
    an image leaves a file without its end.
    """
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))  # a FIFO never blocks
        with os.fdopen(fd, "rb") as f:
            if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
                return False
            png_header(f.read(33), "")
            size = f.seek(0, os.SEEK_END)
            f.seek(max(0, size - 1024))
            return f.read(1024).rfind(PNG_IEND) >= 0
    except (OSError, CaptureError, ValueError):
        return False
