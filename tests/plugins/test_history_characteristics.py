"""``inspector history OUTDIR --characteristics [PNG]`` (issue 28): the capability of each
characteristic over the parts a real history.sqlite recorded, and its control chart; and
``--dfq FILE``: the same parts as Q-DAS AQDEF, read back with the independent aqdefreader."""

from __future__ import annotations

import json
import sqlite3
import statistics
from datetime import UTC, datetime, timedelta, timezone

import numpy as np
import pytest
from PIL import Image

from inspector.characteristics.formats import DFQ_CHARACTERISTIC, DFQ_FIELD, RunRecords
from inspector.characteristics.measure import Characteristic
from inspector.history_store import record
from inspector.model import InspectionResult
from inspector_frontends.cli import main

DIAMETERS = [36.002, 35.998, 36.001, 36.004, 35.997, 36.000, 36.003, 35.999, 36.060]  # the last one NOK


#: The recipe's [[characteristics]] the rows below were measured for (what `inspector run --dfq` writes from).
CHARS = (Characteristic("1", "diameter", ("F04",), -0.05, 0.05, criticality="key", description="Ø36 boss"),
         Characteristic("2", "distance", ("F01", "F02"), -0.02, 0.02))
T0 = datetime(2026, 12, 3, 6, 0, tzinfo=UTC)


def _rows(d: float, t: float | None) -> list[dict]:
    """The stage's rows (``result.json`` ``extras.characteristics``), every key it writes."""
    def row(c: Characteristic, nominal: float, v: float | None, verdict: str) -> dict:
        return {"id": c.id, "kind": c.kind, "features": list(c.features), "nominal": nominal, "measured": v,
                "deviation": None if v is None else v - nominal, "lower": c.lower, "upper": c.upper,
                "u": None if v is None else 0.0005, "U": None if v is None else 0.001, "points": 0 if v is None else 900,
                "verdict": verdict, "reason": "" if v is not None else "too few points", "unit": "mm",
                "criticality": c.criticality, "description": c.description}

    return [row(CHARS[0], 36.0, d, "ok" if abs(d - 36.0) <= 0.05 else "nok"),
            row(CHARS[1], 6.0, t, "ok" if t is not None else "not_measurable")]


def _results() -> list[InspectionResult]:
    """The run's results: 9 parts with characteristics (capture.json timestamps in +01:00), an error."""
    out = []
    for k, d in enumerate(DIAMETERS):
        t = None if k == 4 else 6.0 + 0.001 * (k % 3)  # one part where the thickness was not measurable
        verdict = "fail" if d > 36.05 else "pass"
        stamp = (T0 + timedelta(minutes=k, seconds=7)).astimezone(timezone(timedelta(hours=1))).isoformat()
        out.append(InspectionResult(f"p{k}", "r", verdict, None, {}, extras={"characteristics": _rows(d, t)},
                                    metadata={"part_id": f"S-{k:04d}", "timestamp": stamp}))
    out.append(InspectionResult("broken", "r", "error", "rig.json: not valid JSON", {}))
    return out


@pytest.fixture
def history(tmp_path):
    for k, result in enumerate(_results()):
        record(result, tmp_path, now=T0 + timedelta(minutes=k) + (timedelta(hours=1) if result.verdict == "error" else timedelta()))
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


# --------------------------------------------------------------------------- --dfq FILE


def _read_dfq(path):
    """The DFQ read back by the independent reader: K1001, K1002, per characteristic its K-fields
    and its values by part (batch), in file order."""
    aqdef = pytest.importorskip("aqdefreader", reason="aqdefreader (the independent DFQ reader) is not installed")
    dfq = aqdef.read_dfq_file(str(path))
    assert dfq.part_count() == 1
    part = dfq.get_part(0)

    def num(v):  # the reader keeps '.'-decimals as text (it parses only ','-decimals)
        return float(str(v).replace(",", "."))

    chars = [{"id": str(ch.get_data("K2001")), "label": ch.get_data("K2002"), "nominal": num(ch.get_data("K2101")),
              "lsl": num(ch.get_data("K2110")), "usl": num(ch.get_data("K2111")),
              "values": {m.batch_no: m.value for m in ch.get_measurements()}}
             for ch in part.get_characteristics()]
    return part.get_part_no(), part.get_data("K1002"), chars


def _value_lines(path):
    return [ln for ln in path.read_bytes().decode("latin-1").split("\r\n") if ln and not ln.startswith("K")]


