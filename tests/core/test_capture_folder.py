"""Capture folders (CONTRACT): inspector.capture_folder."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from inspector.capture_folder import (
    is_capture_folder,
    read_capture,
    read_rig,
    write_capture,
)
from inspector.errors import CaptureError
from inspector.model import Camera, Rig

W, H = 64, 48


# --------------------------------------------------------------------------- fixtures


def look_at(centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World->camera R, t for a camera at ``centre`` looking at the origin."""
    z = -centre / np.linalg.norm(centre)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ centre


def make_rig(n: int = 4, seed: int = 0, distortion: bool = False) -> Rig:
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n
        centre = 500.0 * np.array([np.cos(a), np.sin(a), rng.uniform(-0.5, 0.5)])
        R, t = look_at(centre)
        f = 80.0 + rng.uniform(-5, 5)
        K = [[f, 0.0, (W - 1) / 2 + rng.uniform(-1, 1)], [0.0, f * 1.01, (H - 1) / 2], [0.0, 0.0, 1.0]]
        dist = rng.normal(0, 0.01, 5) if distortion else np.zeros(5)
        cams.append(Camera(name=f"cam{i:02d}", width=W, height=H, K=K, dist=dist, R=R, t=t))
    return Rig(tuple(cams))


def make_images(rig: Rig, seed: int = 1) -> dict[str, np.ndarray]:
    """8-bit grey, 16-bit grey, 8-bit RGB, 16-bit RGBA... cycling over the cameras."""
    rng = np.random.default_rng(seed)
    kinds = [(np.uint8, ()), (np.uint16, ()), (np.uint8, (3,)), (np.uint16, (4,))]
    out = {}
    for i, c in enumerate(rig):
        dtype, extra = kinds[i % len(kinds)]
        out[c.name] = rng.integers(0, np.iinfo(dtype).max, size=(c.height, c.width, *extra), endpoint=True).astype(dtype)
    return out


@pytest.fixture
def rig() -> Rig:
    return make_rig()


@pytest.fixture
def capture_dir(tmp_path: Path, rig: Rig) -> Path:
    """A valid capture with every optional part."""
    rng = np.random.default_rng(2)
    bgs = {"cam00": rng.integers(0, 255, (H, W), dtype=np.uint8), "cam02": rng.integers(0, 255, (H, W, 3), dtype=np.uint8)}
    return write_capture(
        tmp_path / "cap-001",
        rig,
        make_images(rig),
        backgrounds=bgs,
        metadata={"part_id": "P-17", "timestamp": "2024-05-01T12:00:00+00:00", "line": 3},
        polarity="bright-object",
        truth_mesh=trimesh.creation.box(extents=(30, 20, 10)),
        truth_info={"pose": np.eye(4), "defects": [], "scale": np.float64(1.5)},
    )


def assert_cameras_equal(a: Camera, b: Camera) -> None:
    assert (a.name, a.width, a.height) == (b.name, b.width, b.height)
    for k in ("K", "dist", "R", "t"):
        np.testing.assert_allclose(getattr(a, k), getattr(b, k), rtol=0, atol=1e-9, err_msg=k)


def edit_json(path: Path, fn: Callable[[dict], object]) -> None:
    data = json.loads(path.read_text())
    fn(data)
    path.write_text(json.dumps(data))  # allow_nan: NaN/Infinity tokens on purpose


def write_png(path: Path, img: np.ndarray) -> None:
    ok, buf = cv2.imencode(".png", img)
    assert ok
    path.write_bytes(buf.tobytes())


# --------------------------------------------------------------------------- round trip


def test_round_trip(capture_dir: Path, rig: Rig) -> None:
    cap = read_capture(capture_dir)
    assert cap.name == "cap-001"
    assert cap.source == capture_dir
    assert cap.rig.names == rig.names
    for a, b in zip(cap.rig, rig):
        assert_cameras_equal(a, b)
    expected = make_images(rig)
    assert list(cap.images) == list(rig.names)
    for name, img in expected.items():
        got = cap.images[name]
        assert got.dtype == img.dtype and got.shape == img.shape, name
        np.testing.assert_array_equal(got, img)
        assert not got.flags.writeable
    assert set(cap.backgrounds) == {"cam00", "cam02"}
    assert cap.backgrounds["cam02"].shape == (H, W, 3)
    assert cap.polarity == "bright-object"
    assert dict(cap.metadata) == {"part_id": "P-17", "timestamp": "2024-05-01T12:00:00+00:00", "line": 3}
    assert cap.truth is not None
    assert cap.truth.mesh_path == capture_dir / "truth" / "part.ply"
    mesh = trimesh.load(cap.truth.mesh_path)
    np.testing.assert_allclose(mesh.extents, (30, 20, 10))
    assert cap.truth.info == {"pose": np.eye(4).tolist(), "defects": [], "scale": 1.5}


