"""Images are checked before they are decoded (issue 15): the PNG header (size, bit depth,
colour type) against the rig, the file's size against the bound the rig's size gives, and
where the file really is (never outside its capture folder). Every refusal is one line naming
the file and the camera; the capture is an error and the other captures are inspected.

Crafted files only (a 2-camera rig of 64x48 real PNGs, and PNG headers built byte by byte);
the CLI tests run the real ``inspector run`` on a segment-only recipe.
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import pytest

from inspector.capture_folder import is_complete_png, png_header, read_capture, write_capture
from inspector.errors import CaptureError
from inspector.limits import MAX_IMAGE_PIXELS, image_file_bytes
from inspector.model import Camera, Rig

W, H = 64, 48
RECIPE = """
[recipe]
name = "images"
[[stages]]
use = "segment.threshold"
"""


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def crafted_png(width: int, height: int, depth: int = 8, colour: int = 0, *, idat: bytes = b"", iend: bool = True) -> bytes:
    """A PNG file built byte by byte: signature, IHDR as given, one IDAT, IEND."""
    out = b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0))
    if idat:
        out += _chunk(b"IDAT", idat)
    return out + (_chunk(b"IEND", b"") if iend else b"")


def _zeros_deflated(n: int) -> bytes:
    """``n`` zero bytes deflated (about n / 1000 bytes), without holding them in memory."""
    c = zlib.compressobj(9)
    block = bytes(1 << 22)
    out = [c.compress(block) for _ in range(n // len(block))]
    return b"".join(out) + c.flush()


def _capture(folder: Path, cameras: int = 2) -> Path:
    import cv2

    cams, images = [], {}
    for i in range(cameras):
        name = f"cam{i:02d}"
        cams.append(Camera(name, W, H, [[80.0, 0, 31.5], [0, 80.0, 23.5], [0, 0, 1]], None, np.eye(3), [0.0, 0.0, 100.0 + i]))
        img = np.full((H, W), 220.0, np.float32)
        cv2.circle(img, (32, 24), 12, 30.0, -1)  # a dark part on a bright background
        images[name] = cv2.GaussianBlur(img, (0, 0), 0.8).round().astype(np.uint8)
    return write_capture(folder, Rig(tuple(cams)), images)


@pytest.fixture
def capture(tmp_path: Path) -> Path:
    return _capture(tmp_path / "cap")


def _refusal(folder: Path) -> str:
    with pytest.raises(CaptureError) as e:
        read_capture(folder)
    msg = str(e.value)
    assert "\n" not in msg and e.value.__cause__ is None
    return msg


# --------------------------------------------------------------------------- the header


@pytest.mark.parametrize("width, height, depth, colour", [
    (1, 1, 1, 0), (W, H, 16, 0), (W, H, 8, 2), (W, H, 16, 2), (W, H, 4, 3), (W, H, 8, 4), (W, H, 16, 6)])
def test_png_header_reads_every_valid_kind(width, height, depth, colour):
    assert png_header(crafted_png(width, height, depth, colour), "x.png") == (width, height, depth, colour)


@pytest.mark.parametrize("data, message", [
    (b"", "x.png: empty file"),
    (b"GIF89a" + bytes(40), "x.png: not a PNG file"),
    (crafted_png(W, H)[:20], "x.png: truncated PNG (its header is cut, 20 bytes)"),
    (crafted_png(W, H).replace(b"IHDR", b"IHDX"), "x.png: corrupt PNG (its first chunk is not a 13-byte header)"),
    (crafted_png(W, H)[:20] + b"\xff" + crafted_png(W, H)[21:], "x.png: corrupt PNG header (checksum mismatch)"),
    (crafted_png(0, H), "x.png: corrupt PNG header (size 0x48)"),
    (crafted_png(W, H, 3, 0), "x.png: corrupt PNG header (3-bit grey; grey is 1/2/4/8/16-bit)"),
    (crafted_png(W, H, 16, 3), "x.png: corrupt PNG header (16-bit palette; palette is 1/2/4/8-bit)"),
    (crafted_png(W, H, 8, 5), "x.png: corrupt PNG header (colour type 5)"),
])
def test_png_header_refuses_in_one_line(data, message):
    with pytest.raises(CaptureError) as e:
        png_header(data, "x.png")
    assert str(e.value) == message


def test_a_small_file_declaring_30000x30000_pixels_is_refused_before_decoding(capture):
    """The issue's probe: 16 files of 0.95 MB declaring 30000x30000 took 15.6 GB to refuse."""
    bomb = crafted_png(30000, 30000, idat=_zeros_deflated(64 << 20))  # valid data for 2000 rows
    assert len(bomb) < 200_000
    (capture / "images" / "cam01.png").write_bytes(bomb)
    t0 = time.process_time()  # CPU time: a loaded machine does not slow it
    assert _refusal(capture) == "images/cam01.png: size 30000x30000, rig.json says 64x48 for camera cam01"
    assert time.process_time() - t0 < 2.0


