"""``inspector experiment``: the paper's cases on a Dask cluster, CSV + PNG + summary.md.

The end-to-end tests run case 1 (scale) of the quick preset on one or two scales and one
orientation: a few inspections of 512x512 images, about half a minute on two cores.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import pytest

from inspector_tools import experiment as ex
from inspector_tools import experiment_cases as excases
from inspector_tools import experiment_execution as exexec


def _parse(*argv: str) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="inspector")
    sub = ap.add_subparsers(dest="command", required=True)
    ex.add_parser(sub)
    return ap.parse_args(["experiment", *argv])


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def _check_png(path: Path) -> None:
    from PIL import Image

    assert path.is_file(), path
    with Image.open(path) as im:
        im.verify()
    with Image.open(path) as im:
        assert im.format == "PNG" and im.size[0] > 300 and im.size[1] > 200


def _check_outputs(out: Path, part: str, values: list[str], methods: list[str]) -> list[dict[str, str]]:
    with (out / "case1_scale.csv").open(encoding="utf-8") as f:
        assert f.readline().strip().split(",") == list(ex.CSV_COLUMNS)
    rows = _rows(out / "case1_scale.csv")
    assert len(rows) == len(values) * len(methods)
    assert sorted({r["value"] for r in rows}, key=float) == values
    assert {r["method"] for r in rows} == set(methods)
    for r in rows:
        assert (r["case"], r["part"], r["variable"], r["orientation"]) == ("scale", part, "scale", "0")
        assert r["status"] == "ok", r["error"]
        assert r["verdict"] in ("pass", "fail")
        assert float(r["footprint_mm"]) == pytest.approx(0.2, rel=0.05)  # quick preset: 0.2 mm/px
        recon, bcps = float(r["recon_mean_mm"]), float(r["bcps_mean_mm"])
        assert 0 < bcps and 0 < recon and float(r["bcps_max_mm"]) >= bcps and float(r["recon_max_mm"]) >= recon
        assert float(r["ratio_mean"]) == pytest.approx(recon / bcps, rel=1e-3)
        assert float(r["t_run_s"]) > 0 and float(r["t_bcps_s"]) > 0 and float(r["t_simulate_s"]) > 0
    _check_png(out / f"case1_scale_{part}.png")
    summary = (out / "summary.md").read_text(encoding="utf-8")
    assert "| sweep |" in summary and "mean error, paper" in summary
    line = next(ln for ln in summary.splitlines() if ln.startswith(f"| 1 scale: {part} |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    paper = ex.PAPER_TABLE1[("scale", part)]
    assert cells[1].startswith(paper["label"])
    assert cells[2] == f"{len(rows)}/{len(rows)}"
    assert all(c.startswith("[") for c in cells[3:])  # every ratio is a [min–max] range
    return rows


# ------------------------------------------------------------------ fast, no cluster


def test_cli_options_and_specs():
    a = _parse("1", "3", "--out", "x", "--quick", "--orientations", "3", "--workers", "1", "--scheduler", "tcp://h:8786")
    assert (a.cases, a.out, a.quick, a.orientations, a.workers, a.scheduler) == (["1", "3"], "x", True, 3, 1, "tcp://h:8786")
    assert a.methods == ["ray", "surface"]
    cases = excases.resolve_cases(["scale", "3", "1"])
    assert [c.name for c in cases] == ["scale", "objects"]
    specs = ex.make_specs(cases, preset="quick", orientations=2)
    n_scale = 2 * len(ex.CASES["scale"].values["quick"]) * 2
    n_obj = (3 * len(ex.OBJECT_VARIANTS) + 3) * 2  # the spring has no bump variants
    assert len(specs) == n_scale + n_obj
    s = specs[0]
    assert s["sim"]["width"] == 512 and s["sim"]["mm_per_px"] == 0.2 and s["methods"] == ["ray", "surface"]
    assert {sp["seed"] for sp in specs} == {0, 1}
    full = ex.make_specs([ex.CASES["scale"]], preset="full")
    assert {sp["value"] for sp in full} == set(ex.CASES["scale"].values["full"])
    assert min(sp["value"] for sp in full) == pytest.approx(0.90) and max(sp["value"] for sp in full) == pytest.approx(1.10)
    assert full[0]["sim"]["width"] == 1024 and full[0]["sim"]["mm_per_px"] == 0.1


def test_the_built_in_pipeline_carves_at_one_pixel_footprint_and_a_recipe_keeps_its_own(tmp_path):
    def voxel(stages):
        return next(s["params"]["voxel_mm"] for s in stages if s["use"] == "carve.hull")

    assert voxel(excases.pipeline(None, "full")[0]) == ex.PRESETS["full"]["rig"]["mm_per_px"] == 0.1
    assert voxel(excases.pipeline(None, "quick")[0]) == ex.PRESETS["quick"]["rig"]["mm_per_px"] == 0.2
    recipe = tmp_path / "r.toml"
    recipe.write_text('[recipe]\nname = "r"\n[[stages]]\nuse = "carve.hull"\nparams = { voxel_mm = 0.5 }\n'
                      '[[stages]]\nuse = "bcps.ray"\n', encoding="utf-8")
    assert voxel(excases.pipeline(str(recipe), "full")[0]) == 0.5


def test_bad_options_are_refused():
    from inspector.errors import RecipeError

    with pytest.raises(RecipeError, match="unknown case"):
        excases.resolve_cases(["7"])
    with pytest.raises(RecipeError, match="scale must be"):
        ex.make_specs([ex.CASES["scale"]], values=["0.1"])
    with pytest.raises(RecipeError, match="variants"):
        ex.make_specs([ex.CASES["objects"]], values=["huge"])
    with pytest.raises(RecipeError, match="unknown part"):
        ex.make_specs([ex.CASES["scale"]], parts=["teapot"])
    with pytest.raises(RecipeError, match="nothing to run"):
        ex.make_specs([ex.CASES["scale"]], parts=["gauge"])


def test_sim_table_bumps_are_paired_across_sizes():
    base = {"part": "cube30", "seed": 3, "sim": {}, "bumps": 3, "variable": "defect_mm"}
    add = exexec._sim_table(base | {"value": 2.0})
    rem = exexec._sim_table(base | {"value": -1.0})
    assert "bumps" not in exexec._sim_table(base | {"value": 0.0})
    assert [b["kind"] for b in add["bumps"]] == ["add"] * 3 and [b["kind"] for b in rem["bumps"]] == ["remove"] * 3
    assert [b["radius_mm"] for b in add["bumps"]] == [2.0] * 3
    assert [b["at"] for b in add["bumps"]] == [b["at"] for b in rem["bumps"]]  # same positions, same seed
    obj = {"part": "gauge", "seed": 0, "sim": {}, "bumps": 3, "variable": "variant"}
    assert exexec._sim_table(obj | {"value": "excess"})["scale"] == 1.03
    assert exexec._sim_table(obj | {"value": "missing"})["scale"] == 0.97


def test_a_failing_task_is_a_row_not_an_exception():
    spec = ex.make_specs([ex.CASES["scale"]], preset="quick", orientations=1, values=["1.0"], parts=["cube30"])[0]
    rows = ex.run_task(spec | {"part": "no_such_part"})
    assert [r["method"] for r in rows] == ["ray", "surface"]
    assert all(r["status"] == "error" and "no_such_part" in r["error"] for r in rows)


def _fake_rows() -> list[dict]:
    rows = []
    for part, recon in (("cube30", 0.5), ("sphere30", 0.06)):
        for v in (0.95, 1.0, 1.05):
            for o in (0, 1):
                for m, b in (("ray", 0.02), ("surface", 0.1)):
                    rows.append({"case": "scale", "part": part, "variable": "scale", "value": v, "orientation": o, "seed": o,
                                 "method": m, "status": "ok", "verdict": "pass", "error": "", "footprint_mm": 0.1,
                                 "recon_mean_mm": recon * v * (0.9 + 0.2 * o), "recon_max_mm": 5 * recon * v,
                                 "bcps_mean_mm": b * v, "bcps_max_mm": 4 * b})
    rows[-1] |= {"status": "error", "verdict": "error", "error": "align: fitness 0.00", "bcps_mean_mm": ""}
    return rows


def test_summary_and_plots_from_rows(tmp_path):
    pytest.importorskip("matplotlib", reason="matplotlib is not installed (pip install matplotlib)")
    rows = _fake_rows()
    cases = [ex.CASES["scale"]]
    # ratios: mean over orientations at each value, then min–max over the values
    r = ex.ratio_ranges([x for x in rows if x["part"] == "cube30"], "ray", "mean")
    assert r == pytest.approx((25.0, 25.0))
    ex.write_csvs(rows, tmp_path, cases)
    assert len(_rows(tmp_path / "case1_scale.csv")) == len(rows)
    for band in ("minmax", "std"):
        paths = ex.write_plots(rows, tmp_path, cases, band=band)
        assert [p.name for p in paths] == ["case1_scale_cube30.png", "case1_scale_sphere30.png"]
        for p in paths:
            _check_png(p)
    s = ex.write_summary(rows, tmp_path, cases, {"preset": "quick", "rig": ex.PRESETS["quick"]["rig"], "tasks": 12, "elapsed_s": 1.0})
    text = s.read_text(encoding="utf-8")
    assert "| 1 scale: cube30 | Cube Scale (7) | 12/12 | [25] |" in text
    assert "| 1 scale: sphere30 | Sphere Scale (8) | 11/12 |" in text
    assert "[3.5]" in text and "[4.74–4.77]" in text and "[5–45]" in text  # the paper's numbers beside ours
    assert "align: fitness 0.00" in text  # failed runs are listed


# ------------------------------------------------------------------ on a Dask cluster


@pytest.fixture
def dask_ready():
    pytest.importorskip("distributed", reason="dask[distributed] is not installed (pip install 'dask[distributed]')")
    pytest.importorskip("matplotlib", reason="matplotlib is not installed (pip install matplotlib)")


def test_quick_case1_on_a_local_cluster(dask_ready, tmp_path, capsys):
    out = tmp_path / "exp"
    args = _parse("1", "--quick", "--parts", "cube30", "--values", "0.95", "1.05", "--orientations", "1",
                  "--workers", "2", "--out", str(out))
    assert ex.run(args) == 0
    rows = _check_outputs(out, "cube30", ["0.95", "1.05"], ["ray", "surface"])
    # the raw reconstruction of a cube carries large bulges; BCPS (ray) removes most of them
    for r in rows:
        if r["method"] == "ray":
            assert float(r["bcps_mean_mm"]) < float(r["recon_mean_mm"])
    captured = capsys.readouterr()
    assert "4/4 inspections OK" in captured.out and "inspector: error" not in captured.err
    assert (out / "experiment.json").is_file()


def test_scheduler_address_of_an_existing_cluster(dask_ready, tmp_path):
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster:
        out = tmp_path / "exp"
        args = _parse("scale", "--quick", "--parts", "sphere30", "--values", "1.0", "--orientations", "1",
                      "--methods", "ray", "--scheduler", cluster.scheduler_address, "--out", str(out), "--no-progress")
        assert ex.run(args) == 0
        rows = _check_outputs(out, "sphere30", ["1"], ["ray"])
        assert rows[0]["worker"] in {str(w) for w in cluster.workers}  # ran on the given cluster's worker


def _boom(spec):
    raise RuntimeError("worker exploded")


def test_a_failed_future_does_not_lose_the_other_results(dask_ready):
    from distributed import Client, LocalCluster

    specs = [{"case": "scale", "part": "cube30", "variable": "scale", "value": 1.0, "orientation": i, "seed": i,
              "methods": ["ray"]} for i in range(3)]

    def fn(spec):
        if spec["orientation"] == 1:
            return _boom(spec)
        return [exexec._base_row(spec, "ray") | {"status": "ok", "verdict": "pass"}]

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster, Client(cluster) as client:
        got = []
        rows = ex.execute(specs, client, fn=fn, on_rows=got.extend, progress=False)
    assert len(rows) == 3 and got == rows
    by = {r["orientation"]: r for r in rows}
    assert by[0]["status"] == by[2]["status"] == "ok"
    assert by[1]["status"] == "error" and "worker exploded" in by[1]["error"]


def test_import_is_light():
    import subprocess

    code = "import sys, inspector_tools.experiment; print(any(m in sys.modules for m in ('dask', 'distributed', 'matplotlib', 'tqdm')))"
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.strip() == "False"