def test_colour_is_rgb_in_memory_and_bgr_on_disk(tmp_path: Path, rig: Rig) -> None:
    images = {c.name: np.zeros((H, W), np.uint8) for c in rig}
    red = np.zeros((H, W, 3), np.uint8)
    red[..., 0] = 200  # RGB red
    images["cam01"] = red
    folder = write_capture(tmp_path / "c", rig, images)
    on_disk = cv2.imread(str(folder / "images" / "cam01.png"), cv2.IMREAD_UNCHANGED)
    assert on_disk[0, 0].tolist() == [0, 0, 200]  # cv2's BGR
    assert read_capture(folder).images["cam01"][0, 0].tolist() == [200, 0, 0]


def test_minimal_capture_defaults(tmp_path: Path, rig: Rig) -> None:
    folder = write_capture(tmp_path / "a" / "b" / "minimal", rig, make_images(rig))
    assert sorted(p.name for p in folder.iterdir()) == ["images", "rig.json"]
    cap = read_capture(str(folder))
    assert cap.polarity == "dark-object"
    assert dict(cap.metadata) == {}
    assert dict(cap.backgrounds) == {}
    assert cap.truth is None
    rig_json = json.loads((folder / "rig.json").read_text())
    assert rig_json["units"] == "mm" and len(rig_json["cameras"]) == len(rig)


def test_units_m_converted_to_mm(capture_dir: Path, rig: Rig) -> None:
    def to_m(d: dict) -> None:
        d["units"] = "m"
        for c in d["cameras"]:
            c["t"] = [x / 1000.0 for x in c["t"]]

    edit_json(capture_dir / "rig.json", to_m)
    cap = read_capture(capture_dir)
    for a, b in zip(cap.rig, rig):
        np.testing.assert_allclose(a.t, b.t, rtol=1e-12)
        np.testing.assert_array_equal(a.K, b.K)  # pixels: unchanged


@pytest.mark.parametrize(
    ("dist", "expected"),
    [
        ([0.1, -0.2, 0.001, 0.002], [0.1, -0.2, 0.001, 0.002, 0.0]),
        ([0.1, -0.2, 0.001, 0.002, 0.05], [0.1, -0.2, 0.001, 0.002, 0.05]),
        ([[0.1, -0.2, 0.001, 0.002, 0.05]], [0.1, -0.2, 0.001, 0.002, 0.05]),  # cv2's (1, 5)
        ([0.1, -0.2, 0.001, 0.002, 0.05, 0, 0, 0], [0.1, -0.2, 0.001, 0.002, 0.05]),
        (None, [0, 0, 0, 0, 0]),
        ("absent", [0, 0, 0, 0, 0]),
    ],
)
def test_dist_forms(capture_dir: Path, dist, expected) -> None:
    def set_dist(d: dict) -> None:
        if dist == "absent":
            del d["cameras"][1]["dist"]
        else:
            d["cameras"][1]["dist"] = dist

    edit_json(capture_dir / "rig.json", set_dist)
    np.testing.assert_array_equal(read_capture(capture_dir).rig.camera("cam01").dist, expected)


def test_read_rig(capture_dir: Path, rig: Rig) -> None:
    got = read_rig(capture_dir / "rig.json")
    for a, b in zip(got, rig):
        assert_cameras_equal(a, b)
    with pytest.raises(CaptureError, match="rig.json"):
        read_rig(capture_dir / "nothing" / "rig.json")