def test_a_16_bit_rgba_png_is_bounded_by_its_camera(capture):
    """16-bit RGBA is a CONTRACT image (8 bytes a pixel): read at the rig's size, refused at
    any other before it is decoded (a 3 MB one declaring a huge size took 6.3 GB)."""
    import cv2

    rgba = np.random.default_rng(1).integers(0, 65535, (H, W, 4), dtype=np.uint16)
    cv2.imwrite(str(capture / "images" / "cam00.png"), rgba)
    img = read_capture(capture).images["cam00"]
    assert img.dtype == np.uint16 and img.shape == (H, W, 4)
    (capture / "images" / "cam00.png").write_bytes(crafted_png(20000, 20000, 16, 6, idat=_zeros_deflated(8 << 20)))
    assert _refusal(capture) == "images/cam00.png: size 20000x20000, rig.json says 64x48 for camera cam00"


@pytest.mark.parametrize("data, message", [
    (lambda good: good[: len(good) // 2], "images/cam01.png: truncated PNG (no IEND chunk)"),
    (lambda good: good[:25], "images/cam01.png: truncated PNG (its header is cut, 25 bytes)"),
    (lambda good: b"\xff\xd8\xff\xe0 a JPEG, not a PNG" + good, "images/cam01.png: not a PNG file"),
    (lambda good: crafted_png(W, H, 16, 4, idat=b"x"), "images/cam01.png: unreadable PNG (corrupt data)"),
    (lambda good: crafted_png(W, H, 2, 2, idat=b"x"), "images/cam01.png: corrupt PNG header (2-bit RGB; RGB is 8/16-bit)"),
])
def test_truncated_foreign_and_invalid_pngs_are_one_line(capture, data, message):
    path = capture / "images" / "cam01.png"
    path.write_bytes(data(path.read_bytes()))
    assert _refusal(capture) == message


def test_a_camera_larger_than_the_bound_is_refused_in_rig_json_and_the_bound_can_be_raised(capture, monkeypatch):
    rig = json.loads((capture / "rig.json").read_text())
    monkeypatch.setenv("INSPECTOR_MAX_IMAGE_PIXELS", str(W * H - 1))
    assert _refusal(capture) == (f"rig.json: camera cam00: {W}x{H} is {W * H} pixels, more than the {W * H - 1} "
                                 "a camera may have (INSPECTOR_MAX_IMAGE_PIXELS)")
    monkeypatch.setenv("INSPECTOR_MAX_IMAGE_PIXELS", str(W * H))
    monkeypatch.setenv("INSPECTOR_MAX_CAPTURE_PIXELS", str(2 * W * H - 1))
    assert _refusal(capture) == (f"rig.json: its 2 cameras have {2 * W * H} pixels together, more than the "
                                 f"{2 * W * H - 1} a capture may have (INSPECTOR_MAX_CAPTURE_PIXELS)")
    monkeypatch.delenv("INSPECTOR_MAX_CAPTURE_PIXELS")
    assert len(read_capture(capture).rig) == len(rig["cameras"])
    monkeypatch.delenv("INSPECTOR_MAX_IMAGE_PIXELS")
    # 30000 x 30000 in rig.json itself: refused before any image is read.
    rig["cameras"][0]["width"] = rig["cameras"][0]["height"] = 30000
    (capture / "rig.json").write_text(json.dumps(rig))
    assert _refusal(capture).startswith(f"rig.json: camera cam00: 30000x30000 is 900000000 pixels, more than the {MAX_IMAGE_PIXELS}")


def test_the_file_size_is_bounded_by_the_cameras_size_before_it_is_read(capture, tmp_path, monkeypatch):
    """The issue's probe: an image linked to a 3 GiB file was read whole (3.2 GB, 10 s)."""
    huge = capture / "images" / "huge.bin"
    with open(huge, "wb") as f:  # sparse: no disk used
        f.truncate(3 << 30)
    (capture / "images" / "cam00.png").unlink()
    (capture / "images" / "cam00.png").symlink_to("huge.bin")
    t0 = time.process_time()  # CPU time: a loaded machine does not slow it
    most = image_file_bytes(W, H)
    assert _refusal(capture) == (f"images/cam00.png: {3 << 30} bytes, more than the {most} a 64x48 image may have "
                                 "(INSPECTOR_MAX_IMAGE_METADATA_BYTES)")
    assert time.process_time() - t0 < 1.0
    # The bound is the camera's pixels at 16-bit RGBA, stored, plus the metadata allowance:
    # a real image with 2 MiB of text in it is read, and refused once the allowance is 1 MiB.
    (capture / "images" / "cam00.png").unlink()
    good = (capture / "images" / "cam01.png").read_bytes()
    text = _chunk(b"tEXt", b"Comment\x00" + b"x" * (2 << 20))
    (capture / "images" / "cam00.png").write_bytes(good[:33] + text + good[33:])
    assert read_capture(capture).images["cam00"].shape == (H, W)
    monkeypatch.setenv("INSPECTOR_MAX_IMAGE_METADATA_BYTES", str(1 << 20))
    size = len(good) + len(text)
    assert _refusal(capture) == (f"images/cam00.png: {size} bytes, more than the {image_file_bytes(W, H)} a 64x48 "
                                 "image may have (INSPECTOR_MAX_IMAGE_METADATA_BYTES)")


def test_an_image_linked_outside_its_capture_is_refused_naming_the_camera(capture, tmp_path):
    """The issue's probe: one camera's image linked to another capture's made a good part FAIL."""
    other = _capture(tmp_path / "other")
    link = capture / "images" / "cam01.png"
    link.unlink()
    link.symlink_to(other / "images" / "cam01.png")
    assert _refusal(capture) == (f"images/cam01.png: camera cam01's image is a link to {other / 'images' / 'cam01.png'}, "
                                 "outside the capture folder (copy the file into the capture)")
    # Also when a folder on the way is the link, and for backgrounds.
    link.unlink()
    (capture / "images" / "cam01.png").write_bytes((other / "images" / "cam01.png").read_bytes())
    (capture / "background").symlink_to(other / "images", target_is_directory=True)
    assert _refusal(capture).startswith("background/cam00.png: camera cam00's image is a link to ")
    (capture / "background").unlink()
    # A link that stays inside the capture is fine (one image shared by two cameras).
    (capture / "images" / "cam01.png").unlink()
    (capture / "images" / "cam01.png").symlink_to("cam00.png")
    assert read_capture(capture).images["cam01"].shape == (H, W)


def test_is_complete_png(capture):
    path = capture / "images" / "cam00.png"
    good = path.read_bytes()
    assert is_complete_png(path)
    for cut in (0, 10, 40, len(good) - 5):
        path.write_bytes(good[:cut])
        assert not is_complete_png(path)
    assert not is_complete_png(capture / "images" / "missing.png")
    os.mkfifo(capture / "images" / "fifo.png")  # never blocks a watcher
    assert not is_complete_png(capture / "images" / "fifo.png") and not is_complete_png(capture / "images")


# --------------------------------------------------------------------------- as a user sees it


def test_run_reports_each_bad_image_in_one_line_and_inspects_the_others(tmp_path, capsys):
    from inspector_frontends.cli import main

    batch = tmp_path / "batch"
    good = _capture(batch / "good")
    bomb = _capture(batch / "bomb")
    (bomb / "images" / "cam01.png").write_bytes(crafted_png(30000, 30000, idat=_zeros_deflated(16 << 20)))
    cut = _capture(batch / "cut")
    data = (cut / "images" / "cam00.png").read_bytes()
    (cut / "images" / "cam00.png").write_bytes(data[: len(data) // 2])
    linked = _capture(batch / "linked")
    (linked / "images" / "cam00.png").unlink()
    (linked / "images" / "cam00.png").symlink_to(good / "images" / "cam00.png")
    recipe = tmp_path / "r.toml"
    recipe.write_text(RECIPE)
    out = tmp_path / "out"
    assert main(["run", str(recipe), "--capture", str(batch), "--out", str(out)]) == 3
    lines = capsys.readouterr().out.splitlines()
    assert lines[:4] == [
        "[1/4] bomb: ERROR images/cam01.png: size 30000x30000, rig.json says 64x48 for camera cam01",
        "[2/4] cut: ERROR images/cam00.png: truncated PNG (no IEND chunk)",
        lines[2],
        f"[4/4] linked: ERROR images/cam00.png: camera cam00's image is a link to {good / 'images' / 'cam00.png'}, "
        "outside the capture folder (copy the file into the capture)",
    ]
    assert lines[2].startswith("[3/4] good: PASS")
    verdicts = {n: json.loads((out / n / "result.json").read_text())["verdict"] for n in ("bomb", "cut", "good", "linked")}
    assert verdicts == {"bomb": "error", "cut": "error", "good": "pass", "linked": "error"}


def test_sixteen_bombs_cost_no_memory(tmp_path):
    """The issue's probe as a new user runs it: 16 cameras, each image a small file declaring
    30000 x 30000 pixels. Measured in a real ``inspector run`` process against the same run
    on 16 truncated images (which decodes nothing either): a stale Numba cache compiles the
    kernels at import, about 3 GB, in whichever process comes first, so the baseline runs
    first and the comparison is made on what the images cost (15.6 GB before)."""
    recipe = tmp_path / "r.toml"
    recipe.write_text(RECIPE)
    code = ("import resource, sys; from inspector_frontends.cli import main; rc = main(sys.argv[1:]); "
            "print('maxrss_kb', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr); sys.exit(rc)")

    def peak(name: str, image: bytes) -> tuple[float, list[str]]:
        cap = _capture(tmp_path / name, cameras=16)
        for i in range(16):
            (cap / "images" / f"cam{i:02d}.png").write_bytes(image)
        p = subprocess.run([sys.executable, "-c", code, "run", str(recipe), "--capture", str(cap), "--out",
                            str(tmp_path / f"out-{name}"), "-q"],
                           capture_output=True, text=True, timeout=900, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        assert p.returncode == 3, p.stderr
        err = p.stderr.splitlines()
        return int(err[-1].split()[1]) / 1024, err

    baseline, _ = peak("cuts", crafted_png(64, 48, iend=False))
    maxrss_mb, err = peak("bombs", crafted_png(30000, 30000, idat=_zeros_deflated(64 << 20)))
    assert err[0] == "inspector: error: bombs: images/cam00.png: size 30000x30000, rig.json says 64x48 for camera cam00"
    # one decoded 30000^2 grey image alone is 858 MB
    assert maxrss_mb < baseline + 400, f"peak {maxrss_mb:.0f} MB against {baseline:.0f} MB decoding nothing"


def test_a_capture_that_would_not_fit_in_memory_is_refused_before_its_images_are_read(capture, monkeypatch):
    """Issue 27 finding 3: 16 x 8192² is within the pixel bounds and died with MemoryError at
    10.1 GB; the budget refuses it from rig.json, naming what it would need."""
    from inspector.errors import InputError
    from inspector.limits import inspection_bytes, memory_budget

    rig = json.loads((capture / "rig.json").read_text())
    cam = rig["cameras"][0]
    rig["cameras"] = [dict(cam, name=f"cam{i:02d}", width=8192, height=8192) for i in range(16)]
    (capture / "rig.json").write_text(json.dumps(rig))
    monkeypatch.setenv("INSPECTOR_MEMORY_BUDGET_MB", "12288")  # a 24 GB cell PC's half
    pixels = 16 * 8192 * 8192
    assert _refusal(capture) == (f"rig.json: its 16 cameras ({pixels} pixels) would need about "
                                 f"{inspection_bytes(pixels) / 2**30:.1f} GB to inspect, more than the memory budget of "
                                 "12.0 GB (INSPECTOR_MEMORY_BUDGET_MB)")
    assert inspection_bytes(pixels) > 15 * 2**30
    # The default budget is half this machine's memory: a 16 x 1 MP rig fits on any cell PC.
    monkeypatch.delenv("INSPECTOR_MEMORY_BUDGET_MB")
    budget, where = memory_budget()
    assert budget >= inspection_bytes(16 * 1024 * 1024) and where.startswith("half of this machine's")
    monkeypatch.setenv("INSPECTOR_MEMORY_BUDGET_MB", "lots")
    with pytest.raises(InputError, match=r"INSPECTOR_MEMORY_BUDGET_MB: expected a positive integer, got 'lots'"):
        memory_budget()
