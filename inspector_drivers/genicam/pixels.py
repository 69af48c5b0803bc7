"""GenICam (PFNC) pixel formats -> numpy arrays in the CONTRACT's conventions.

Shared by the ``genicam`` and ``aravis`` drivers. What comes out is what
:class:`~inspector.model.Capture` holds: ``uint8`` or ``uint16``; grey ``(H, W)``; colour
**RGB** ``(H, W, 3)`` or **RGBA** ``(H, W, 4)``. The result is always a fresh, C-contiguous,
read-only array that owns its memory, so the acquisition buffer it came from can be re-queued
at once (a view on a re-queued buffer would silently change under the inspection).

Supported
---------
``Mono8``; ``Mono10``/``Mono12``/``Mono14``/``Mono16`` (unpacked little-endian, values as
sent, not rescaled); packed ``Mono10p``, ``Mono12p``, ``Mono12Packed``; ``RGB8``, ``BGR8``,
``RGBa8``, ``BGRa8``, ``RGB16``; Bayer ``BayerRG/GR/GB/BG`` at 8 bits, and 10/12/16 bits
unpacked: demosaiced to RGB (OpenCV, edge-aware bilinear) or, with ``bayer="raw"``, the mosaic
itself as grey.

Input is either the raw bytes of the image (what Aravis gives) or an array already expanded by
the transport library (Harvesters expands packed formats to ``uint16``); row padding at the
end of each line (``x_padding``) is removed.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["SUPPORTED", "PFNC_CODES", "UnsupportedPixelFormat", "to_array", "pixel_format_name"]


class UnsupportedPixelFormat(ValueError):
    """The pixel format has no conversion here (message names the format)."""


# name -> (channels, bits per stored sample (8 or 16), kind)
_UNPACKED: dict[str, tuple[int, int, str]] = {
    "Mono8": (1, 8, "mono"),
    "Mono10": (1, 16, "mono"),
    "Mono12": (1, 16, "mono"),
    "Mono14": (1, 16, "mono"),
    "Mono16": (1, 16, "mono"),
    "RGB8": (3, 8, "rgb"),
    "BGR8": (3, 8, "bgr"),
    "RGBa8": (4, 8, "rgba"),
    "BGRa8": (4, 8, "bgra"),
    "RGB16": (3, 16, "rgb"),
}
for _pat in ("RG", "GR", "GB", "BG"):
    _UNPACKED[f"Bayer{_pat}8"] = (1, 8, f"bayer{_pat}")
    for _bits in (10, 12, 16):
        _UNPACKED[f"Bayer{_pat}{_bits}"] = (1, 16, f"bayer{_pat}")

# packed mono: name -> (bits, layout)
_PACKED: dict[str, tuple[int, str]] = {
    "Mono10p": (10, "lsb"),  # PFNC: LSB-first bit stream, 4 px in 5 bytes
    "Mono12p": (12, "lsb"),  # PFNC: LSB-first bit stream, 2 px in 3 bytes
    "Mono12Packed": (12, "gev"),  # GigE Vision legacy: [A11..4][B3..0 A3..0][B11..4]
}

#: Every pixel format name this module converts.
SUPPORTED: tuple[str, ...] = tuple(sorted(set(_UNPACKED) | set(_PACKED)))

# PFNC Bayer pattern (first two pixels of the first row) -> OpenCV code name. OpenCV names
# its legacy codes after the second row's pixels, so RGGB is "BayerBG" there.
_CV_BAYER = {"RG": "COLOR_BayerBG2RGB", "GR": "COLOR_BayerGB2RGB", "GB": "COLOR_BayerGR2RGB", "BG": "COLOR_BayerRG2RGB"}


#: PFNC 32-bit codes (what GigE Vision leaders and Aravis buffers carry) of the formats above.
PFNC_CODES: dict[int, str] = {
    0x01080001: "Mono8", 0x01100003: "Mono10", 0x01100005: "Mono12", 0x01100025: "Mono14",
    0x01100007: "Mono16", 0x010A0046: "Mono10p", 0x010C0047: "Mono12p", 0x010C0006: "Mono12Packed",
    0x02180014: "RGB8", 0x02180015: "BGR8", 0x02200016: "RGBa8", 0x02200017: "BGRa8", 0x02300033: "RGB16",
    0x01080008: "BayerGR8", 0x01080009: "BayerRG8", 0x0108000A: "BayerGB8", 0x0108000B: "BayerBG8",
    0x0110000C: "BayerGR10", 0x0110000D: "BayerRG10", 0x0110000E: "BayerGB10", 0x0110000F: "BayerBG10",
    0x01100010: "BayerGR12", 0x01100011: "BayerRG12", 0x01100012: "BayerGB12", 0x01100013: "BayerBG12",
    0x0110002E: "BayerGR16", 0x0110002F: "BayerRG16", 0x01100030: "BayerGB16", 0x01100031: "BayerBG16",
}


def pixel_format_name(value: Any) -> str:
    """A PFNC name from a name, or from a PFNC code (``0x01080001`` -> ``"Mono8"``)."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return PFNC_CODES.get(int(value), f"0x{int(value):08X}")
    return str(value).strip()


def _as_bytes(data: Any) -> np.ndarray:
    if isinstance(data, (bytes, bytearray, memoryview)):
        return np.frombuffer(data, np.uint8)
    a = np.asarray(data)
    if not a.flags.c_contiguous:
        a = np.ascontiguousarray(a)
    return a.reshape(-1).view(np.uint8)


