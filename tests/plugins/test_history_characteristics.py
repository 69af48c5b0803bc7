"""``inspector history OUTDIR --characteristics [PNG]`` (issue 28): the capability of each
characteristic over the parts a real history.sqlite recorded, and its control chart."""

from __future__ import annotations

import statistics
from datetime import UTC, datetime, timedelta

import numpy as np
import pytest
from PIL import Image

from inspector.history_store import record
from inspector.model import InspectionResult
from inspector_frontends.cli import main

DIAMETERS = [36.002, 35.998, 36.001, 36.004, 35.997, 36.000, 36.003, 35.999, 36.060]  # the last one NOK


def _rows(d: float, t: float | None) -> list[dict]:
    return [
        {"id": "1", "kind": "diameter", "nominal": 36.0, "measured": d, "lower": -0.05, "upper": 0.05, "unit": "mm",
         "verdict": "ok" if abs(d - 36.0) <= 0.05 else "nok"},
        {"id": "2", "kind": "distance", "nominal": 6.0, "measured": t, "lower": -0.02, "upper": 0.02, "unit": "mm",
         "verdict": "ok" if t is not None else "not_measurable"},
    ]


@pytest.fixture
def history(tmp_path):
    t0 = datetime(2026, 12, 3, 6, 0, tzinfo=UTC)
    for k, d in enumerate(DIAMETERS):
        t = None if k == 4 else 6.0 + 0.001 * (k % 3)  # one part where the thickness was not measurable
        verdict = "fail" if d > 36.05 else "pass"
        record(InspectionResult(f"p{k}", "r", verdict, None, {}, extras={"characteristics": _rows(d, t)}),
               tmp_path, now=t0 + timedelta(minutes=k))
    record(InspectionResult("broken", "r", "error", "rig.json: not valid JSON", {}), tmp_path, now=t0 + timedelta(hours=1))
    return tmp_path


def test_the_capability_table_is_the_recorded_values(history, tmp_path, capsys):
    png = tmp_path / "charts.png"
    assert main(["history", str(history), "--characteristics", str(png)]) == 0
    out = capsys.readouterr().out.splitlines()
    line1 = next(line for line in out if line.split()[:2] == ["1", "diameter"]).split()
    n, n_m, mean, s, cp, cpk, oot = line1[4:11]
    assert (int(n), int(n_m), int(oot)) == (9, 0, 1)
    assert float(mean) == pytest.approx(statistics.mean(DIAMETERS), abs=1e-4)
    assert float(s) == pytest.approx(statistics.stdev(DIAMETERS), abs=1e-5)
    assert float(cp) == pytest.approx(0.1 / (6 * statistics.stdev(DIAMETERS)), abs=0.01)
    line2 = next(line for line in out if line.split()[:2] == ["2", "distance"]).split()
    assert (int(line2[4]), int(line2[5])) == (8, 1)  # the part where it was not measurable is counted apart
    assert "9 parts with characteristics of 10 inspections" in out
    img = np.asarray(Image.open(png).convert("RGB"))
    assert img.shape[0] > 400 and img.shape[1] > 800  # two panels
    red = (img[..., 0] > 170) & (img[..., 1] < 90) & (img[..., 2] < 90)
    assert red.sum() > 50  # the control limits and the out-of-tolerance cross are drawn


def test_a_history_without_characteristics_says_so(tmp_path, capsys):
    record(InspectionResult("p", "r", "pass", None, {}), tmp_path)
    assert main(["history", str(tmp_path), "--characteristics"]) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "measured characteristics" in err
