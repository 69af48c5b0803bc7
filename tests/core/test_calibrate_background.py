"""``inspector calibrate --background --captures DIR --out FOLDER``: each camera's empty field,
several frames averaged, stored as ``FOLDER/background/<camera>.png`` where the segmentation
finds it; its bad inputs one line, exit 2, nothing written. Real files: frames of a vignetted,
dusty field with noise written as capture folders."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from inspector_frontends.cli import main

SIZE = 96
CAMS = ("cam00", "cam01", "cam02")


def _field(k: int) -> np.ndarray:
    """Camera ``k``'s noise-free empty field (SIZE, SIZE) float: 200 at the centre, vignetted to
    ~65 % at the corners, two dark specks."""
    y, x = np.mgrid[0:SIZE, 0:SIZE].astype(float)
    r2 = ((x - SIZE / 2) ** 2 + (y - SIZE / 2) ** 2) / (SIZE / 2) ** 2 / 2.0
    f = 200.0 * (1.0 - 0.35 * r2)
    f[20 + k:22 + k, 30:32] *= 0.3
    f[60, 70 - k] *= 0.5
    return f


def _frames(root: Path, n: int = 5, seed: int = 0, cams: tuple[str, ...] = CAMS) -> Path:
    rng = np.random.default_rng(seed)
    for i in range(n):
        d = root / f"frame_{i:03d}" / "images"
        d.mkdir(parents=True)
        for k, name in enumerate(cams):
            img = np.clip(np.rint(_field(k) + rng.normal(0.0, 2.0, (SIZE, SIZE))), 0, 255).astype(np.uint8)
            cv2.imwrite(str(d / f"{name}.png"), img)
    return root


def _one_line_exit_2(capsys, argv: list[str], must: str, nothing: Path) -> str:
    before = sorted(p.relative_to(nothing) for p in nothing.rglob("*")) if nothing.exists() else None
    rc = main(argv)
    cap = capsys.readouterr()
    errs = [line for line in cap.err.splitlines() if not line.startswith("calibrate: ")]
    assert rc == 2, cap.err
    assert len(errs) == 1, cap.err
    assert must in errs[0], errs[0]
    after = sorted(p.relative_to(nothing) for p in nothing.rglob("*")) if nothing.exists() else None
    assert after == before, "something was written"
    return errs[0]


def test_averages_the_frames_where_segmentation_finds_them(tmp_path, capsys):
    from inspector.capture_folder import read_capture, write_capture
    from inspector.model import Rig
    from inspector_drivers.sim.rig import sphere_rig
    from inspector_plugins.segment import SegmentParams, segment_camera

    frames = _frames(tmp_path / "empty", n=5)
    # the cell's folder: its rig (names and sizes must match the frames) and later a capture
    rig = Rig(tuple(sphere_rig(3, width=SIZE, height=SIZE, mm_per_px=1.0).cameras))
    cell = tmp_path / "cell"
    cell.mkdir()
    (cell / "rig.json").write_text(json.dumps(rig.to_json()))
    assert main(["calibrate", "--background", "--captures", str(frames), "--out", str(cell)]) == 0
    out = capsys.readouterr()
    assert "calibrate: averaging the empty field of 3 cameras over 5 frames" in out.err
    assert "cam02" in out.out and "5 frames averaged" in out.out
    meta = json.loads((cell / "background.json").read_text())
    assert meta["frames"] == 5 and set(meta["cameras"]) == set(CAMS)
    for k, name in enumerate(CAMS):
        bg = cv2.imread(str(cell / "background" / f"{name}.png"), cv2.IMREAD_UNCHANGED)
        assert bg.dtype == np.uint8 and bg.shape == (SIZE, SIZE)
        err = bg.astype(float) - _field(k)
        # five frames of sigma 2 averaged (0.89) and rounded (0.29): about 0.95 RMS; one frame is 2
        assert np.sqrt(np.mean(err**2)) < 1.3
        assert abs(meta["cameras"][name]["noise"] - 2.0) < 0.4
        assert meta["cameras"][name]["level"][1] > 190 and meta["cameras"][name]["level"][0] < 150

    # a capture of a dark part on that field, with the reference copied in: the segment stage
    # flat-fields against it
    rng = np.random.default_rng(5)
    images = {}
    for k, name in enumerate(CAMS):
        f = _field(k)
        f[30:70, 35:75] = 40.0
        images[name] = np.clip(np.rint(f + rng.normal(0, 2.0, f.shape)), 0, 255).astype(np.uint8)
    part = write_capture(tmp_path / "part-0001", rig, images)
    shutil.copytree(cell / "background", part / "background")
    cap = read_capture(part)
    assert set(cap.backgrounds) == set(CAMS)
    sil, report = segment_camera(cap.images["cam01"], cap.backgrounds["cam01"], cap.polarity, SegmentParams(), "cam01")
    assert report["background"] == "image"
    assert abs(float(sil.soft.sum()) - 40 * 40) < 40

    # again without --force: refused, nothing replaced; with --force: replaced
    _one_line_exit_2(capsys, ["calibrate", "--background", "--captures", str(frames), "--out", str(cell)],
                     must="exists (use --force", nothing=cell)
    assert main(["calibrate", "--background", "--captures", str(frames), "--out", str(cell), "--force", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 5


def test_a_camera_missing_from_some_frames_is_averaged_over_the_others(tmp_path, capsys):
    frames = _frames(tmp_path / "empty", n=4)
    (frames / "frame_002" / "images" / "cam01.png").unlink()
    out = tmp_path / "cell"
    assert main(["calibrate", "--background", "--captures", str(frames), "--out", str(out), "--json"]) == 0
    meta = json.loads(capsys.readouterr().out)
    assert meta["cameras"]["cam01"]["frames"] == 3 and meta["cameras"]["cam00"]["frames"] == 4
    assert any(n.startswith("cam01: 3 of 4 frames") for n in meta["notes"])


def test_something_moved_in_one_frame(tmp_path, capsys):
    frames = _frames(tmp_path / "empty", n=4)
    p = frames / "frame_002" / "images" / "cam01.png"
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    img[40:50, 40:50] = 60  # a hand passing: 100 px of 9216
    cv2.imwrite(str(p), img)
    out = tmp_path / "cell"
    line = _one_line_exit_2(capsys, ["calibrate", "--background", "--captures", str(frames), "--out", str(out)],
                            must="frame_002/images/cam01.png: differs from the other frames of camera cam01",
                            nothing=tmp_path)
    assert "something moved" in line


def test_a_field_that_is_not_empty(tmp_path, capsys):
    frames = _frames(tmp_path / "empty", n=3)
    for d in frames.iterdir():  # a part left in the rig, in every frame
        p = d / "images" / "cam02.png"
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        img[30:60, 30:60] = 40
        cv2.imwrite(str(p), img)
    _one_line_exit_2(capsys, ["calibrate", "--background", "--captures", str(frames), "--out", str(tmp_path / "cell")],
                     must="camera cam02: 9.8 % of its empty field is darker than half the background level (",
                     nothing=tmp_path)


@pytest.mark.parametrize("case", ["depth", "rig-size", "rig-camera", "no-frames", "out-file", "with-target"])
def test_bad_inputs(tmp_path, capsys, case):
    from inspector.model import Rig
    from inspector_drivers.sim.rig import sphere_rig

    frames = _frames(tmp_path / "empty", n=3)
    out = tmp_path / "cell"
    argv = ["calibrate", "--background", "--captures", str(frames), "--out", str(out)]
    if case == "depth":
        p = frames / "frame_001" / "images" / "cam00.png"
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(p), img.astype(np.uint16) * 257)
        must = "frame_001/images/cam00.png: 96x96, 16-bit, 1 channel, but camera cam00 is 96x96, 8-bit, 1 channel"
    elif case in ("rig-size", "rig-camera"):
        n, size = (3, 128) if case == "rig-size" else (4, SIZE)
        out.mkdir()
        rig = Rig(tuple(sphere_rig(n, width=size, height=size, mm_per_px=1.0).cameras))
        (out / "rig.json").write_text(json.dumps(rig.to_json()))
        must = ("camera cam00 is 128x128, its empty-field frames are 96x96" if case == "rig-size"
                else "camera cam03 has no empty-field frame")
    elif case == "no-frames":
        argv[argv.index(str(frames))] = str(tmp_path / "nothing")
        (tmp_path / "nothing").mkdir()
        must = "no capture folder in it"
    elif case == "out-file":
        out.write_text("x")
        must = "is a file, not a folder"
    else:
        argv.insert(1, "examples/calibration/charuco_cube.toml")
        must = "TARGET.toml is not used here"
    _one_line_exit_2(capsys, argv, must=must, nothing=tmp_path)


def test_a_live_driver_attaches_the_reference_to_every_capture(tmp_path, capsys):
    """The hardware drivers' ``rig`` parameter names the cell's folder: its background/ comes
    with every capture (so ``inspector capture`` writes it into each capture folder)."""
    from types import SimpleNamespace

    from inspector.capture_folder import read_capture, save_capture
    from inspector.errors import InputError
    from inspector.model import Rig
    from inspector_drivers.genicam.common import Frame, LiveDriver
    from inspector_drivers.sim.rig import sphere_rig

    rig = Rig(tuple(sphere_rig(3, width=SIZE, height=SIZE, mm_per_px=1.0).cameras))
    cell = tmp_path / "cell"
    cell.mkdir()
    (cell / "rig.json").write_text(json.dumps(rig.to_json()))

    class Session:
        trigger_mode = "software"

        def trigger(self):
            return {n: Frame(np.full((SIZE, SIZE), 120, np.uint8)) for n in CAMS}, {}

        def close(self):
            pass

    class Driver(LiveDriver):
        name = "fake"

        def _open_session(self):
            return Session()

    params = SimpleNamespace(rig=str(cell), serials={n: f"SN{k}" for k, n in enumerate(CAMS)}, count=1)
    assert Driver(params).capture("a").backgrounds == {}  # no reference yet: none attached
    assert main(["calibrate", "--background", "--captures", str(_frames(tmp_path / "empty", n=4)), "--out", str(cell)]) == 0
    capsys.readouterr()
    for where in (str(cell), str(cell / "rig.json")):
        cap = Driver(SimpleNamespace(**{**vars(params), "rig": where})).capture("b")
        assert set(cap.backgrounds) == set(CAMS)
        ref = cv2.imread(str(cell / "background" / "cam01.png"), cv2.IMREAD_UNCHANGED)
        assert np.array_equal(cap.backgrounds["cam01"], ref)
    saved = read_capture(save_capture(cap, tmp_path / "captures" / "b"))
    assert set(saved.backgrounds) == set(CAMS)
    (cell / "background" / "cam02.png").unlink()
    with pytest.raises(InputError, match=r"fake: .*cam02.png: missing \(every camera needs its empty-field image"):
        Driver(params)