def test_hand_written_capture_folder(tmp_path: Path) -> None:
    """A folder written by another program (json.dump + cv2.imwrite), in metres."""
    rig = make_rig(n=3, seed=5, distortion=True)
    folder = tmp_path / "from-elsewhere"
    (folder / "images").mkdir(parents=True)
    (folder / "background").mkdir()
    cams = []
    for c in rig:
        cams.append(
            {
                "name": c.name,
                "width": c.width,
                "height": c.height,
                "K": c.K.tolist(),
                "dist": c.dist[:4].tolist() if c.name == "cam02" else c.dist.tolist(),
                "R": c.R.tolist(),
                "t": (c.t / 1000.0).tolist(),
            }
        )
    with open(folder / "rig.json", "w") as f:
        json.dump({"units": "m", "cameras": cams}, f, indent=1)
    with open(folder / "capture.json", "w") as f:
        json.dump({"part_id": "A1", "timestamp": "2024-05-01T12:00:00Z", "polarity": "dark-object", "operator": "kim"}, f)
    rng = np.random.default_rng(7)
    grey16 = rng.integers(0, 65535, (H, W), dtype=np.uint16)
    bgr = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    grey8 = rng.integers(0, 255, (H, W), dtype=np.uint8)
    cv2.imwrite(str(folder / "images" / "cam00.png"), grey16)
    cv2.imwrite(str(folder / "images" / "cam01.png"), bgr)
    cv2.imwrite(str(folder / "images" / "cam02.png"), grey8)
    for c in rig:
        cv2.imwrite(str(folder / "background" / f"{c.name}.png"), np.full((H, W), 240, np.uint8))
    (folder / "images" / "notes.txt").write_text("ignored")
    (folder / "images" / ".DS_Store").write_bytes(b"\0\1")

    assert is_capture_folder(folder)
    cap = read_capture(folder)
    assert cap.name == "from-elsewhere"
    for got, want in zip(cap.rig, rig):
        np.testing.assert_allclose(got.t, want.t, rtol=1e-12)
        np.testing.assert_allclose(got.R, want.R)
        np.testing.assert_allclose(got.K, want.K)
        expected_dist = np.append(want.dist[:4], 0.0) if want.name == "cam02" else want.dist
        np.testing.assert_allclose(got.dist, expected_dist)
    assert cap.rig.camera("cam00").has_distortion
    np.testing.assert_array_equal(cap.images["cam00"], grey16)
    assert cap.images["cam00"].dtype == np.uint16
    np.testing.assert_array_equal(cap.images["cam01"], bgr[..., ::-1])  # RGB in memory
    np.testing.assert_array_equal(cap.images["cam02"], grey8)
    assert list(cap.backgrounds) == ["cam00", "cam01", "cam02"]
    assert all(int(b[0, 0]) == 240 for b in cap.backgrounds.values())
    assert cap.polarity == "dark-object"
    assert cap.metadata == {"part_id": "A1", "timestamp": "2024-05-01T12:00:00Z", "operator": "kim"}
    assert cap.truth is None


def test_is_capture_folder(capture_dir: Path, tmp_path: Path) -> None:
    assert is_capture_folder(capture_dir)
    assert is_capture_folder(str(capture_dir))
    assert not is_capture_folder(tmp_path)
    assert not is_capture_folder(tmp_path / "missing")
    assert not is_capture_folder(capture_dir / "rig.json")


def test_read_16_images_1024(tmp_path: Path, benchmark) -> None:
    """16 cameras of 1024x1024 (the product's rig): decoded in a small thread pool."""
    rig = Rig(tuple(Camera(c.name, 1024, 1024, c.K, c.dist, c.R, c.t) for c in make_rig(n=16, seed=3)))
    yy, xx = np.mgrid[:1024, :1024]
    disc = ((xx - 512) ** 2 + (yy - 500) ** 2 < 300**2).astype(np.uint8)
    images = {c.name: (230 - 200 * disc).astype(np.uint8) for c in rig}
    folder = write_capture(tmp_path / "big", rig, images)
    cap = benchmark(read_capture, folder)
    assert len(cap.images) == 16 and cap.images["cam15"].shape == (1024, 1024)


# --------------------------------------------------------------------------- writer


