"""``inspector calibrate TARGET.toml --captures DIR --out RIG.json`` end to end on small rendered
captures of the calibration cube (8 cameras, 320 x 320 px, 10 poses), and its bad inputs:
one line, exit 2, nothing written."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from inspector_frontends.cli import main

ROOT = Path(__file__).resolve().parents[2]
CUBE = ROOT / "examples" / "calibration" / "charuco_cube.toml"


@pytest.fixture(scope="module")
def captures(tmp_path_factory) -> Path:
    """10 poses of the cube seen by 8 cameras (f = 1600 px on 320^2, k1 = 0.1, blur, noise 2)."""
    from inspector.calibration.target import load_target
    from inspector.capture_folder import save_capture
    from inspector_drivers.sim.rig import sphere_rig
    from inspector_drivers.sim.target import simulate_target

    root = tmp_path_factory.mktemp("target_captures")
    rig = sphere_rig(8, width=320, height=320, mm_per_px=0.25, dist=[0.1])
    for cap in simulate_target(load_target(CUBE), rig, 10, seed=3):
        save_capture(cap, root / cap.name)
    return root


@pytest.fixture(scope="module")
def calibrated(captures, tmp_path_factory):
    import contextlib
    import io

    out = tmp_path_factory.mktemp("calibrated") / "rig.json"
    so, se = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
        rc = main(["calibrate", str(CUBE), "--captures", str(captures), "--out", str(out)])
    return rc, out, so.getvalue(), se.getvalue()


@pytest.fixture(scope="module")
def few_captures(captures, tmp_path_factory) -> Path:
    """Three of the poses (what the refusals need, detected faster)."""
    root = tmp_path_factory.mktemp("few_captures")
    for d in sorted(captures.iterdir())[:3]:
        shutil.copytree(d, root / d.name)
    return root


def _one_line_exit_2(capsys, argv, *, must: str, out: Path | None = None) -> str:
    rc = main(argv)
    cap = capsys.readouterr()
    errs = [line for line in cap.err.splitlines() if not line.startswith("calibrate: ")]
    assert rc == 2, cap.err
    assert len(errs) == 1, cap.err
    assert must in errs[0], errs[0]
    if out is not None:
        assert not out.exists()
        assert not out.with_name(f"{out.stem}_report").exists()
    return errs[0]


def test_calibrates_the_rig_from_rendered_captures(calibrated, captures):
    from inspector.capture_folder import read_rig
    from inspector.kernels.calibration import compare_rigs

    rc, out, stdout, stderr = calibrated
    assert rc == 0, stderr
    data = json.loads(out.read_text())
    assert data["units"] == "mm"
    cams = data["cameras"]
    assert [c["name"] for c in cams] == [f"cam{i:02d}" for i in range(8)]
    assert set(cams[0]) == {"name", "width", "height", "K", "dist", "R", "t"}
    cal = data["calibration"]
    assert {"date", "target", "poses", "rms_px", "rejected_boards", "cameras"} <= set(cal)
    assert cal["poses"] == 10 and cal["target"]["kind"] == "charuco_cube" and 0 < cal["rms_px"] < 0.3
    # against the truth (the captures' rig.json), after a similarity
    est = read_rig(out)
    true = read_rig(captures / "pose_000" / "rig.json")
    cmp = compare_rigs(list(est.cameras), list(true.cameras), radius_mm=15.0)
    assert cmp["rms_px"].max() < 0.5
    assert np.abs(cmp["f_err"]).max() < 0.08
    assert abs(cmp["scale"] - 1.0) < 2e-3
    # a narrow lens (half diagonal / f = 0.14): k2 and k3 are not observable and stay 0
    assert all(c.dist[1] == 0.0 and c.dist[4] == 0.0 for c in est)
    # the frame: origin at the point nearest the optical axes
    from inspector.kernels.calibration import nearest_point_to_lines

    origin = nearest_point_to_lines(np.array([c.centre for c in est]), np.array([c.R[2] for c in est]))
    assert np.linalg.norm(origin) < 1e-6
    # progress per stage, the report as text, its files
    for stage in ("detecting", "initialising", "adjusting", "writing"):
        assert f"calibrate: {stage}" in stderr
    # each stage's seconds, and the command's own benchmark line (also in report.json)
    import re

    assert re.search(r"calibrate: found \d+ boards, \d+ corners \(detection [\d.]+ s\)", stderr)
    assert re.search(r"calibrate: done in [\d.]+ s \([\d.]+ s of CPU\): detection [\d.]+ s, initialisation [\d.]+ s, "
                     r"adjustment [\d.]+ s, uncertainty [\d.]+ s, writing [\d.]+ s", stderr), stderr
    assert re.search(r"^Time: [\d.]+ s", stdout, re.M)
    assert "cam07" in stdout and "RMS" in stdout
    rep = out.with_name("rig_report")
    report = json.loads((rep / "report.json").read_text())
    assert len(report["cameras"]) == 8
    c0 = report["cameras"][0]
    for key in ("rms_px", "max_px", "corners", "views", "coverage_pct", "centre_std_mm", "angle_std_deg"):
        assert c0[key] is not None and c0[key] >= 0
    assert 0 < c0["coverage_pct"] <= 100 and c0["views"] <= 10
    t = report["timings_s"]
    assert {"detect_s", "initialise_s", "adjust_s", "covariance_s", "write_s", "command_s", "cpu_s"} <= set(t)
    assert t["command_s"] >= t["detect_s"] + t["adjust_s"]
    assert (rep / "corners_all.png").stat().st_size > 1000
    assert (rep / "corners_cam03.png").is_file()


def test_refuses_to_overwrite_without_force_and_json_report(calibrated, captures, capsys):
    rc, out, _, _ = calibrated
    before = out.read_text()
    _one_line_exit_2(capsys, ["calibrate", str(CUBE), "--captures", str(captures), "--out", str(out)],
                     must="exists (use --force")
    assert out.read_text() == before
    rep = out.parent / "other_report"
    assert main(["calibrate", str(CUBE), "--captures", str(captures), "--out", str(out), "--force", "--json",
                 "--report", str(rep)]) == 0
    cap = capsys.readouterr()
    summary = json.loads(cap.out)
    assert summary["poses"] == 10 and len(summary["cameras"]) == 8
    assert (rep / "report.json").is_file() and (rep / "corners_all.png").is_file()
    assert json.loads(out.read_text())["calibration"]["date"]


def _blank_captures(root: Path, names: list[str], n: int = 2, size: int = 64) -> Path:
    import cv2

    for i in range(n):
        d = root / f"pose_{i:03d}" / "images"
        d.mkdir(parents=True)
        for name in names:
            cv2.imwrite(str(d / f"{name}.png"), np.full((size, size), 90 + 10 * i, np.uint8))
    return root


def test_a_folder_without_the_target(tmp_path, capsys):
    caps = _blank_captures(tmp_path / "caps", ["cam00", "cam01"])
    out = tmp_path / "rig.json"
    _one_line_exit_2(capsys, ["calibrate", str(CUBE), "--captures", str(caps), "--out", str(out)],
                     must="no target in the images", out=out)


def test_captures_of_parts_instead_of_the_target(tmp_path, capsys):
    """A folder of ordinary captures (a part, no target): one line, nothing written."""
    from inspector.capture_folder import save_capture
    from inspector_drivers.sim.simulate import SimParams, sim_rig, simulate

    p = SimParams(part="cube30", cameras=3, width=160, height=160, mm_per_px=0.3, supersample=1)
    rig = sim_rig(p)
    caps = tmp_path / "parts"
    for i in range(2):
        save_capture(simulate(p, i, rig), caps / f"part-{i}")
    out = tmp_path / "rig.json"
    _one_line_exit_2(capsys, ["calibrate", str(CUBE), "--captures", str(caps), "--out", str(out)],
                     must="no target in the images", out=out)


def test_a_camera_that_never_sees_the_target(few_captures, tmp_path, capsys):
    import cv2

    caps = tmp_path / "caps"
    shutil.copytree(few_captures, caps, ignore=shutil.ignore_patterns("truth", "rig.json"))
    for d in sorted(caps.iterdir()):
        cv2.imwrite(str(d / "images" / "cam99.png"), np.full((320, 320), 90, np.uint8))
    out = tmp_path / "rig.json"
    line = _one_line_exit_2(capsys, ["calibrate", str(CUBE), "--captures", str(caps), "--out", str(out)],
                            must="camera cam99 never sees the target", out=out)
    assert "show the target to cam99" in line


@pytest.mark.parametrize("change, must", [
    (("DICT_5X5_1000", "DICT_4X4_1000"), "the target description does not match the images"),
    (("squares = [5, 5]", "squares = [4, 4]"), "the target description does not match the images"),
    (("squares = [5, 5]", "squares = [6, 6]"), "the target description does not match the images"),
    (("DICT_5X5_1000", "DICT_6X6_250"), "the target description does not match the images"),
    (("marker_mm = 5.0", "marker_mm = 5.0\nmarkers = 3"), "unknown key target.markers"),
    (("square_mm = 7.0", "squares_mm = 7.0"), "unknown key target.squares_mm"),
    (("side_mm = 40.0", "side_mm = 40.0\n[board]\nx = 1"), "unknown table or key 'board' (expected only [target])"),
    (("DICT_5X5_1000", "DICT_5X5_999"), "target.dictionary 'DICT_5X5_999' is not an OpenCV predefined dictionary"),
    (("kind = \"charuco_cube\"", "kind = \"cube\""), "target.kind must be one of"),
])
def test_a_target_description_that_does_not_match(few_captures, tmp_path, capsys, change, must):
    text = CUBE.read_text().replace(*change)
    if "[6, 6]" in text:  # 6 x 7 mm boards need a bigger cube (else load_target refuses it first)
        text = text.replace("side_mm = 40.0", "side_mm = 44.0")
    toml = tmp_path / "target.toml"
    toml.write_text(text)
    out = tmp_path / "rig.json"
    _one_line_exit_2(capsys, ["calibrate", str(toml), "--captures", str(few_captures), "--out", str(out)], must=must, out=out)


def test_bad_command_lines(captures, tmp_path, capsys):
    out = tmp_path / "rig.json"
    _one_line_exit_2(capsys, ["calibrate", str(CUBE), "--captures", str(captures)], must="--out", out=out)
    _one_line_exit_2(capsys, ["calibrate", str(CUBE), "--captures", str(tmp_path / "nowhere"), "--out", str(out)],
                     must="no such folder", out=out)
    (tmp_path / "empty").mkdir()
    _one_line_exit_2(capsys, ["calibrate", str(CUBE), "--captures", str(tmp_path / "empty"), "--out", str(out)],
                     must="no capture folder", out=out)
    _one_line_exit_2(capsys, ["calibrate", str(tmp_path / "none.toml"), "--captures", str(captures), "--out", str(out)],
                     must="no such target file", out=out)
    _one_line_exit_2(capsys, ["calibrate", str(CUBE), "--captures", str(captures), "--out", str(tmp_path / "no" / "rig.json")],
                     must="no such folder")


def test_a_camera_seen_too_little_is_named_with_what_to_do(captures, tmp_path, capsys):
    import cv2

    caps = tmp_path / "caps"
    shutil.copytree(captures, caps, ignore=shutil.ignore_patterns("truth"))
    for d in sorted(caps.iterdir())[3:]:  # cam03 sees the target in the first 3 poses only
        cv2.imwrite(str(d / "images" / "cam03.png"), np.full((320, 320), 90, np.uint8))
    out = tmp_path / "rig.json"
    assert main(["calibrate", str(CUBE), "--captures", str(caps), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "Seen too little:" in text
    line = next(x for x in text.splitlines() if x.strip().startswith("cam03:"))
    assert "the target seen in 3 poses" in line and "show it to cam03 in more poses" in line
    report = json.loads((tmp_path / "rig_report" / "report.json").read_text())
    assert [a.split(":")[0] for a in report["advice"]] == ["cam03"]
    cam03 = next(c for c in report["cameras"] if c["name"] == "cam03")
    others = [c["centre_std_mm"] for c in report["cameras"] if c["name"] != "cam03"]
    assert cam03["views"] == 3 and cam03["centre_std_mm"] > max(others)


def test_capture_help_says_how_to_take_calibration_captures(capsys):
    with pytest.raises(SystemExit) as e:
        main(["capture", "--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    assert "calibration captures" in text and "one capture folder" in text and "per pose of the calibration target" in text
    assert "inspector calibrate TARGET.toml --captures calib/" in text
    assert "inspector calibrate --background --captures empty/ --out cell/" in text
