"""The grey PNG decoder (:func:`inspector.png.decode_grey`): OpenCV's pixels, or None for OpenCV.

The PNGs here are written by a small encoder of the test's own that chooses each row's filter
(OpenCV's writer filters every row ``Sub``), and OpenCV decodes every one of them as the
reference.
"""

from __future__ import annotations

import struct
import tracemalloc
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from inspector.capture_folder import decode_image
from inspector.errors import CaptureError
from inspector.png import PNG_SIGNATURE, decode_grey


def _filtered(img: np.ndarray, kinds: list[int], bpp: int) -> bytes:
    """Each row of ``img`` (H, row bytes, uint8) as PNG filter type ``kinds[y]`` prescribes."""
    a = img.astype(np.int32)
    left = np.zeros_like(a)
    left[:, bpp:] = a[:, :-bpp]
    up = np.zeros_like(a)
    up[1:] = a[:-1]
    upleft = np.zeros_like(a)
    upleft[1:, bpp:] = a[:-1, :-bpp]
    p = left + up - upleft
    pa, pb, pc = np.abs(p - left), np.abs(p - up), np.abs(p - upleft)
    paeth = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, upleft))
    predictors = [np.zeros_like(a), left, up, (left + up) >> 1, paeth]
    rows = [bytes([k]) + ((a[y] - predictors[k][y]) % 256).astype(np.uint8).tobytes() for y, k in enumerate(kinds)]
    return b"".join(rows)


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def _png(img: np.ndarray, kinds: list[int] | None = None, *, extra: tuple[tuple[bytes, bytes], ...] = (),
         parts: int = 3, colour: int = 0, interlace: int = 0) -> bytes:
    """A grey PNG of ``img`` (uint8 or uint16, (H, W)), its rows filtered ``kinds`` (default
    cycling through all five), its data in ``parts`` IDAT chunks, ``extra`` chunks first."""
    h, w = img.shape
    depth = 16 if img.dtype == np.uint16 else 8
    data = img.astype(">u2").view(np.uint8).reshape(h, 2 * w) if depth == 16 else img
    kinds = kinds if kinds is not None else [y % 5 for y in range(h)]
    z = zlib.compress(_filtered(data, kinds, depth // 8), 6)
    cuts = np.linspace(0, len(z), parts + 1).astype(int)
    out = PNG_SIGNATURE + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, depth, colour, 0, 0, interlace))
    out += b"".join(_chunk(k, b) for k, b in extra)
    out += b"".join(_chunk(b"IDAT", z[a:b]) for a, b in zip(cuts[:-1], cuts[1:]))
    return out + _chunk(b"IEND", b"")


def _opencv(data: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)


