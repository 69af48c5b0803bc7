"""``inspector run --csv`` (issue 16, item 7): per-point deviations and per-region summaries
next to the PLY, agreeing with it and with result.json."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from inspector.outputs import read_ply
from inspector_frontends.cli import main

DEFAULT = str(Path(__file__).resolve().parents[2] / "recipes" / "default.toml")


def test_run_csv_writes_points_and_regions_matching_the_ply(tmp_path, small_capture):
    out = tmp_path / "out"
    code = main(["run", DEFAULT, "--capture", str(small_capture), "--out", str(out), "--reference", "builtin:cube30",
                 "--csv", "-q"])
    folder = out / small_capture.name
    res = json.loads((folder / "result.json").read_text())
    assert code in (0, 1) and res["verdict"] in ("pass", "fail")
    ply = read_ply(folder / "bcps_points.ply")
    with open(folder / "bcps_points.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(ply["x"]) == res["stats"]["n_points"]
    dev = np.array([float(r["deviation_mm"]) for r in rows])
    assert np.allclose(dev, ply["deviation"], atol=1e-6)  # the same points, in the same order
    assert np.allclose([float(r["x_mm"]) for r in rows], ply["x"], atol=1e-5)
    rig = json.loads((small_capture / "rig.json").read_text())
    assert {r["camera"] for r in rows} <= {c["name"] for c in rig["cameras"]}
    assert {r["region"] for r in rows} == {"default"}
    assert sum(r["out_of_tolerance"] == "1" for r in rows) == res["stats"]["out_of_tolerance_points"]
    with open(folder / "regions.csv", newline="") as f:
        regions = {r["region"]: r for r in csv.DictReader(f)}
    assert list(regions) == ["default", "all"]
    d = regions["default"]
    assert int(d["n_points"]) == res["stats"]["n_points"]
    assert float(d["lower_mm"]) == res["stats"]["tolerance_mm"]["lower"]
    assert abs(float(d["mean_mm"]) - res["stats"]["deviation_mm"]["mean"]) < 1e-6
    assert int(regions["all"]["defects"]) == len(res["defects"])
