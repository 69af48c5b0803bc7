"""``inspector calibrate --refine`` and ``--verify``: a knocked camera brought back from the
parts' silhouettes, a rig's scale measured with a gauge and corrected, and bad inputs (one
line, exit 2, nothing written). Small simulated rigs, fixed seeds."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from inspector.calibration.command import write_rig
from inspector.kernels.silhouette_fit import turn_camera
from inspector.model import Camera, Rig
from inspector_frontends.cli import main

pytestmark = pytest.mark.slow

#: A quick recipe for the small rig (0.4 mm/px: a coarser hull, a wider band).
SMALL_RECIPE = """
[recipe]
name = "small"
reference = "builtin:cube30"
[driver]
use = "replay"
[[stages]]
use = "segment.threshold"
[[stages]]
use = "carve.hull"
params = { voxel_mm = 1.0 }
[[stages]]
use = "align.global_icp"
[[stages]]
use = "bcps.ray"
[[stages]]
use = "evaluate.tolerance"
[tolerance]
default = { lower = -0.5, upper = 0.5 }
"""

KNOCKED = 3
KNOCK_PX = 2.0


def _simulate(root: Path, count: int, **params) -> Rig:
    from inspector.capture_folder import save_capture
    from inspector.params import build_params
    from inspector_drivers.sim.simulate import SimParams, sim_rig, simulate

    p = build_params(SimParams, params, "test")
    rig = sim_rig(p)
    for i in range(count):
        cap = simulate(p, i, rig)
        save_capture(cap, root / cap.name, overwrite=True)
    return rig


def _knocked(rig: Rig, index: int, px: float) -> tuple[Rig, np.ndarray]:
    """``rig`` with camera ``index`` turned about an axis in its image plane by ``px``."""
    cams, theta = [], np.zeros(3)
    for i, c in enumerate(rig.cameras):
        th = np.zeros(3)
        if i == index:
            th = theta = c.R.T @ np.array([0.6, -0.8, 0.0]) * px / c.K[0, 0]
        R, t = turn_camera(c.R, c.t, th, np.zeros(3))
        cams.append(Camera(c.name, c.width, c.height, c.K, c.dist, R, t))
    return Rig(tuple(cams)), theta


def _reprojection_px(a: Camera, b: Camera) -> float:
    P = np.random.default_rng(0).uniform(-20.0, 20.0, size=(2000, 3))
    return float(np.sqrt(np.mean(np.sum((a.project(P)[0] - b.project(P)[0]) ** 2, axis=1))))


@pytest.fixture(scope="module")
def cubes(tmp_path_factory):
    root = tmp_path_factory.mktemp("refine")
    caps = root / "captures"
    exact = _simulate(caps, 4, part="cube30", seed=31, cameras=8, width=256, height=256, mm_per_px=0.4)
    recipe = root / "small.toml"
    recipe.write_text(SMALL_RECIPE)
    bad, theta = _knocked(exact, KNOCKED, KNOCK_PX)
    rig = write_rig(bad, root / "knocked.json")
    return {"root": root, "captures": caps, "exact": exact, "rig": rig, "recipe": recipe, "theta": theta}


@pytest.fixture(scope="module")
def refined(cubes, tmp_path_factory):
    import contextlib
    import io

    out = cubes["root"] / "refined.json"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["calibrate", "--refine", str(cubes["rig"]), "--captures", str(cubes["captures"]),
                     "--reference", "builtin:cube30", "--recipe", str(cubes["recipe"]), "--out", str(out), "--json"])
    return code, json.loads(buf.getvalue()), out


def test_refine_brings_back_a_knocked_camera(cubes, refined):
    from inspector.capture_folder import read_rig

    code, report, out = refined
    assert code == 0
    name = f"cam{KNOCKED:02d}"
    cam = report["cameras"][name]
    # Its rays missed the reference by a pixel (half of them in, half out); now as the others.
    assert cam["before_px"] > 0.6
    assert cam["after_px"] < 0.03
    assert all(c["after_px"] < 0.03 for c in report["cameras"].values())
    assert report["converged"]
    assert name not in report["gauge_cameras"] and len(report["gauge_cameras"]) == 7
    rig = read_rig(out)
    exact, knocked = cubes["exact"], read_rig(cubes["rig"])
    i = KNOCKED
    # Where it projects the working volume: 2 px off before, within a tenth after.
    assert _reprojection_px(knocked.cameras[i], exact.cameras[i]) > 1.9
    assert _reprojection_px(rig.cameras[i], exact.cameras[i]) < 0.1
    assert max(_reprojection_px(a, b) for a, b in zip(rig.cameras, exact.cameras)) < 0.1
    # The turn found undoes the knock: the refined camera's rotation is the exact one's.
    f = exact.cameras[i].K[0, 0]
    found = np.array(cam["turn_mrad"]) * 1e-3
    assert np.linalg.norm(found + cubes["theta"]) * f < 0.3
    from scipy.spatial.transform import Rotation

    d = Rotation.from_matrix(rig.cameras[i].R.T @ exact.cameras[i].R).as_rotvec()
    assert np.linalg.norm(d) * f < 0.3
    # The frame and the scale are the input rig's.
    C0 = np.array([c.centre for c in knocked.cameras])
    C1 = np.array([c.centre for c in rig.cameras])
    assert abs(np.linalg.norm(C1, axis=1).mean() - np.linalg.norm(C0, axis=1).mean()) < 1e-4
    held = [k for k, c in enumerate(rig.cameras) if c.name in report["gauge_cameras"]]
    assert np.linalg.norm((C1 - C0)[held].mean(axis=0)) < 1e-4  # the cameras that agree hold the frame
    turns = np.array([report["cameras"][rig.cameras[k].name]["turn_mrad"] for k in held])
    assert np.linalg.norm(turns.mean(axis=0)) < 1e-4  # mrad (as reported, rounded)
    data = json.loads(out.read_text())
    assert data["refinement"]["cameras"][name]["before_px"] == cam["before_px"]
    assert set(data) == {"units", "cameras", "refinement"}


def test_refine_text_report_and_force(cubes, refined, capsys):
    _, _, out = refined
    before = out.read_text()
    code = main(["calibrate", "--refine", str(cubes["rig"]), "--captures", str(cubes["captures"]),
                 "--reference", "builtin:cube30", "--recipe", str(cubes["recipe"]), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "exists" in err and "--force" in err
    assert out.read_text() == before


@pytest.mark.parametrize("case", ["no-out", "no-reference", "no-rig-file", "empty-captures", "foreign-cameras",
                                  "bad-reference", "rig-is-out", "verify-no-rig", "verify-with-out",
                                  "bad-recipe"])
def test_bad_inputs_are_one_line_exit_2_nothing_written(cubes, tmp_path, capsys, case):
    caps, rig, recipe = str(cubes["captures"]), str(cubes["rig"]), str(cubes["recipe"])
    out = tmp_path / "out.json"
    base = ["calibrate", "--refine", rig, "--captures", caps, "--reference", "builtin:cube30", "--recipe", recipe]
    if case == "no-out":
        argv = base
    elif case == "no-reference":
        argv = ["calibrate", "--refine", rig, "--captures", caps, "--out", str(out)]
    elif case == "no-rig-file":
        argv = [*base[:2], str(tmp_path / "missing.json"), *base[3:], "--out", str(out)]
    elif case == "empty-captures":
        (tmp_path / "empty").mkdir()
        argv = [*base[:4], str(tmp_path / "empty"), *base[5:], "--out", str(out)]
    elif case == "foreign-cameras":
        other = tmp_path / "other.json"
        data = json.loads(Path(rig).read_text())
        data["cameras"][0]["name"] = "stranger"
        other.write_text(json.dumps(data))
        argv = [*base[:2], str(other), *base[3:], "--out", str(out)]
    elif case == "bad-reference":
        (tmp_path / "broken.stl").write_text("solid nothing\nendsolid nothing\n")
        argv = [*base[:6], str(tmp_path / "broken.stl"), *base[7:], "--out", str(out)]
    elif case == "rig-is-out":
        copy = tmp_path / "rig.json"
        copy.write_text(Path(rig).read_text())
        argv = [*base[:2], str(copy), *base[3:], "--out", str(copy), "--force"]
    elif case == "verify-no-rig":
        argv = ["calibrate", "--verify", "builtin:cube30", "--captures", caps, "--correct", str(out)]
    elif case == "verify-with-out":
        argv = ["calibrate", "--verify", "builtin:cube30", "--captures", caps, "--rig", rig, "--out", str(out)]
    else:
        (tmp_path / "bad.toml").write_text("[recipe\n")
        argv = [*base[:8], str(tmp_path / "bad.toml"), "--out", str(out)]
    listing = sorted(p.name for p in tmp_path.iterdir())
    code = main(argv)
    captured = capsys.readouterr()
    assert code == 2, captured
    assert captured.err.count("\n") == 1, captured.err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == listing  # nothing written, no partial file


@pytest.fixture(scope="module")
def spheres(tmp_path_factory):
    root = tmp_path_factory.mktemp("gauge")
    caps = root / "captures"
    exact = _simulate(caps, 2, part="sphere30", seed=11, cameras=8, width=512, height=512, mm_per_px=0.1)
    big = Rig(tuple(Camera(c.name, c.width, c.height, c.K, c.dist, c.R, c.t * 1.001) for c in exact.cameras))
    return {"root": root, "captures": caps, "exact": exact, "big": write_rig(big, root / "big.json")}


def _verify(spheres, rig: Path, *extra: str) -> tuple[int, dict]:
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["calibrate", "--verify", "builtin:sphere30", "--captures", str(spheres["captures"]),
                     "--rig", str(rig), "--json", *extra])
    return code, json.loads(buf.getvalue())


def test_verify_measures_the_scale_and_corrects_it(spheres):
    from inspector.capture_folder import read_rig

    corrected = spheres["root"] / "corrected.json"
    code, v = _verify(spheres, spheres["big"], "--correct", str(corrected))
    assert code == 0
    # A rig 1000 ppm too large shows the sphere 1000 ppm too large (0.015 mm on its radius).
    assert 900 < v["scale_ppm"] < 1100, v
    assert v["measured"] == 2 and v["uncertainty_ppm"] is not None
    assert v["residual_px"] > 0.1  # every point 0.15 px out
    rig = read_rig(corrected)
    big = read_rig(spheres["big"])
    ratio = [np.linalg.norm(a.centre) / np.linalg.norm(b.centre) for a, b in zip(rig.cameras, big.cameras)]
    np.testing.assert_allclose(ratio, 1.0 / (1.0 + v["scale_ppm"] * 1e-6), rtol=1e-9)
    assert all(np.allclose(a.R, b.R) and np.allclose(a.K, b.K) for a, b in zip(rig.cameras, big.cameras))
    assert json.loads(corrected.read_text())["verification"]["scale_ppm"] == v["scale_ppm"]
    code, v2 = _verify(spheres, corrected)
    assert code == 0
    assert abs(v2["scale_ppm"]) < 100, v2
    assert v2["residual_px"] < 0.05


def test_verify_refuses_an_existing_correct_file(spheres, capsys):
    existing = spheres["root"] / "exists.json"
    existing.write_text("{}")
    code = main(["calibrate", "--verify", "builtin:sphere30", "--captures", str(spheres["captures"]),
                 "--rig", str(spheres["big"]), "--correct", str(existing)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "--force" in err
    assert existing.read_text() == "{}"


def test_refine_with_intrinsics_keeps_the_focal_scale(cubes, tmp_path):
    import contextlib
    import io

    from inspector.capture_folder import read_rig

    out = tmp_path / "refined.json"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["calibrate", "--refine", str(cubes["rig"]), "--captures", str(cubes["captures"]),
                     "--reference", "builtin:cube30", "--recipe", str(cubes["recipe"]), "--out", str(out), "--json",
                     "--intrinsics"])
    assert code == 0
    report = json.loads(buf.getvalue())
    assert report["intrinsics"] and "intrinsics_px" in report["cameras"]["cam00"]
    rig, exact = read_rig(out), cubes["exact"]
    # Every part grown alike and every focal length grown alike look the same: held.
    df = [(a.K[0, 0] - b.K[0, 0]) + (a.K[1, 1] - b.K[1, 1]) for a, b in zip(rig.cameras, exact.cameras)]
    assert abs(float(np.mean(df))) < 1e-6
    assert report["cameras"][f"cam{KNOCKED:02d}"]["after_px"] < 0.03
    assert max(_reprojection_px(a, b) for a, b in zip(rig.cameras, exact.cameras)) < 0.12
