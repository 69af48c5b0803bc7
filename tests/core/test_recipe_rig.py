"""Recipes checked against the rig they run on (issue 27 finding 6).

``min_cameras = 17`` on a 16-camera rig, or ``min_points = 1000000``, passed the notched
cube with exit 0: in range for the parameter, impossible for the rig. Now a value no part of
the rig could ever meet is refused in one line naming the key and the rig (exit 2, nothing
written), at inspection and by ``inspector recipe check --rig``; ``min_points`` above what one
part gave makes that part an error, never a pass.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from inspector_frontends.cli import main

ROOT = Path(__file__).resolve().parents[2]
DEFAULT = (ROOT / "recipes" / "default.toml").read_text()
NOTCH = ({"at": [15.0, 15.0, 0.0], "radius_mm": 1.5, "kind": "remove"},)


def recipe(tmp_path: Path, evaluate: str) -> str:
    """recipes/default.toml with the evaluate stage's params replaced."""
    text = DEFAULT.replace("params = { cluster_radius_mm = 1.0, min_points = 3 }", f"params = {{ {evaluate} }}")
    assert text != DEFAULT
    path = tmp_path / "r.toml"
    path.write_text(text)
    return str(path)


def one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.slow
def test_min_cameras_above_the_rigs_cameras_is_refused_and_the_notched_part_is_not_passed(sim_captures, tmp_path,
                                                                                           capsys):
    notched = str(sim_captures["notched"])  # 16 cameras of 1024 x 1024
    out = tmp_path / "out"
    code = main(["run", recipe(tmp_path, "min_cameras = 17"), "--capture", notched, "--out", str(out), "-q",
                 "--reference", "builtin:cube30"])
    line = one_error_line(capsys.readouterr().err)
    assert code == 2  # was 0: the notched part passed
    assert "min_cameras = 17" in line and "the rig has 16 cameras" in line and "'notched'" in line
    assert not (out / "notched").exists() and not (out / "history.sqlite").exists()  # nothing written, no row

    # min_points = 1000000 is below what a 16 x 1024^2 rig's images could hold, but above what
    # this part gave: the part is an error (exit 3) naming the key, not a pass.
    code = main(["run", recipe(tmp_path, "min_points = 1000000"), "--capture", notched, "--out", str(out), "-q",
                 "--reference", "builtin:cube30"])
    assert code == 3
    res = json.loads((out / "notched" / "result.json").read_text())
    n = res["stats"]["n_points"]
    assert res["verdict"] == "error" and 0 < n < 1_000_000
    assert res["error"] == (f"min_points = 1000000 is more than the {n} points measured on this part: no defect "
                            "could reject it; lower min_points")
    assert "min_points = 1000000" in one_error_line(capsys.readouterr().err)

    # The same recipe values within the rig: the notched part fails as it should.
    code = main(["run", recipe(tmp_path, "min_cameras = 2, min_points = 3"), "--capture", notched, "--out",
                 str(tmp_path / "ok"), "-q", "--reference", "builtin:cube30"])
    assert code == 1


def test_min_points_beyond_what_a_small_rig_can_give_is_refused(tmp_path, capsys):
    from inspector.capture_folder import save_capture
    from inspector.params import build_params
    from inspector_drivers.sim.simulate import SimParams, simulate

    # 6 cameras of 128 x 128 px: at most 6 x (127 x 128 + 128 x 127) = 195072 contour points.
    params = build_params(SimParams, {"part": "cube30", "seed": 22, "cameras": 6, "width": 128, "height": 128,
                                      "mm_per_px": 0.5, "bumps": NOTCH}, "test")
    folder = save_capture(simulate(params, 0, name="tiny"), tmp_path / "tiny", overwrite=True)
    out = tmp_path / "out"
    code = main(["run", recipe(tmp_path, "min_points = 1000000"), "--capture", str(folder), "--out", str(out), "-q",
                 "--reference", "builtin:cube30"])
    line = one_error_line(capsys.readouterr().err)
    assert code == 2 and not (out / "tiny").exists()
    assert "min_points = 1000000" in line and "6 cameras (128x128 px) can give at most 195072 points" in line
    assert main(["recipe", "check", recipe(tmp_path, "min_points = 1000000"), "--reference", "builtin:cube30",
                 "--rig", str(folder / "rig.json")]) == 2
    assert "can give at most 195072 points" in one_error_line(capsys.readouterr().err)


def test_recipe_check_refuses_a_recipe_no_part_of_the_rig_could_fail(sim_captures, tmp_path, capsys):
    rig = str(sim_captures["notched"] / "rig.json")
    bad = recipe(tmp_path, "min_cameras = 17")
    assert main(["recipe", "check", bad, "--reference", "builtin:cube30"]) == 0  # without a rig: nothing to judge by
    capsys.readouterr()
    assert main(["recipe", "check", bad, "--reference", "builtin:cube30", "--rig", rig]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert "r.toml" in line and "stage 'evaluate' (evaluate.tolerance)" in line and "min_cameras = 17" in line
    assert "16 cameras" in line and "rig.json" in line
    assert main(["recipe", "check", str(ROOT / "recipes" / "default.toml"), "--reference", "builtin:cube30",
                 "--rig", rig]) == 0
    assert "16 cameras): a part can be rejected" in capsys.readouterr().out
    assert main(["recipe", "check", bad, "--reference", "builtin:cube30", "--rig", str(tmp_path / "none.json")]) == 2
    assert "--rig" in one_error_line(capsys.readouterr().err)