def test_write_refuses_non_empty_folder_unless_overwrite(tmp_path: Path, rig: Rig) -> None:
    folder = tmp_path / "c"
    folder.mkdir()
    (folder / "keep.txt").write_text("x")
    with pytest.raises(FileExistsError):
        write_capture(folder, rig, make_images(rig))
    write_capture(folder, rig, make_images(rig), backgrounds={"cam00": np.zeros((H, W), np.uint8)}, overwrite=True)
    assert read_capture(folder).rig.names == rig.names
    # Overwrite with a smaller rig: stale images and backgrounds must go.
    small = Rig(rig.cameras[:2])
    write_capture(folder, small, {n: make_images(rig)[n] for n in small.names}, overwrite=True)
    cap = read_capture(folder)
    assert cap.rig.names == ("cam00", "cam01")
    assert dict(cap.backgrounds) == {}
    assert (folder / "keep.txt").exists()


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (lambda imgs: imgs.pop("cam03"), "cam03"),
        (lambda imgs: imgs.update(cam09=np.zeros((H, W), np.uint8)), "cam09"),
        (lambda imgs: imgs.update(cam01=np.zeros((H, W + 1), np.uint8)), "cam01"),
        (lambda imgs: imgs.update(cam01=np.zeros((H, W), np.float32)), "float32"),
    ],
)
def test_write_rejects_bad_images_and_writes_nothing(tmp_path: Path, rig: Rig, change, match) -> None:
    images = make_images(rig)
    change(images)
    with pytest.raises(ValueError, match=match):
        write_capture(tmp_path / "c", rig, images)
    assert not (tmp_path / "c").exists()


def test_write_rejects_bad_polarity(tmp_path: Path, rig: Rig) -> None:
    with pytest.raises(ValueError, match="polarity"):
        write_capture(tmp_path / "c", rig, make_images(rig), polarity="grey-object")


# --------------------------------------------------------------------------- errors


def _rig(fn: Callable[[dict], object]) -> Callable[[Path], None]:
    return lambda folder: edit_json(folder / "rig.json", fn)


def _cam(i: int, fn: Callable[[dict], object]) -> Callable[[Path], None]:
    return _rig(lambda d: fn(d["cameras"][i]))


def _set(key: str, value) -> Callable[[dict], object]:
    return lambda obj: obj.__setitem__(key, value)


def _del(key: str) -> Callable[[dict], object]:
    return lambda obj: obj.pop(key)


def _write(rel: str, data: bytes | str) -> Callable[[Path], None]:
    def f(folder: Path) -> None:
        p = folder / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data.encode() if isinstance(data, str) else data)

    return f


def _png(rel: str, img: np.ndarray) -> Callable[[Path], None]:
    return lambda folder: write_png(folder / rel, img)