def _rows(flat: np.ndarray, height: int, row_items: int, padding_items: int, what: str) -> np.ndarray:
    """(height, row_items) view of a flat array whose rows may carry trailing padding."""
    stride = row_items + padding_items
    need = height * stride
    if flat.size < need:
        # The last row's padding may be absent.
        if padding_items and flat.size >= need - padding_items:
            flat = np.concatenate([flat, np.zeros(need - flat.size, flat.dtype)])
        else:
            raise ValueError(f"{what}: {flat.size} items for {height} rows of {row_items} (+{padding_items} padding)")
    return flat[:need].reshape(height, stride)[:, :row_items]


def _unpack(raw: np.ndarray, width: int, height: int, bits: int, layout: str, padding_bytes: int, fmt: str) -> np.ndarray:
    if layout == "gev" or bits == 12:
        if width % 2:
            raise ValueError(f"{fmt}: odd width {width} is not supported")
        row_bytes = width * 3 // 2
        rows = _rows(raw, height, row_bytes, padding_bytes, fmt).astype(np.uint16)
        b0, b1, b2 = rows[:, 0::3], rows[:, 1::3], rows[:, 2::3]
        if layout == "gev":
            p0 = (b0 << 4) | (b1 & 0x0F)
            p1 = (b2 << 4) | (b1 >> 4)
        else:  # Mono12p, LSB first
            p0 = b0 | ((b1 & 0x0F) << 8)
            p1 = (b1 >> 4) | (b2 << 4)
        out = np.empty((height, width), np.uint16)
        out[:, 0::2], out[:, 1::2] = p0, p1
        return out
    # Mono10p: 4 pixels in 5 bytes, LSB first
    if width % 4:
        raise ValueError(f"{fmt}: width {width} is not a multiple of 4")
    row_bytes = width * 5 // 4
    rows = _rows(raw, height, row_bytes, padding_bytes, fmt).astype(np.uint16)
    b = [rows[:, k::5] for k in range(5)]
    out = np.empty((height, width), np.uint16)
    out[:, 0::4] = b[0] | ((b[1] & 0x03) << 8)
    out[:, 1::4] = (b[1] >> 2) | ((b[2] & 0x0F) << 6)
    out[:, 2::4] = (b[2] >> 4) | ((b[3] & 0x3F) << 4)
    out[:, 3::4] = (b[3] >> 6) | (b[4] << 2)
    return out


def to_array(
    data: Any,
    width: int,
    height: int,
    pixel_format: str,
    *,
    x_padding: int = 0,
    bayer: str = "rgb",
) -> np.ndarray:
    """Convert one frame to a read-only numpy image that owns its memory.

    Parameters
    ----------
    data
        Raw bytes (``bytes``/``memoryview``/uint8 array), or an array already expanded to
        the format's sample type (uint16 for 10..16-bit formats).
    width, height : int
        Image size in pixels.
    pixel_format : str
        PFNC name (``"Mono8"``, ``"BayerRG8"``, ...).
    x_padding : int
        Padding bytes at the end of every line.
    bayer : ``"rgb"`` or ``"raw"``
        Demosaic Bayer formats to RGB, or return the mosaic as grey.

    Raises
    ------
    UnsupportedPixelFormat
        The format is not one of :data:`SUPPORTED`.
    ValueError
        The data is too short for the given size.
    """
    fmt = pixel_format_name(pixel_format)
    width, height = int(width), int(height)
    if width <= 0 or height <= 0:
        raise ValueError(f"{fmt}: invalid image size {width}x{height}")
    arr = data if isinstance(data, np.ndarray) else None

    if fmt in _PACKED:
        bits, layout = _PACKED[fmt]
        if arr is not None and arr.dtype == np.uint16:  # already expanded (Harvesters)
            out = _rows(arr.reshape(-1), height, width, x_padding // 2, fmt)
        else:
            out = _unpack(_as_bytes(data), width, height, bits, layout, x_padding, fmt)
        return _finish(out)

    if fmt not in _UNPACKED:
        raise UnsupportedPixelFormat(f"unsupported pixel format {fmt!r} (supported: {', '.join(SUPPORTED)})")
    channels, bits, kind = _UNPACKED[fmt]
    dtype = np.dtype("<u2") if bits == 16 else np.dtype(np.uint8)
    item = dtype.itemsize
    if x_padding % item:
        raise ValueError(f"{fmt}: line padding of {x_padding} bytes is not a whole number of samples")
    raw = _as_bytes(data)
    flat = raw[: raw.size - raw.size % item].view(dtype)
    rows = _rows(flat, height, width * channels, x_padding // item, fmt)
    img = rows.reshape(height, width, channels) if channels > 1 else rows
    img = img.astype(np.uint16 if bits == 16 else np.uint8, copy=False)

    if kind == "bgr":
        img = img[:, :, ::-1]
    elif kind == "bgra":
        img = img[:, :, [2, 1, 0, 3]]
    elif kind.startswith("bayer") and bayer == "rgb":
        import cv2

        img = cv2.cvtColor(np.ascontiguousarray(img), getattr(cv2, _CV_BAYER[kind[5:]]))
    elif kind.startswith("bayer") and bayer != "raw":
        raise ValueError(f"bayer must be 'rgb' or 'raw', got {bayer!r}")
    return _finish(img)


def _finish(img: np.ndarray) -> np.ndarray:
    out = np.array(img, copy=True, order="C")  # owns its memory: the buffer is re-queued next
    out.setflags(write=False)
    return out