def _image(shape: tuple[int, int], dtype: type, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    top = np.iinfo(dtype).max
    # Smooth with noise, and the extremes: every filter's wrap-around is exercised.
    y, x = np.mgrid[: shape[0], : shape[1]]
    smooth = (np.sin(x / 5.0) + np.cos(y / 7.0) + 2.0) / 4.0 * top
    img = np.clip(smooth + rng.normal(0, top / 20, shape), 0, top).astype(dtype)
    img[rng.random(shape) < 0.05] = top
    img[rng.random(shape) < 0.05] = 0
    return img


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("shape", [(1, 1), (5, 1), (3, 2), (17, 7), (40, 64)])
def test_every_filter_type_decodes_as_opencv_does(dtype: type, shape: tuple[int, int]) -> None:
    img = _image(shape, dtype, seed=shape[0] * 100 + shape[1])
    for kinds in ([y % 5 for y in range(shape[0])], [(y + 4) % 5 for y in range(shape[0])]):
        data = _png(img, kinds)
        ours = decode_grey(data)
        assert ours is not None
        assert ours.dtype == dtype and ours.shape == shape
        assert np.array_equal(ours, img)
        assert np.array_equal(ours, _opencv(data))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_opencv_written_png_decodes_the_same(dtype: type) -> None:
    img = _image((48, 80), dtype, seed=3)
    ok, buf = cv2.imencode(".png", img)
    assert ok
    ours = decode_grey(buf.tobytes())
    assert ours is not None and ours.dtype == dtype
    assert np.array_equal(ours, img)
    assert ours.flags.c_contiguous and ours.flags.writeable


def test_text_time_and_size_chunks_are_read_past() -> None:
    img = _image((9, 11), np.uint8, seed=4)
    extra = ((b"tEXt", b"Camera\x00cam03"), (b"tIME", bytes(7)), (b"pHYs", struct.pack(">IIB", 10000, 10000, 1)))
    data = _png(img, extra=extra)
    assert np.array_equal(decode_grey(data), img)


def _with_crc_broken(data: bytes, kind: bytes) -> bytes:
    at = data.index(kind) + 4
    length = struct.unpack(">I", data[at - 8:at - 4])[0]
    b = bytearray(data)
    b[at + length] ^= 0xFF
    return bytes(b)


def _unknown_filter(img: np.ndarray) -> bytes:
    h, w = img.shape
    raw = bytearray(_filtered(img, [0] * h, 1))
    raw[(h // 2) * (w + 1)] = 5  # PNG defines filter types 0-4
    return (PNG_SIGNATURE + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
            + _chunk(b"IDAT", zlib.compress(bytes(raw))) + _chunk(b"IEND", b""))


def _cases() -> dict[str, bytes]:
    img = _image((12, 10), np.uint8, seed=5)
    good = _png(img)
    idat = good.index(b"IDAT") - 4
    iend = good.index(b"IEND") - 4
    rgb = cv2.imencode(".png", np.dstack([img, img, img]))[1].tobytes()
    split = _png(img, parts=2)
    second = split.index(b"IDAT", split.index(b"IDAT") + 4) - 4
    return {
        "rgb": rgb,
        "interlaced": _png(img, interlace=1),
        "gamma": _png(img, extra=((b"gAMA", struct.pack(">I", 45455)),)),
        "transparency": _png(img, extra=((b"tRNS", struct.pack(">H", 0)),)),
        "image data checksum": _with_crc_broken(good, b"IDAT"),
        "header checksum": _with_crc_broken(good, b"IHDR"),
        "image data cut": good[: idat + 30] + good[iend:],
        "no end": good[:iend],
        "unknown filter type": _unknown_filter(img),
        "image data not consecutive": split[:second] + _chunk(b"tEXt", b"a\x00b") + split[second:],
    }


@pytest.mark.parametrize("case", list(_cases()))
def test_anything_else_is_left_to_opencv(case: str) -> None:
    assert decode_grey(_cases()[case]) is None


def test_a_header_of_no_pixels_is_left_to_opencv() -> None:
    # Width 0, and image data of exactly its three rows' filter-type bytes.
    data = (PNG_SIGNATURE + _chunk(b"IHDR", struct.pack(">IIBBBBB", 0, 3, 8, 0, 0, 0, 0))
            + _chunk(b"IDAT", zlib.compress(bytes(3))) + _chunk(b"IEND", b""))
    assert decode_grey(data) is None


def test_a_file_without_image_data_is_left_to_opencv() -> None:
    data = PNG_SIGNATURE + _chunk(b"IHDR", struct.pack(">IIBBBBB", 1, 1, 8, 0, 0, 0, 0)) + _chunk(b"IEND", b"")
    assert decode_grey(data) is None


def test_a_larger_image_than_its_header_says_is_left_to_opencv() -> None:
    img = _image((12, 10), np.uint8, seed=6)
    data = bytearray(_png(np.vstack([img, img])))
    ihdr = data.index(b"IHDR")
    data[ihdr + 4:ihdr + 17] = struct.pack(">IIBBBBB", 10, 12, 8, 0, 0, 0, 0)  # half the rows it holds
    data[ihdr + 17:ihdr + 21] = struct.pack(">I", zlib.crc32(bytes(data[ihdr:ihdr + 17])))
    assert decode_grey(bytes(data)) is None


def test_decode_image_gives_opencv_pixels_and_opencv_errors(tmp_path: Path) -> None:
    img = _image((30, 20), np.uint16, seed=7)
    good = tmp_path / "good.png"
    good.write_bytes(_png(img))
    assert np.array_equal(decode_image(good, "good.png", size=(20, 30)), img)
    rgb = tmp_path / "rgb.png"
    colour = np.dstack([img, img // 2, img // 3])
    rgb.write_bytes(cv2.imencode(".png", colour)[1].tobytes())
    assert np.array_equal(decode_image(rgb, "rgb.png", size=(20, 30)), colour)  # OpenCV's BGR, as before
    bad = tmp_path / "bad.png"
    bad.write_bytes(_with_crc_broken(_png(img), b"IDAT"))
    with pytest.raises(CaptureError, match=r"^bad\.png: unreadable PNG \(corrupt data\)$"):
        decode_image(bad, "bad.png", size=(20, 30))


def test_a_header_larger_than_its_data_can_inflate_to_is_left_to_opencv() -> None:
    img = np.zeros((4, 4), np.uint8)
    data = bytearray(_png(img, parts=1))
    ihdr = data.index(b"IHDR")
    # 60000 x 60000 pixels declared by a file of some 100 bytes: refused before any memory is reserved.
    data[ihdr + 4:ihdr + 17] = struct.pack(">IIBBBBB", 60000, 60000, 8, 0, 0, 0, 0)
    data[ihdr + 17:ihdr + 21] = struct.pack(">I", zlib.crc32(bytes(data[ihdr:ihdr + 17])))
    tracemalloc.start()
    try:
        assert decode_grey(bytes(data)) is None
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20
    # The bound is DEFLATE's own: a black image compresses about 1000 to 1 and still decodes.
    black = np.zeros((600, 800), np.uint8)
    assert np.array_equal(decode_grey(_png(black, [0] * 600, parts=1)), black)
