"""The ``inspector`` CLI: CONTRACT exit codes, outputs, and one-line errors for bad input."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from inspector.outputs import read_ply
from inspector_frontends.cli import main

DEFAULT = str(Path(__file__).resolve().parents[2] / "recipes" / "default.toml")


def run_cli(*args: str) -> int:
    return main(list(args))


@pytest.fixture(scope="module")
def e2e(sim_captures, tmp_path_factory):
    out = tmp_path_factory.mktemp("e2e")
    code = run_cli("run", DEFAULT, "--capture", str(sim_captures["good"]), str(sim_captures["notched"]),
                   "--out", str(out), "--reference", "builtin:cube30")
    return code, out


@pytest.mark.slow
def test_good_cube_passes_and_notched_cube_fails(e2e, sim_captures):
    code, out = e2e
    assert code == 1  # one part failed
    good = json.loads((out / "good" / "result.json").read_text())
    bad = json.loads((out / "notched" / "result.json").read_text())
    assert good["verdict"] == "pass", good["defects"]
    assert good["defects"] == []
    assert bad["verdict"] == "fail"
    assert len(bad["defects"]) == 1
    d = bad["defects"][0]
    truth = json.loads((sim_captures["notched"] / "truth" / "truth.json").read_text())
    pose = np.array(truth["pose"])
    bump_world = pose[:3, :3] @ np.array([15.0, 15.0, 0.0]) + pose[:3, 3]
    assert np.linalg.norm(np.array(d["position"]) - bump_world) < 1.5
    assert d["kind"] == "missing" and d["worst_mm"] < -0.5


@pytest.mark.slow
def test_result_files_follow_the_contract(e2e):
    _, out = e2e
    res = json.loads((out / "good" / "result.json").read_text())
    assert set(res) >= {"capture", "recipe", "verdict", "error", "timings_s", "pose", "stats", "defects", "points"}
    assert res["capture"] == "good" and res["recipe"] == "default" and res["error"] is None
    assert set(res["timings_s"]) >= {"segment", "carve", "align", "bcps", "evaluate", "total"}
    assert np.array(res["pose"]).shape == (4, 4)
    assert res["points"] == {"bcps": "bcps_points.ply", "reconstruction": "reconstruction.ply"}
    pts = read_ply(out / "good" / "bcps_points.ply")
    assert {"x", "y", "z", "deviation", "confidence", "segment_mm"} <= set(pts) and len(pts["x"]) > 5000
    assert np.all((pts["confidence"] > 0) & (pts["confidence"] <= 1))
    assert 0 < res["stats"]["confidence"]["mean"] <= 1
    assert np.all(np.abs(pts["deviation"]) < 0.2)
    rec = read_ply(out / "good" / "reconstruction.ply")
    assert len(rec["x"]) > 1000


@pytest.mark.slow
def test_bcps_accuracy_against_truth(e2e):
    """Issue 2 bar: BCPS mean distance to the true surface <= 0.25 px footprint."""
    _, out = e2e
    res = json.loads((out / "good" / "result.json").read_text())
    t = res["stats"]["truth"]
    assert t["bcps"]["mean_px"] <= 0.25, t
    assert t["bcps"]["mean_mm"] < t["reconstruction"]["mean_mm"] / 5


# -- bad input ---------------------------------------------------------------------------
def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def _mut_rig(key_path, value):
    def f(folder: Path):
        rig = json.loads((folder / "rig.json").read_text())
        obj = rig
        for k in key_path[:-1]:
            obj = obj[k]
        obj[key_path[-1]] = value
        (folder / "rig.json").write_text(json.dumps(rig))
    return f


def _truncate(folder: Path):
    p = folder / "images" / "cam03.png"
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])


def _resize(folder: Path):
    import cv2

    p = folder / "images" / "cam02.png"
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(p), img[:-8])


def _blank(folder: Path):
    import cv2

    p = folder / "images" / "cam04.png"
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(p), np.full_like(img, 200))


def _drop_camera(folder: Path):
    rig = json.loads((folder / "rig.json").read_text())
    rig["cameras"] = [c for c in rig["cameras"] if c["name"] != "cam01"]
    (folder / "rig.json").write_text(json.dumps(rig))


BAD = [
    ("missing-image", lambda f: (f / "images" / "cam05.png").unlink(), "cam05"),
    ("unreadable-image", lambda f: (f / "images" / "cam06.png").write_bytes(b"not a png"), "cam06.png"),
    ("truncated-png", _truncate, "cam03.png"),
    ("size-mismatch", _resize, "cam02.png"),
    ("camera-not-in-rig", _drop_camera, "cam01"),
    ("R-not-rotation", _mut_rig(("cameras", 2, "R"), [[1, 0, 0], [0, 1, 0], [0, 0, 2]]), "cam02"),
    ("K-non-finite", _mut_rig(("cameras", 1, "K"), [[float("nan"), 0, 1], [0, 1, 1], [0, 0, 1]]), "cam01"),
    ("rig-not-json", lambda f: (f / "rig.json").write_text("{cameras: ["), "rig.json"),
    ("empty-silhouette", _blank, "cam04"),
]


@pytest.mark.parametrize("name, mutate, needle", BAD, ids=[b[0] for b in BAD])
def test_bad_capture_is_an_error_and_the_batch_goes_on(name, mutate, needle, small_capture, tmp_path, capsys):
    bad = _copy(small_capture, tmp_path / f"bad-{name}")
    mutate(bad)
    good = _copy(small_capture, tmp_path / "ok")
    out = tmp_path / "out"
    code = run_cli("run", DEFAULT, "--capture", str(bad), str(good), "--out", str(out), "--reference", "builtin:cube30", "-q")
    assert code == 3
    res = json.loads((out / bad.name / "result.json").read_text())
    assert res["verdict"] == "error"
    assert needle in res["error"] and "\n" not in res["error"]
    assert "Traceback" not in capsys.readouterr().err
    other = json.loads((out / "ok" / "result.json").read_text())
    assert other["verdict"] in ("pass", "fail")  # still inspected


def test_missing_capture_folder(tmp_path, small_capture):
    code = run_cli("run", DEFAULT, "--capture", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o"), "--reference", "builtin:cube30", "-q")
    assert code == 3
    res = json.loads((tmp_path / "o" / "nowhere" / "result.json").read_text())
    assert res["verdict"] == "error" and "nowhere" in res["error"]


def test_quiet_mode_still_prints_an_error_on_stderr(tmp_path, small_capture, capsys):
    code = run_cli("run", DEFAULT, "--capture", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o"),
                   "--reference", "builtin:cube30", "-q")
    assert code == 3
    out, err = capsys.readouterr()
    assert out == ""
    assert err.strip() == f"inspector: error: nowhere: capture folder {tmp_path / 'nowhere'}: does not exist"


@pytest.mark.parametrize("how, needle", [("file", "is a file, not a folder"), ("under-a-file", "cannot create the result folder")])
def test_an_unwritable_result_folder_is_a_command_error_before_any_inspection(how, needle, tmp_path, small_capture, capsys):
    blocker = tmp_path / "blocker"
    blocker.write_text("not a folder")
    out = blocker if how == "file" else blocker / "results"
    code = run_cli("run", DEFAULT, "--capture", str(small_capture), "--out", str(out), "--reference", "builtin:cube30")
    assert code == 2
    line = _stderr_line(capsys)
    assert line.startswith(f"inspector: error: --out {out}: ") and needle in line
    assert capsys.readouterr().out == ""  # nothing inspected


def test_two_captures_of_the_same_name_are_refused_and_one_given_twice_is_inspected_once(tmp_path, small_capture, capsys):
    a = _copy(small_capture, tmp_path / "day1" / "part7")
    b = _copy(small_capture, tmp_path / "day2" / "part7")
    code = run_cli("run", DEFAULT, "--capture", str(a), str(b), "--out", str(tmp_path / "o"), "--reference", "builtin:cube30")
    assert code == 2
    assert _stderr_line(capsys) == (f"inspector: error: --capture: {a} and {b} are both named 'part7'; "
                                    "their results would overwrite each other in OUTDIR/part7/")
    assert not (tmp_path / "o" / "part7").exists()
    code = run_cli("run", DEFAULT, "--capture", str(a), str(a), "--out", str(tmp_path / "o"), "--reference", "builtin:cube30")
    assert code in (0, 1)
    assert "1 inspected" in capsys.readouterr().out


def _stderr_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and "Traceback" not in "\n".join(err)
    return err[-1]


def test_reference_missing_is_invalid(tmp_path, small_capture, capsys):
    code = run_cli("run", DEFAULT, "--capture", str(small_capture), "--out", str(tmp_path / "o"), "--reference", str(tmp_path / "none.stl"))
    assert code == 2
    assert "none.stl" in _stderr_line(capsys)
    assert not (tmp_path / "o").exists()  # nothing inspected


def test_reference_not_watertight_is_invalid(tmp_path, small_capture, capsys):
    import trimesh

    m = trimesh.creation.box((30, 30, 30))
    m.update_faces(np.arange(len(m.faces)) != 0)
    m.export(tmp_path / "open.stl")
    code = run_cli("run", DEFAULT, "--capture", str(small_capture), "--out", str(tmp_path / "o"), "--reference", str(tmp_path / "open.stl"))
    assert code == 2
    line = _stderr_line(capsys)
    assert "open.stl" in line and "watertight" in line


@pytest.mark.parametrize(
    "text, needle",
    [
        ('[[stages]]\nuse = "segment.magic"\n', "unknown stage 'segment.magic'"),
        ('[[stages]]\nuse = "segment.threshold"\nparams = { polarty = "dark-object" }\n', "unknown parameter 'polarty'"),
    ],
)
def test_bad_recipe_is_invalid(text, needle, tmp_path, small_capture, capsys):
    r = tmp_path / "bad.toml"
    r.write_text(text)
    code = run_cli("run", str(r), "--capture", str(small_capture), "--out", str(tmp_path / "o"))
    assert code == 2
    line = _stderr_line(capsys)
    assert "bad.toml" in line and needle in line


def test_recipe_check_and_plugins(capsys):
    assert run_cli("recipe", "check", DEFAULT, "--reference", "builtin:cube30") == 0
    assert "OK" in capsys.readouterr().out
    assert run_cli("plugins", "--json") == 0
    doc = json.loads(capsys.readouterr().out)
    assert "bcps.ray" in doc["stages"] and "sim" in doc["drivers"]
    assert any(p["name"] == "voxel_mm" for p in doc["stages"]["carve.hull"]["params"])


def test_usage_error_exit_code():
    with pytest.raises(SystemExit) as e:
        run_cli("run")
    assert e.value.code == 2


def test_console_script_runs_without_traceback(tmp_path):
    exe = Path(sys.executable).with_name("inspector")
    p = subprocess.run([str(exe), "recipe", "check", str(tmp_path / "x.toml")], capture_output=True, text=True)
    assert p.returncode == 2
    assert p.stderr.strip().count("\n") == 0 and "x.toml" in p.stderr and "Traceback" not in p.stderr


@pytest.mark.slow
def test_foreign_capture_in_metres_with_a_file_reference(tmp_path):
    """A capture written by another program (plain json + cv2, rig in metres, 16-bit images):
    a Ø30 sphere in a random pose, reference given as an STL file."""
    import cv2

    from inspector.parts import make_part
    from inspector_drivers.sim.render import render_coverage, to_image
    from inspector_drivers.sim.rig import sphere_rig
    from inspector_drivers.sim.simulate import random_pose

    rng = np.random.default_rng(42)
    rig = sphere_rig(16)
    part = make_part("sphere30")
    pose = random_pose(rng, 6.0)
    world = part.copy()
    world.apply_transform(pose)
    cover = render_coverage(world, rig)
    folder = tmp_path / "foreign-sphere"
    (folder / "images").mkdir(parents=True)
    cams = []
    for cam in rig.cameras:
        img = to_image(cover[cam.name], rng=rng, noise_sigma=2.0, bit_depth=16)
        cv2.imwrite(str(folder / "images" / f"{cam.name}.png"), img)
        cams.append({"name": cam.name, "width": cam.width, "height": cam.height, "K": cam.K.tolist(),
                     "R": cam.R.tolist(), "t": (cam.t / 1000.0).tolist()})
    (folder / "rig.json").write_text(json.dumps({"units": "m", "cameras": cams}))
    ref = tmp_path / "sphere.stl"
    part.export(ref)
    out = tmp_path / "out"
    code = run_cli("run", DEFAULT, "--capture", str(folder), "--out", str(out), "--reference", str(ref), "-q")
    res = json.loads((out / "foreign-sphere" / "result.json").read_text())
    assert code == 0, res
    pts = read_ply(out / "foreign-sphere" / "bcps_points.ply")
    P = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(float)
    err = np.abs(np.linalg.norm(P - pose[:3, 3], axis=1) - 15.0)
    assert err.mean() <= 0.025, err.mean()  # 0.25 px footprint
    pose_est = np.array(res["pose"])
    assert np.linalg.norm(pose_est[:3, 3] - pose[:3, 3]) < 0.02


@pytest.mark.slow
def test_report_draws_the_deviation_picture(e2e):
    import cv2

    _, out = e2e
    assert run_cli("report", str(out)) == 0
    img = cv2.imread(str(out / "notched" / "deviation.png"))
    assert img is not None and img.shape[0] > 300 and img.shape[1] > 800
    # Not a blank page: the scatter and the colour bar put many colours on it.
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 50


def _result_folder(folder: Path, **changes) -> Path:
    """A result folder as `inspector run` writes it (CONTRACT), with ``changes`` to result.json."""
    from inspector.outputs import write_ply

    folder.mkdir(parents=True)
    rng = np.random.default_rng(3)
    xyz = rng.normal(0.0, 10.0, (500, 3)).astype(np.float32)
    write_ply(folder / "bcps_points.ply", {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2],
                                           "deviation": rng.normal(0.0, 0.03, 500).astype(np.float32)})
    res = {"capture": folder.name, "recipe": "default", "verdict": "pass", "error": None, "timings_s": {},
           "pose": np.eye(4).tolist(), "stats": {}, "defects": [],
           "points": {"bcps": "bcps_points.ply", "reconstruction": None}}
    res.update(changes)
    (folder / "result.json").write_text(json.dumps({k: v for k, v in res.items() if v is not ...}))
    return folder


def test_report_names_the_damaged_file_and_draws_the_others(tmp_path, capsys):
    good = _result_folder(tmp_path / "r" / "a-good")
    _result_folder(tmp_path / "r" / "b-nopose", pose=...)
    cut = _result_folder(tmp_path / "r" / "c-truncated")
    data = (cut / "bcps_points.ply").read_bytes()
    (cut / "bcps_points.ply").write_bytes(data[: len(data) // 2])
    gone = _result_folder(tmp_path / "r" / "d-noply")
    (gone / "bcps_points.ply").unlink()
    assert run_cli("report", str(tmp_path / "r")) == 3
    out, err = capsys.readouterr()
    assert out.strip() == f"wrote {good / 'deviation.png'}"
    r = tmp_path / "r"
    lines = err.strip().splitlines()
    assert len(lines) == 3
    assert lines[0] == f"inspector: error: {r / 'b-nopose' / 'result.json'}: missing key 'pose'"
    assert lines[1].startswith(f"inspector: error: {r / 'c-truncated' / 'bcps_points.ply'}: not a readable PLY (")
    assert lines[1].endswith("early end-of-file)")
    assert lines[2] == f"inspector: error: {r / 'd-noply' / 'bcps_points.ply'}: missing (result.json names it)"


def test_a_bug_is_one_line_for_the_user_and_its_traceback_is_kept(monkeypatch, tmp_path, capsys):
    import inspector_frontends.cli as cli

    def broken(args):
        raise RuntimeError("something\nunexpected")

    monkeypatch.setattr(cli, "_plugins", broken)
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)  # re-read TMPDIR
    assert run_cli("plugins") == 3
    err = capsys.readouterr().err
    saved = list(tmp_path.glob("inspector-traceback-*.txt"))
    assert len(saved) == 1
    assert err == f"inspector: error: internal error RuntimeError: something unexpected (traceback in {saved[0]})\n"
    assert "Traceback" in saved[0].read_text() and "raise RuntimeError" in saved[0].read_text()


def test_a_batch_keeps_no_inspection_in_memory_once_it_is_written(monkeypatch, tmp_path, small_capture):
    # A live driver runs for days: each result (points, reconstruction, 5 MB) must be
    # released once written, not kept until the end of the run.
    import gc
    import weakref

    import inspector.runner as runner

    run_batch, refs, kept = runner.run_batch, [], []

    def watched(*args, **kwargs):
        for outcome in run_batch(*args, **kwargs):
            gc.collect()
            kept.append(sum(ref() is not None for ref in refs))  # earlier results still in memory
            refs.append(weakref.ref(outcome.result))
            yield outcome

    monkeypatch.setattr(runner, "run_batch", watched)
    caps = [_copy(small_capture, tmp_path / "c" / f"part{i}") for i in range(3)]
    assert run_cli("run", DEFAULT, "--capture", *map(str, caps), "--out", str(tmp_path / "o"),
                   "--reference", "builtin:cube30", "-q") in (0, 1)
    assert kept == [0, 0, 0]


def test_a_capability_warning_is_printed_once_per_run_and_kept_in_each_result(tmp_path, small_capture, capsys):
    caps = [_copy(small_capture, tmp_path / "c" / f"part{i}") for i in range(2)]  # a 0.4 mm/px rig, +-0.1 mm
    run_cli("run", DEFAULT, "--capture", *map(str, caps), "--out", str(tmp_path / "o"), "--reference", "builtin:cube30", "-q")
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("inspector: warning: ")]
    assert len(warnings) == 1 and warnings[0].startswith("inspector: warning: part0: tolerance [-0.1, +0.1] mm is 0.25 px")
    for i in range(2):
        res = json.loads((tmp_path / "o" / f"part{i}" / "result.json").read_text())
        assert res["stats"]["warnings"] == [warnings[0].split(": ", 3)[3]]


def test_report_shows_the_result_warnings_under_the_picture(tmp_path):
    import cv2

    def red_in_bottom_band(folder: Path) -> int:
        assert run_cli("report", str(folder)) == 0
        img = cv2.imread(str(folder / "deviation.png"))  # BGR
        band = img[int(img.shape[0] * 0.9):].astype(int)
        return int(((band[..., 2] > 140) & (band[..., 1] < 80) & (band[..., 0] < 80)).sum())

    plain = _result_folder(tmp_path / "plain")
    warned = _result_folder(tmp_path / "warned", stats={"warnings": ["tolerance [-0.1, +0.1] mm is 0.40 px at this rig's "
                                                                      "0.25 mm pixel footprint"]})
    assert red_in_bottom_band(plain) == 0 and red_in_bottom_band(warned) > 200