def test_dfq_holds_the_recorded_values_one_line_per_part(history, tmp_path, capsys):
    out = tmp_path / "hist.dfq"
    assert main(["history", str(history), "--dfq", str(out)]) == 0
    assert f"wrote {out}: 2 characteristics, 9 parts of 10 inspections" in capsys.readouterr().out
    number, description, chars = _read_dfq(out)
    assert (number, description) == ("r", "r")  # no --recipe: the recorded recipe's name
    assert [c["id"] for c in chars] == ["1", "2"] and chars[0]["label"] == "Ø36 boss"
    assert (chars[0]["nominal"], chars[0]["lsl"], chars[0]["usl"]) == pytest.approx((36.0, 35.95, 36.05))
    assert (chars[1]["nominal"], chars[1]["lsl"], chars[1]["usl"]) == pytest.approx((6.0, 5.98, 6.02))
    con = sqlite3.connect(history / "history.sqlite")
    rows = con.execute("SELECT capture, triggered_at, extras FROM inspections WHERE extras IS NOT NULL ORDER BY id").fetchall()
    con.close()
    lines = _value_lines(out)
    assert len(rows) == 9 and len(lines) == 9  # one value line per part with characteristics
    for (capture, triggered, extras), line in zip(rows, lines, strict=True):
        recorded = {r["id"]: r["measured"] for r in json.loads(extras)["characteristics"]}
        for c in chars:
            if recorded[c["id"]] is None:  # not measurable: attribute 255, no value the reader keeps
                assert capture not in c["values"]
            else:
                assert c["values"][capture] == pytest.approx(recorded[c["id"]], abs=1e-9)
        # the date/time field as written (the reader takes dd.mm for mm.dd when the day is <= 12): the
        # capture's own clock, as `inspector run --dfq` writes it; the capture as the part id
        fields = [cell.split(DFQ_FIELD) for cell in line.split(DFQ_CHARACTERISTIC)]
        when = datetime.fromisoformat(triggered).strftime("%d.%m.%Y/%H:%M:%S")
        assert all(f[2] == when and f[4] == capture for f in fields)
        assert [f[1] for f in fields] == ["0" if recorded[c["id"]] is not None else "255" for c in chars]
    assert sorted(chars[1]["values"]) == sorted(f"p{k}" for k in range(9) if k != 4)


def test_dfq_is_what_inspector_run_wrote_for_the_same_parts(history, tmp_path):
    run = RunRecords(CHARS, (), tmp_path / "run.dfq", None, part_number="r", part_description="r")
    for result in _results():  # what `inspector run --dfq` collects from each result and writes at the end
        run.add(result)
    run.write()
    assert main(["history", str(history), "--dfq", str(tmp_path / "hist.dfq")]) == 0
    assert (tmp_path / "hist.dfq").read_bytes() == (tmp_path / "run.dfq").read_bytes()


def test_dfq_takes_the_part_number_from_recipe(history, tmp_path):
    recipe = tmp_path / "r.toml"
    recipe.write_text('[recipe]\nname = "r"\nreference = "builtin:bracket"\n[[stages]]\nuse = "segment.threshold"\n'
                      '[[stages]]\nuse = "carve.hull"\n[[stages]]\nuse = "align.global_icp"\n[[stages]]\n'
                      'use = "bcps.ray"\n[[stages]]\nuse = "evaluate.tolerance"\n')
    assert main(["history", str(history), "--recipe", str(recipe), "--dfq", str(tmp_path / "h.dfq")]) == 0
    assert _read_dfq(tmp_path / "h.dfq")[:2] == ("builtin:bracket", "r")  # as `inspector run --dfq` names it


def test_dfq_respects_last_and_cell(history, tmp_path, capsys):
    out = tmp_path / "last.dfq"
    assert main(["history", str(history), "--last", "4", "--dfq", str(out)]) == 0  # 3 parts and the error
    assert len(_value_lines(out)) == 3
    assert sorted(_read_dfq(out)[2][0]["values"]) == ["p6", "p7", "p8"]
    capsys.readouterr()
    assert main(["history", str(history), "--cell", "no-such-cell", "--dfq", str(tmp_path / "none.dfq")]) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "none of the 0 inspections measured characteristics" in err
    assert not (tmp_path / "none.dfq").exists()


def test_dfq_of_a_history_without_characteristics_says_so(tmp_path, capsys):
    record(InspectionResult("p", "r", "pass", None, {}), tmp_path)
    assert main(["history", str(tmp_path), "--dfq", str(tmp_path / "x.dfq")]) == 3  # as --characteristics
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "measured characteristics" in err
    assert not (tmp_path / "x.dfq").exists()


def test_dfq_that_cannot_be_written_is_one_line_naming_it(history, tmp_path, capsys):
    missing = tmp_path / "no" / "h.dfq"
    assert main(["history", str(history), "--dfq", str(missing)]) == 2  # checked before the history is read
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"--dfq {missing}" in err and "no such folder" in err
    assert main(["history", str(history), "--dfq", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"--dfq {tmp_path}: is a folder" in err
    target = tmp_path / "h.dfq"
    (tmp_path / ".h.dfq.partial").mkdir()  # the temporary file cannot be made (root ignores permissions)
    assert main(["history", str(history), "--dfq", str(target)]) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"--dfq {target}: cannot write" in err and not target.exists()


def test_dfq_dates_a_part_without_a_capture_timestamp_by_its_inspection(tmp_path):
    record(InspectionResult("p", "r", "pass", None, {}, extras={"characteristics": _rows(36.001, 6.0)}), tmp_path,
           now=T0)  # no capture.json timestamp: the run's clock (local time) at the inspection, as the run writes it
    assert main(["history", str(tmp_path), "--dfq", str(tmp_path / "x.dfq")]) == 0
    fields = _value_lines(tmp_path / "x.dfq")[0].split(DFQ_CHARACTERISTIC)[0].split(DFQ_FIELD)
    assert fields[:3] == ["36.0010", "0", T0.astimezone().strftime("%d.%m.%Y/%H:%M:%S")] and fields[4] == "p"


def test_dfq_of_a_row_that_cannot_be_read_names_the_inspection(tmp_path, capsys):
    rows = [{k: v for k, v in r.items() if k != "features"} for r in _rows(36.0, 6.0)]  # not what the stage writes
    record(InspectionResult("odd", "r", "pass", None, {}, extras={"characteristics": rows}), tmp_path)
    assert main(["history", str(tmp_path), "--dfq", str(tmp_path / "x.dfq")]) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "the inspection of 'odd'" in err and "cannot be read" in err
    assert not (tmp_path / "x.dfq").exists()
