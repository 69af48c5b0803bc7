"""PNG's row filters undone: the inflated image data of a PNG file back into its pixel bytes.

Written here because no library offers it apart from a whole decoder: a 16 x 5 MP capture
spends a quarter of its inspection cycle decoding PNGs (OpenCV 28-33 ms an image, of which
zlib's inflate 19 ms). :func:`inspector.png.decode_grey` inflates with libdeflate (11 ms)
and undoes the filters here (about 1.5 ms an image, a compiled loop: numpy's ``cumsum``
over the rows of a ``Sub``-filtered image takes 11 ms).

The five filter types are those of the PNG specification (ISO/IEC 15948, section 9):
None, Sub, Up, Average and Paeth, each undone on the bytes of a row with ``bpp`` bytes
per complete pixel. Pure: arrays in, arrays out. Imported lazily by :mod:`inspector.png`
(the first PNG decoded), so ``import inspector`` stays free of Numba.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["unfilter_rows"]


@numba.njit(cache=True, nogil=True)
def _unfilter(raw, height, row_bytes, bpp, out):  # pragma: no cover - compiled; tested through unfilter_rows
    """Undo each row's filter from ``raw`` into ``out`` (H, row_bytes); False at an unknown filter type."""
    for y in range(height):
        start = y * (row_bytes + 1)
        kind = raw[start]
        row = raw[start + 1:start + 1 + row_bytes]
        o = out[y]
        if kind == 0:
            o[:] = row
        elif kind == 1:
            if bpp == 1:  # a running byte in a register: reading o[x - 1] back costs a store-forwarding stall
                acc = np.uint8(0)
                for x in range(row_bytes):
                    acc = np.uint8(acc + row[x])
                    o[x] = acc
            else:
                o[:bpp] = row[:bpp]
                for x in range(bpp, row_bytes):
                    o[x] = np.uint8(row[x] + o[x - bpp])
        elif kind == 2:
            if y == 0:
                o[:] = row
            else:
                up = out[y - 1]
                for x in range(row_bytes):
                    o[x] = np.uint8(row[x] + up[x])
        elif kind == 3:
            for x in range(row_bytes):
                left = np.int32(o[x - bpp]) if x >= bpp else np.int32(0)
                above = np.int32(out[y - 1, x]) if y > 0 else np.int32(0)
                o[x] = np.uint8(np.int32(row[x]) + ((left + above) >> 1))
        elif kind == 4:
            for x in range(row_bytes):
                a = np.int32(o[x - bpp]) if x >= bpp else np.int32(0)
                b = np.int32(out[y - 1, x]) if y > 0 else np.int32(0)
                c = np.int32(out[y - 1, x - bpp]) if y > 0 and x >= bpp else np.int32(0)
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                o[x] = np.uint8(np.int32(row[x]) + pred)
        else:
            return False
    return True


def unfilter_rows(raw: np.ndarray, height: int, row_bytes: int, bpp: int) -> np.ndarray | None:
    """The pixel bytes of a non-interlaced PNG image from its inflated data.

    Parameters
    ----------
    raw : (height * (row_bytes + 1),) uint8
        The inflated image data: each row a filter-type byte and ``row_bytes`` filtered bytes.
    height, row_bytes : int
        Rows, and bytes per row without the filter-type byte (width x bytes per pixel).
    bpp : int
        Bytes per complete pixel, at least 1 (8-bit grey 1, 16-bit grey 2).

    Returns
    -------
    (height, row_bytes) uint8 or None
        The unfiltered bytes (16-bit samples big-endian, as in the file); None when a row
        names a filter type that PNG does not define.
    """
    raw = np.ascontiguousarray(raw, np.uint8).ravel()
    if not raw.flags.writeable:  # one compiled signature (Numba types read-only arrays apart)
        raw = raw.copy()
    if height < 1 or row_bytes < 1 or bpp < 1 or raw.size != height * (row_bytes + 1):
        raise ValueError(f"raw holds {raw.size} bytes, not {height} rows of 1 + {row_bytes} (bpp {bpp})")
    out = np.empty((height, row_bytes), np.uint8)
    return out if _unfilter(raw, np.int64(height), np.int64(row_bytes), np.int64(bpp), out) else None
