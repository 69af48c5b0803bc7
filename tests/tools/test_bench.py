"""``inspector bench``: a pytest-benchmark of one inspection, and the command on tiny settings.

pytest runs with ``--benchmark-disable`` here, so a benchmark body runs once: it asserts
correctness, never timing. ``pytest --benchmark-enable tests/tools/test_bench.py`` times it.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import pytest

from inspector.errors import RecipeError
from inspector_tools.bench import carving, common, cycles, targets
from inspector_tools.bench import command as bench

RECIPES = Path(__file__).resolve().parents[2] / "recipes"


def _args(*argv: str) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="inspector")
    sub = ap.add_subparsers(dest="command", required=True)
    bench.add_parser(sub)
    return ap.parse_args(["bench", *argv])


@pytest.fixture(scope="module")
def default_recipe():
    from inspector_frontends.cli import _load

    return _load(str(RECIPES / "default.toml"), "builtin:cube30")


def test_benchmark_one_inspection(benchmark, default_recipe, small_capture, tmp_path):
    """One batch inspection (read + every stage + outputs) of 8 cameras, 256x256, 0.4 mm/px."""
    from inspector.runner import run_batch

    pm, recipe, ref = default_recipe
    acq = cycles.acquisition(small_capture)
    runs = iter(range(1_000_000))

    def one():
        return next(run_batch(recipe, [acq], pm, reference=ref, outdir=tmp_path / f"r{next(runs)}"))

    outcome = benchmark(one)
    res = outcome.result
    assert res.error is None and res.verdict in ("pass", "fail")
    for stage in ("load", *(s.name for s in recipe.steps), "total"):
        assert res.timings_s[stage] >= 0.0
    assert "truth" not in res.stats  # the benchmark's acquisition drops truth/, as in production
    assert res.stats["reconstruction_points"] > 1000
    assert res.bcps is not None and len(res.bcps.points) > 100
    # The BCPS points lie on the reference surface after alignment (30 mm cube, 0.4 mm pixels).
    assert abs(res.stats["deviation_mm"]["mean"]) < 0.1
    folder = next((tmp_path).glob("r*")) / small_capture.name
    doc = json.loads((folder / "result.json").read_text())
    assert doc["verdict"] == res.verdict
    assert (folder / "bcps_points.ply").stat().st_size > 0


def test_run_tiny(tmp_path, capsys):
    """The whole command, simulating a small capture; every figure in the JSON."""
    out = tmp_path / "bench.json"
    rc = bench.run(_args("--runs", "1", "--cameras", "8", "--size", "256x224", "--mm-per-px", "0.4", "--carve-voxel", "0.5",
                         "--carve-runs", "1", "--open3d-voxel", "2.0", "--no-first-run", "--json", str(out)))
    assert rc in (0, 1)  # targets are for the full capture, not this one
    doc = json.loads(out.read_text())
    assert set(doc) >= {"config", "machine", "compile", "startup", "cycles", "carving", "targets", "verdicts"}
    cap = doc["config"]["capture"]
    assert (cap["width"], cap["height"], cap["cameras"]) == (256, 224, 8)  # non-square, as asked
    assert doc["targets"]["cycle"]["target_s"] == pytest.approx(bench.cycle_target_s(256, 224, 8))
    # a new process inspected the capture and printed its verdict; the first run was not asked for
    cold = doc["startup"]["cold_start"]
    assert cold["exit"] in (0, 1) and cold["verdict"] in ("pass", "fail") and 0 < cold["verdict_s"] <= cold["exit_s"]
    assert "first_run" not in doc["startup"] and doc["targets"]["first_run"]["met"] is None
    assert doc["targets"]["cold_start"]["value_s"] == cold["verdict_s"]
    assert doc["compile"]["exit"] in (0, 1) and doc["compile"]["seconds"] > 0
    assert doc["verdicts"] and all(v in ("pass", "fail") for v in doc["verdicts"])
    cyc = doc["cycles"]
    assert len(cyc["runs"]) == 1 and cyc["warmup_s"] > 0
    for name in ("load", "segment", "carve", "align", "bcps", "evaluate", "outputs", "total", "cycle"):
        assert set(cyc["stages"][name]) == {"median", "min", "max"}
    assert cyc["stages"]["cycle"]["median"] >= cyc["stages"]["total"]["median"]
    mem = cyc["memory"]
    assert mem["peak_mb"] > 0 and mem["increase_mb"] >= 0
    c = doc["carving"]
    assert c["ours"]["n_points"] > 0 and c["ours"]["median_s"] > 0
    o3 = c["open3d"]
    assert o3["grid"] and o3["n_voxels"] > 0 and o3["carve_silhouette_s"] >= 0
    assert len(o3["per_camera_s"]) == 8
    assert o3["our_points_in_kept_voxels"] > 0.99  # both carvers use the cameras alike
    assert c["ratio"] is not None and c["ratio"] > 0
    for key in ("cycle", "memory", "carve_ratio"):
        assert isinstance(doc["targets"][key]["met"], bool)
    assert rc == (0 if all(t["met"] for t in doc["targets"].values()) else 1)
    text = capsys.readouterr().out
    assert "targets:" in text and "carve ratio" in text and ("NOT MET" in text or "MET" in text)


def test_kernels_are_compiled_by_a_real_inspection_in_a_child(small_capture, tmp_path):
    r = common.compile_kernels(str(RECIPES / "default.toml"), "builtin:cube30", small_capture, tmp_path / "out")
    assert r["exit"] in (0, 1)  # pass or out of tolerance: the whole pipeline ran
    assert (tmp_path / "out" / small_capture.name / "result.json").is_file()
    bad = common.compile_kernels(str(RECIPES / "default.toml"), "builtin:cube30", tmp_path / "missing", tmp_path / "o2")
    assert bad["exit"] not in (0, 1)


def test_open3d_grid_too_large_is_refused(default_recipe, small_capture):
    from inspector.capture_folder import read_capture

    _, recipe, _ = default_recipe
    c = carving.compare_carving(read_capture(small_capture), recipe, carve_voxel=0.8, open3d_voxel=0.25, carve_runs=1,
                              open3d_max_gb=0.001)
    assert "refused" in c["open3d"] and "--open3d-voxel" in c["open3d"]["refused"]
    assert c["ratio"] is None and c["ours"]["n_points"] > 0
    assert targets.targets({"stages": {}, "memory": {}}, c)["carve_ratio"]["met"] is None


@pytest.mark.parametrize("argv", [("--runs", "0"), ("--carve-voxel", "0"), ("--open3d-voxel", "-1"), ("--capture", "/nonexistent/x")])
def test_invalid_options(argv):
    with pytest.raises(RecipeError):
        bench.run(_args(*argv))


def test_import_is_light():
    code = "import sys, inspector_tools.bench.command; print(sorted(m for m in ('numpy', 'open3d', 'numba', 'scipy', 'cv2') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]"


def test_carving_ratios(default_recipe, small_capture):
    """The target ratio is against our whole carve() call; the informative one leaves out
    only our display mesh."""
    pytest.importorskip("open3d")
    from inspector.capture_folder import read_capture

    _, recipe, _ = default_recipe
    c = carving.compare_carving(read_capture(small_capture), recipe, carve_voxel=0.8, open3d_voxel=2.0, carve_runs=2)
    ours = c["ours"]
    assert 0 < ours["without_mesh_median_s"] <= ours["max_s"]
    assert c["ratio"] == pytest.approx(c["open3d"]["carve_silhouette_s"] / ours["median_s"])
    assert c["ratio_without_mesh"] == pytest.approx(c["open3d"]["carve_silhouette_s"] / ours["without_mesh_median_s"])


def test_cold_start_times_the_verdict_line_and_a_command_error_has_none(tmp_path):
    """A capture that cannot be read is an ERROR verdict (a line, as the CONTRACT says); a
    recipe that cannot be read is a command error: no verdict line at all."""
    from inspector_tools.precompile import cold_start

    r = cold_start(RECIPES / "default.toml", tmp_path / "missing", tmp_path / "out", reference="builtin:cube30")
    assert r["verdict"] == "error" and 0 < r["verdict_s"] <= r["exit_s"] and r["exit"] != 0
    r = cold_start(tmp_path / "nope.toml", tmp_path / "missing", tmp_path / "out2")
    assert r["verdict_s"] is None and r["verdict"] is None and r["exit"] == 2 and r["exit_s"] > 0


@pytest.mark.parametrize("text, expected", [("1024", (1024, 1024)), ("2448x2048", (2448, 2048)), ("640X480", (640, 480))])
def test_size_accepts_square_and_non_square(text, expected):
    assert bench.parse_size(text) == expected
    args = _args("--size", text)
    assert bench.image_size(args) == expected
    assert args.size == expected[0]  # the width, an int, as the other benches read it


def test_size_default_is_square():
    assert bench.image_size(_args()) == (1024, 1024)


@pytest.mark.parametrize("text", ["", "x", "12x", "3x4x5", "-5", "1.5x2", "abc"])
def test_size_refused_in_one_line(text, capsys):
    with pytest.raises(SystemExit) as e:
        _args("--size", text)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--size" in err and "WxH" in err


def test_too_small_non_square_size_is_refused():
    with pytest.raises(RecipeError, match="--size"):
        bench.run(_args("--size", "640x8", "--runs", "1"))


def test_targets_follow_the_image_size_and_camera_count():
    """Issue 26: 0.5 s up to 1 MP, 1.0 s up to 5 MP (16 cameras), scaled with the camera
    count; 1.5 and 2.5 GB of peak memory."""
    assert bench.cycle_target_s(1024, 1024) == pytest.approx(0.5)
    assert bench.cycle_target_s(512, 512) == pytest.approx(0.5)
    assert bench.cycle_target_s(2448, 2048) == pytest.approx(1.0)
    assert bench.cycle_target_s(2448, 2048, 32) == pytest.approx(2.0)
    assert bench.cycle_target_s(1024, 1024, 8) == pytest.approx(0.25)
    assert bench.cycle_target_s(4096, 4096) is None
    assert bench.memory_target_mb(1024, 1024) == pytest.approx(1500.0)
    assert bench.memory_target_mb(2448, 2048) == pytest.approx(2500.0)
    assert bench.memory_target_mb(4096, 4096) is None
    cycles = {"stages": {"cycle": {"median": 0.8, "min": 0.7, "max": 0.9}}, "memory": {"peak_mb": 2000.0},
              "loadavg": {"min": 1.0, "median": 1.5, "max": 2.0}}
    small = targets.targets(cycles, None, size=(1024, 1024), cameras=16)
    assert small["cycle"]["met"] is False and small["memory"]["met"] is False
    big = targets.targets(cycles, None, size=(2448, 2048), cameras=16)
    assert big["cycle"]["met"] is True and big["memory"]["met"] is True
    assert big["cycle"]["loadavg"] == cycles["loadavg"]  # the load stands beside the figure
    huge = targets.targets(cycles, None, size=(4096, 4096), cameras=16)
    assert huge["cycle"]["met"] is None and huge["memory"]["met"] is None


def test_cycles_record_load_and_cpu_per_run(default_recipe, small_capture, tmp_path):
    pm, recipe, ref = default_recipe
    c = cycles.bench_cycles(recipe, ref, pm, small_capture, tmp_path, 2)
    assert len(c["runs"]) == 2
    for r in c["runs"]:
        assert len(r["loadavg"]) == 2 and all(x is None or x >= 0 for x in r["loadavg"])
        assert r["cpu_s"] > 0
    assert set(c["stages"]["cycle_cpu"]) == {"median", "min", "max"}
    if c["loadavg"] is not None:
        assert c["loadavg"]["min"] <= c["loadavg"]["median"] <= c["loadavg"]["max"]
    # the hypervisor's share beside each run, where the machine reports it (Linux: /proc/stat)
    import os

    linux = os.path.exists("/proc/stat")
    assert all((r["steal"] is not None) == linux for r in c["runs"])
    if linux:
        assert 0.0 <= c["steal"]["min"] <= c["steal"]["median"] <= c["steal"]["max"] <= 1.0


def test_steal_share_between_two_readings(tmp_path, monkeypatch):
    """The stolen share is the steal ticks over all ticks between two ``/proc/stat`` readings."""
    from inspector_tools.bench import common

    lines = iter(["cpu  100 5 50 800 10 0 5 30 0 0\n", "cpu  160 5 70 900 10 0 5 80 7 0\n", "intr 1 2\n"])
    real_open = open

    def fake_open(path, *a, **k):
        if path == "/proc/stat":
            p = tmp_path / "stat"
            p.write_text(next(lines))
            return real_open(p, *a, **k)
        return real_open(path, *a, **k)

    monkeypatch.setattr("builtins.open", fake_open)
    a, b = common.cpu_jiffies(), common.cpu_jiffies()
    assert a == (30, 1000) and b == (80, 1230)  # guest ticks are inside user's: not added again
    assert common.steal_share(a, b) == pytest.approx(50 / 230, abs=1e-3)
    assert common.cpu_jiffies() is None  # not a cpu line
    assert common.steal_share(a, None) is None and common.steal_share(b, a) is None