def _truncate(rel: str) -> Callable[[Path], None]:
    def f(folder: Path) -> None:
        data = (folder / rel).read_bytes()
        (folder / rel).write_bytes(data[: len(data) // 2])

    return f


def _corrupt(rel: str) -> Callable[[Path], None]:
    """Flip bytes inside the image data, leaving the file's end (IEND) intact."""

    def f(folder: Path) -> None:
        data = bytearray((folder / rel).read_bytes())
        mid = len(data) // 2
        data[mid : mid + 16] = bytes(b ^ 0xFF for b in data[mid : mid + 16])
        (folder / rel).write_bytes(bytes(data))

    return f


def _unlink(rel: str) -> Callable[[Path], None]:
    return lambda folder: (folder / rel).unlink()


def _rmtree(rel: str) -> Callable[[Path], None]:
    return lambda folder: shutil.rmtree(folder / rel)


def _reflect(cam: dict) -> None:
    cam["R"][2] = [-x for x in cam["R"][2]]


def _scale_r(cam: dict) -> None:
    cam["R"] = [[1.01 * x for x in row] for row in cam["R"]]


def _folder_is_file(folder: Path) -> None:
    shutil.rmtree(folder)
    folder.write_text("not a folder")


GREY = np.zeros((H, W), np.uint8)

ERROR_CASES = {
    # folder and rig.json
    "folder missing": (lambda f: shutil.rmtree(f), ["cap-001", "does not exist"]),
    "folder is a file": (_folder_is_file, ["cap-001", "not a directory"]),
    "rig.json missing": (_unlink("rig.json"), ["rig.json", "missing"]),
    "rig.json bad json": (_write("rig.json", '{\n  "units": "mm"\n  "cameras": []\n}'), ["rig.json: not valid JSON (line 3 column 3)"]),
    "rig.json not utf-8": (_write("rig.json", b'{"units": "\xff"}'), ["rig.json", "UTF-8"]),
    "rig.json not object": (_write("rig.json", "[1, 2]"), ["rig.json", "object"]),
    "rig.json duplicate key": (_write("rig.json", '{"units": "mm", "units": "m", "cameras": []}'), ["rig.json", "duplicate key 'units'"]),
    "units inch": (_rig(_set("units", "inch")), ["rig.json", "units", "inch"]),
    "units missing": (_rig(_del("units")), ["rig.json", "units"]),
    "cameras missing": (_rig(_del("cameras")), ["rig.json", "cameras"]),
    "cameras empty": (_rig(_set("cameras", [])), ["rig.json", "cameras", "empty"]),
    "cameras not list": (_rig(_set("cameras", {"cam00": {}})), ["rig.json", "cameras", "list"]),
    "camera not object": (_rig(lambda d: d["cameras"].__setitem__(2, "cam02")), ["rig.json", "cameras[2]", "object"]),
    "camera no name": (_cam(1, _del("name")), ["rig.json", "cameras[1]", "'name'"]),
    "camera bad name": (_cam(1, _set("name", "../x")), ["rig.json", "cameras[1]", "file name"]),
    "camera no width": (_cam(1, _del("width")), ["rig.json", "camera cam01", "'width'"]),
    "camera no height": (_cam(1, _del("height")), ["rig.json", "camera cam01", "'height'"]),
    "camera no K": (_cam(1, _del("K")), ["rig.json", "camera cam01", "'K'"]),
    "camera no R": (_cam(1, _del("R")), ["rig.json", "camera cam01", "'R'"]),
    "camera no t": (_cam(1, _del("t")), ["rig.json", "camera cam01", "'t'"]),
    "width zero": (_cam(1, _set("width", 0)), ["rig.json", "camera cam01", "width"]),
    "height string": (_cam(1, _set("height", "48")), ["rig.json", "camera cam01", "height"]),
    "K shape": (_cam(3, _set("K", [[80, 0, 32], [0, 80, 24]])), ["rig.json", "camera cam03", "K", "shape 2x3"]),
    "K strings": (_cam(3, _set("K", [["80", 0, 32], [0, 80, 24], [0, 0, 1]])), ["rig.json", "camera cam03", "K", "numbers"]),
    "K ragged": (_cam(3, _set("K", [[80, 0, 32], [0, 80], [0, 0, 1]])), ["rig.json", "camera cam03", "K"]),
    "K last row": (_cam(3, _set("K", [[80, 0, 32], [0, 80, 24], [0, 0, 2]])), ["rig.json", "camera cam03", "K", "form"]),
    "R shape": (_cam(3, _set("R", [[1, 0], [0, 1]])), ["rig.json", "camera cam03", "R", "shape 2x2"]),
    "t shape": (_cam(3, _set("t", [0, 0])), ["rig.json", "camera cam03", "t", "shape 2"]),
    "t scalar": (_cam(3, _set("t", 500)), ["rig.json", "camera cam03", "t"]),
    "duplicate names": (_cam(2, _set("name", "cam01")), ["rig.json", "duplicate camera name 'cam01'"]),
    "K nan": (_cam(2, lambda c: c["K"][0].__setitem__(2, float("nan"))), ["rig.json", "camera cam02", "K", "non-finite"]),
    "R inf": (_cam(2, lambda c: c["R"][1].__setitem__(1, float("inf"))), ["rig.json", "camera cam02", "R", "non-finite"]),
    "t nan": (_cam(2, lambda c: c["t"].__setitem__(0, float("nan"))), ["rig.json", "camera cam02", "t", "non-finite"]),
    "dist nan": (_cam(2, _set("dist", [0, float("nan"), 0, 0, 0])), ["rig.json", "camera cam02", "dist", "non-finite"]),
    "fx zero": (_cam(0, lambda c: c["K"][0].__setitem__(0, 0.0)), ["rig.json", "camera cam00", "fx"]),
    "fy negative": (_cam(0, lambda c: c["K"][1].__setitem__(1, -80.0)), ["rig.json", "camera cam00", "fy"]),
    "R reflection": (_cam(3, _reflect), ["rig.json: camera cam03: R is not a rotation matrix (det=-1"]),
    "R scaled": (_cam(3, _scale_r), ["rig.json: camera cam03: R is not a rotation matrix (det=1.03"]),
    "dist 3": (_cam(1, _set("dist", [0.1, 0.2, 0.3])), ["rig.json", "camera cam01", "dist"]),
    "dist 6": (_cam(1, _set("dist", [0.1, 0.2, 0.3, 0.0, 0.0, 0.0])), ["rig.json", "camera cam01", "dist"]),
    "dist 8 rational": (_cam(1, _set("dist", [0.1, 0.2, 0, 0, 0, 0.5, 0, 0])), ["rig.json", "camera cam01", "dist", "k4"]),
    "dist string": (_cam(1, _set("dist", "none")), ["rig.json", "camera cam01", "dist"]),
    # images
    "images folder missing": (_rmtree("images"), ["images", "missing"]),
    "image missing": (_unlink("images/cam02.png"), ["camera cam02 has no image (images/cam02.png)"]),
    "image unknown camera": (_png("images/cam99.png", GREY), ["images/cam99.png: camera cam99 is not in rig.json"]),
    "image upper-case ext": (_png("images/cam98.PNG", GREY), ["images/cam98.PNG", ".png"]),
    "image truncated": (_truncate("images/cam01.png"), ["images/cam01.png", "truncated"]),
    "image corrupt": (_corrupt("images/cam01.png"), ["images/cam01.png", "unreadable"]),
    "image empty": (_write("images/cam01.png", b""), ["images/cam01.png", "empty"]),
    "image not png": (_write("images/cam01.png", b"\xff\xd8\xff\xe0 a jpeg"), ["images/cam01.png", "not a PNG"]),
    "image is folder": (lambda f: (_unlink("images/cam01.png")(f), (f / "images/cam01.png").mkdir()), ["images/cam01.png", "not a file"]),
    "image size": (_png("images/cam02.png", np.zeros((H, W - 4), np.uint8)), [f"images/cam02.png: size {W - 4}x{H}, rig.json says {W}x{H}"]),
    # backgrounds
    "background unknown camera": (_png("background/cam99.png", GREY), ["background/cam99.png: camera cam99 is not in rig.json"]),
    "background size": (_png("background/cam00.png", np.zeros((H + 2, W), np.uint16)), [f"background/cam00.png: size {W}x{H + 2}, rig.json says {W}x{H}"]),
    "background truncated": (_truncate("background/cam02.png"), ["background/cam02.png", "truncated"]),
    "background is file": (lambda f: (_rmtree("background")(f), (f / "background").write_text("x")), ["background", "not a folder"]),
    # capture.json
    "capture.json bad json": (_write("capture.json", '{"polarity": dark}'), ["capture.json: not valid JSON (line 1 column 14)"]),
    "capture.json not object": (_write("capture.json", '["dark-object"]'), ["capture.json", "object"]),
    "polarity invalid": (_write("capture.json", '{"polarity": "dark"}'), ["capture.json", "polarity", "dark"]),
    "part_id not string": (_write("capture.json", '{"part_id": 17}'), ["capture.json", "part_id"]),
    "timestamp invalid": (_write("capture.json", '{"timestamp": "yesterday"}'), ["capture.json", "timestamp", "yesterday"]),
    # truth
    "truth.json bad json": (_write("truth/truth.json", "{pose: 1}"), ["truth/truth.json: not valid JSON (line 1 column 2)"]),
    "truth.json not object": (_write("truth/truth.json", "3"), ["truth/truth.json", "object"]),
}


@pytest.mark.parametrize("mutate, expected", list(ERROR_CASES.values()), ids=list(ERROR_CASES))
def test_read_capture_errors(capture_dir: Path, mutate, expected: list[str]) -> None:
    mutate(capture_dir)
    with pytest.raises(CaptureError) as info:
        read_capture(capture_dir)
    msg = str(info.value)
    assert "\n" not in msg and msg.strip() == msg and msg
    for part in expected:
        assert part in msg, f"{part!r} not in {msg!r}"
    # Never a raw library exception as the cause the user would see.
    assert info.value.__cause__ is None


def test_errors_fuzz_rig_json(capture_dir: Path) -> None:
    """Random replacements of rig.json values give a valid rig or a one-line CaptureError."""
    rng = np.random.default_rng(11)
    original = json.loads((capture_dir / "rig.json").read_text())
    junk = [None, True, "x", "", [], {}, [[1]], -1, 0, 1e308, float("nan"), [1, 2, 3], [[1, 0, 0]] * 3, {"a": 1}]

    def paths(obj, prefix=()):
        yield prefix
        if isinstance(obj, dict):
            for k, v in obj.items():
                yield from paths(v, (*prefix, k))
        elif isinstance(obj, list):
            for i, v in enumerate(obj):
                yield from paths(v, (*prefix, i))

    all_paths = [p for p in paths(original) if p]
    failures = 0
    for _ in range(300):
        data = json.loads(json.dumps(original))
        p = all_paths[rng.integers(len(all_paths))]
        target = data
        for k in p[:-1]:
            target = target[k]
        target[p[-1]] = junk[rng.integers(len(junk))]
        (capture_dir / "rig.json").write_text(json.dumps(data))
        try:
            read_capture(capture_dir)
        except CaptureError as exc:
            failures += 1
            assert "\n" not in str(exc) and str(exc).startswith(("rig.json", "images/", "camera ", "background/"))
    assert failures > 100


def test_errors_fuzz_png_bytes(capture_dir: Path) -> None:
    """Cut or flipped PNG bytes: the capture reads, or a one-line CaptureError names the file."""
    rng = np.random.default_rng(12)
    for rel in ("images/cam01.png", "images/cam03.png", "background/cam02.png"):
        original = (capture_dir / rel).read_bytes()
        for _ in range(25):
            data = bytearray(original)
            if rng.random() < 0.5:
                data = data[: rng.integers(0, len(data))]
            else:
                for i in rng.integers(0, len(data), size=rng.integers(1, 4)):
                    data[i] ^= int(rng.integers(1, 256))
            (capture_dir / rel).write_bytes(bytes(data))
            try:
                read_capture(capture_dir)
            except CaptureError as exc:
                assert "\n" not in str(exc) and str(exc).startswith(rel), str(exc)
        (capture_dir / rel).write_bytes(original)


@pytest.mark.parametrize("key", ["polarity", "part_id", "timestamp"])
@pytest.mark.parametrize("value", [None, 1, 1.5, True, [], {}, "", "x"])
def test_capture_json_value_types(capture_dir: Path, key: str, value) -> None:
    (capture_dir / "capture.json").write_text(json.dumps({key: value}))
    try:
        cap = read_capture(capture_dir)
    except CaptureError as exc:
        assert str(exc).startswith("capture.json: ") and key in str(exc) and "\n" not in str(exc)
    else:
        assert cap.polarity in ("dark-object", "bright-object")
        assert value is None or (key == "part_id" and isinstance(value, str))


def test_capture_name_is_the_folder_name_as_given(capture_dir: Path, tmp_path: Path, monkeypatch) -> None:
    link = tmp_path / "line3-0042"
    link.symlink_to(capture_dir, target_is_directory=True)
    assert read_capture(link).name == "line3-0042"  # not the symlink's target
    monkeypatch.chdir(capture_dir)
    assert read_capture(".").name == "cap-001"


def test_decode_errors_name_the_first_bad_file_in_rig_order(capture_dir: Path) -> None:
    """Images are decoded in a thread pool; the error is still the first bad file in rig
    order (images before backgrounds), whichever decode fails first."""
    good = {rel: (capture_dir / rel).read_bytes() for rel in ("images/cam01.png", "images/cam03.png")}
    _corrupt("images/cam03.png")(capture_dir)
    _truncate("background/cam00.png")(capture_dir)
    _truncate("images/cam01.png")(capture_dir)
    expected = [
        "images/cam01.png: truncated PNG (no IEND chunk)",
        "images/cam03.png: unreadable PNG (corrupt data)",
        "background/cam00.png: truncated PNG (no IEND chunk)",
    ]
    for i, msg in enumerate(expected):
        for _ in range(3):  # the pool's timing varies; the message does not
            with pytest.raises(CaptureError) as info:
                read_capture(capture_dir)
            assert str(info.value) == msg and info.value.__cause__ is None
        if i < 2:
            rel = msg.split(":")[0]
            (capture_dir / rel).write_bytes(good[rel])
