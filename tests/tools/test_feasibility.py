"""``inspector feasibility``: bad inputs refused in one line, and a tiny study end to end on a
real ``dask scheduler`` + ``dask worker`` started here on 127.0.0.1 (outputs, resume, the
same verdict as ``inspector run`` on a kept capture).

The study is tiny on purpose: 2 nominal poses and one capture with 2 defects of a 30 mm cube,
16 cameras of 128x128 px at 0.6 mm/px (the whole suite has 8 minutes on two cores).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from inspector_frontends.cli import main

BIN = Path(sys.executable).parent

TINY = """
[recipe]
name = "tiny"
reference = "builtin:cube30"

[driver]
use = "sim"
params = {{ cameras = 16, width = 128, height = 128, mm_per_px = 0.6, offset_mm = 1.0, noise_sigma = 2.0 }}

[[stages]]
use = "segment.threshold"

[[stages]]
use = "carve.hull"
params = {{ voxel_mm = 0.6 }}

[[stages]]
use = "align.global_icp"

[[stages]]
use = "bcps.ray"

[[stages]]
use = "evaluate.tolerance"

[tolerance]
default = {{ lower = -{tol}, upper = {tol} }}

[[tolerance.regions]]
name = "top"
box_min = [-16.0, -16.0, 14.0]
box_max = [16.0, 16.0, 16.0]
lower = -{tol}
upper = {tol}
"""


def _recipe(tmp_path: Path, tol: float = 0.4, name: str = "tiny.toml") -> Path:
    p = tmp_path / name
    p.write_text(TINY.format(tol=tol), encoding="utf-8")
    return p


def _refused(capsys, argv: list[str], *needles: str) -> str:
    assert main(argv) == 2
    cap = capsys.readouterr()
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("inspector: error: "), cap.err
    assert "Traceback" not in cap.err + cap.out
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


# ------------------------------------------------------------------ bad inputs, one line each


def test_bad_inputs_are_refused_in_one_line_before_anything_runs(tmp_path, capsys):
    import trimesh

    from inspector_drivers.sim.rig import sphere_rig

    out = tmp_path / "out"
    recipe = str(_recipe(tmp_path))
    box = trimesh.creation.box((20, 20, 20))
    box.update_faces(np.arange(len(box.faces)) != 0)  # one triangle missing: open
    open_stl = tmp_path / "open.stl"
    box.export(open_stl)
    _refused(capsys, ["feasibility", str(open_stl), "--out", str(out), "--recipe", recipe], "open.stl", "not watertight")
    _refused(capsys, ["feasibility", "cube30", "--out", str(out), "--recipe", recipe, "--region", "bore"],
             "--region 'bore'", "no such region in tiny.toml", "its regions: top")
    narrow = str(_recipe(tmp_path, tol=0.1, name="narrow.toml"))  # 0.17 px at 0.6 mm/px
    _refused(capsys, ["feasibility", "cube30", "--out", str(out), "--recipe", narrow], "narrow.toml", "0.17 px",
             "pixel footprint")
    rig = tmp_path / "rig.json"
    rig.write_text(json.dumps(sphere_rig(8, width=64, height=64, mm_per_px=0.1).to_json()), encoding="utf-8")  # 6.4 mm field
    _refused(capsys, ["feasibility", "cube30", "--out", str(out), "--recipe", recipe, "--rig", str(rig)],
             "does not see the part", "cam00")
    _refused(capsys, ["feasibility", "teapot", "--out", str(out)], "no such file, nor a built-in part")
    _refused(capsys, ["feasibility", "cube30", "--out", str(out), "--poses", "1"], "--poses")
    assert not out.exists()  # nothing ran, nothing written


# ------------------------------------------------------------------ on a real scheduler


@pytest.fixture(scope="module")
def dask_scheduler(tmp_path_factory):
    """``dask scheduler`` and one ``dask worker`` process on 127.0.0.1; their address."""
    pytest.importorskip("distributed", reason="dask[distributed] is not installed")
    pytest.importorskip("statsmodels", reason="statsmodels is not installed (pip install statsmodels)")
    dask = BIN / "dask"
    if not dask.exists():
        pytest.skip("the dask command is not installed (pip install 'dask[distributed]')")
    folder = tmp_path_factory.mktemp("dask")
    sfile = folder / "scheduler.json"
    env = os.environ | {"DASK_DISTRIBUTED__WORKER__DAEMON": "False"}
    procs = [subprocess.Popen([str(dask), "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(sfile)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              env=env, start_new_session=True)]
    try:
        for _ in range(300):
            if sfile.is_file() and sfile.stat().st_size:
                break
            time.sleep(0.1)
        address = json.loads(sfile.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        procs.append(subprocess.Popen([str(dask), "worker", address, "--host", "127.0.0.1", "--nworkers", "1", "--nthreads",
                                       "1", "--no-dashboard", "--name", "feasibility-test-worker"],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, start_new_session=True))
        from distributed import Client

        with Client(address, timeout="30s") as c:
            c.wait_for_workers(1, timeout=60)
        yield address
    finally:
        for p in reversed(procs):
            try:
                os.killpg(p.pid, signal.SIGTERM)  # the session each started: the process and its children
            except ProcessLookupError:
                pass
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()


def _numbers(out: Path) -> dict:
    data = json.loads((out / "feasibility.json").read_text())
    for k in ("elapsed_s", "simulations_run"):
        data.pop(k)
    return data


@pytest.mark.slow
def test_a_tiny_study_on_a_dask_scheduler_reports_resumes_and_agrees_with_inspector_run(dask_scheduler, tmp_path, capsys):
    from inspector.outputs import read_ply

    recipe = str(_recipe(tmp_path))
    out = tmp_path / "study"
    argv = ["feasibility", "cube30", "--recipe", recipe, "--out", str(out), "--poses", "2", "--defect-captures", "1",
            "--defects-per-capture", "2", "--element-mm", "2", "--keep-captures", "1", "--scheduler", dask_scheduler,
            "--no-progress"]
    assert main(argv) == 0, capsys.readouterr().err
    printed = capsys.readouterr().out
    assert "0 already done" in printed and "3 to run on tcp://127.0.0.1:" in printed
    assert "region 'top' " in printed and "be inspected at ±0.4 mm with this rig: Cg = " in printed

    # the outputs
    sims = sorted(p.name for p in (out / "sims").glob("*.npz"))
    assert sims == ["defect-0000.npz", "nominal-0000.npz", "nominal-0001.npz"]
    ply = read_ply(out / "observability.ply")
    for field in ("red", "green", "blue", "observability", "poses_observed", "err_mean_mm", "err_p95_mm", "points", "region"):
        assert field in ply
    obs = ply["observability"]
    assert 0 < (obs > 0).mean() < 0.6 and obs.max() <= 1.0  # a cube is seen at its edges, never inside its faces
    never = obs == 0
    assert np.all(ply["red"][never] == 219) and np.all(np.isnan(ply["err_p95_mm"][never]))  # marked, no error there
    assert np.nanmax(ply["err_p95_mm"]) < 0.6  # within a pixel footprint of the true surface
    for png in ("observability.png", "error.png", "gauge.png", "pod_00_default.png", "pod_01_top.png"):
        assert (out / png).stat().st_size > 10_000, png
    md = (out / "feasibility.md").read_text()
    assert "| region | band | area, mm² | observable share | a90/95 dents | a90/95 bumps | Cg | Cgk | false-reject rate | verdict |" in md
    assert "| `top` | ±0.4 mm |" in md and "| `default` | ±0.4 mm |" in md and "![observability map](observability.png)" in md
    html = (out / "feasibility.html").read_text()
    assert html.count("src='data:image/png;base64,") == 5 and "<table>" in html
    data = json.loads((out / "feasibility.json").read_text())
    assert [r["name"] for r in data["regions"]] == ["default", "top"] and data["nominal"]["captures"] == 2
    rows = (out / "simulations.csv").read_text().splitlines()
    assert len(rows) == 4 and all(",feasibility-test-worker" in r for r in rows[1:])  # ran on the scheduler's worker
    assert len((out / "defects.csv").read_text().splitlines()) == 3

    # the kept capture gives the same verdict with inspector run
    run_out = tmp_path / "run"
    status = main(["run", recipe, "--capture", str(out / "captures" / "nominal-0000"), "--out", str(run_out), "-q"])
    capsys.readouterr()
    result = json.loads((run_out / "nominal-0000" / "result.json").read_text())
    header = rows[0].split(",")
    first = dict(zip(header, next(r for r in rows if r.startswith("nominal-0000,")).split(",")))
    assert result["verdict"] == first["verdict"] and status == {"pass": 0, "fail": 1}[first["verdict"]]
    assert result["stats"]["n_points"] == int(first["n_points"])

    # resume: only the missing simulation runs again, and the numbers are the same
    before = _numbers(out)
    kept = {p.name: p.stat().st_mtime_ns for p in (out / "sims").glob("*.npz") if p.name != "nominal-0001.npz"}
    (out / "sims" / "nominal-0001.npz").unlink()
    assert main(argv) == 0
    assert "2 already done" in capsys.readouterr().out
    assert {p.name: p.stat().st_mtime_ns for p in (out / "sims").glob("*.npz") if p.name != "nominal-0001.npz"} == kept
    assert (out / "sims" / "nominal-0001.npz").is_file()
    assert _numbers(out) == before
