"""Shift counters (``inspector.shift``): shifts from the cell's times, counts equal to the
history's, regions and error reasons grouped, settings refused in one line."""

from __future__ import annotations

import shutil
import sqlite3
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

from inspector.errors import InputError, RecipeError
from inspector.shift import (
    ShiftSettings,
    error_key,
    format_shifts,
    print_shifts,
    shift_at,
    shift_counters,
    shift_settings,
    shifts_until,
)
from inspector_frontends.cli import main

DEFAULT = str(Path(__file__).resolve().parents[2] / "recipes" / "default.toml")
UTC = UTC


def _run(captures, out: Path) -> int:
    return main(["run", DEFAULT, "--capture", *map(str, captures), "--out", str(out), "--reference", "builtin:cube30", "-q"])


@pytest.fixture
def real_history(tmp_path, small_capture):
    """A history.sqlite made by real inspections: a part judged (twice) and a part whose
    rig.json is broken (an error row)."""
    a = shutil.copytree(small_capture, tmp_path / "c" / "part-a")
    b = shutil.copytree(small_capture, tmp_path / "c" / "part-b")
    (b / "rig.json").write_text("{ broken")
    out = tmp_path / "out"
    _run([a, b], out)
    _run([a], out)
    return out


def _one_day_shift_holding(rows) -> ShiftSettings:
    """One 24-hour shift starting at the first row's minute (UTC): every row is in it,
    whenever the test runs."""
    first = datetime.fromisoformat(rows[0]["inspected_at"]).astimezone(UTC)
    return ShiftSettings(starts=(first.strftime("%H:%M"),), names=("day",), timezone="UTC")


def test_shift_counters_equal_the_history_for_the_same_rows(real_history, capsys):
    from inspector.history_store import read_history
    from inspector_plugins.history import tally

    rows = read_history(real_history)
    assert len(rows) == 3
    settings = _one_day_shift_holding(rows)
    now = datetime.fromisoformat(rows[-1]["inspected_at"])
    before = (real_history / "history.sqlite").read_bytes()
    (c,) = shift_counters(real_history, settings, now=now)
    assert (real_history / "history.sqlite").read_bytes() == before  # read-only
    n, share = tally(rows)
    assert c.ids == tuple(r["id"] for r in rows)
    assert (c.passed, c.failed, c.errors) == (n["pass"], n["fail"], n["error"]) and n["error"] >= 1
    assert c.yield_ == share
    # regions: what the defects table holds for these rows
    con = sqlite3.connect(real_history / "history.sqlite")
    want = {}
    for region, iid, worst in con.execute("SELECT COALESCE(region, 'default'), inspection_id, worst_mm FROM defects"):
        parts, k, w = want.get(region, (set(), 0, 0.0))
        want[region] = (parts | {iid}, k + 1, worst if abs(worst) > abs(w) else w)
    con.close()
    assert {g.region: (g.parts, g.defects, g.worst_mm) for g in c.regions} == {
        r: (len(p), k, w) for r, (p, k, w) in want.items()}
    # part-b's broken rig.json (part-a is judged, or on a machine too loaded for the stage
    # time limit an error of its own, grouped apart)
    (err,) = [g for g in c.error_groups if g.example.startswith("rig.json: not valid JSON")]
    assert err.count == 1 and sum(g.count for g in c.error_groups) == c.errors
    # `inspector history` says the same counts for the same rows
    capsys.readouterr()
    assert main(["history", str(real_history)]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith(f"3 inspections: {c.passed} pass, {c.failed} fail, {c.errors} error")
    text = format_shifts([c])
    assert f"3 inspected: {c.passed} pass, {c.failed} fail, {c.errors} error" in text and "rig.json: not valid JSON" in text


def test_a_shift_that_ended_counts_nothing_of_the_next(real_history):
    from inspector.history_store import read_history

    rows = read_history(real_history)
    settings = _one_day_shift_holding(rows)
    first = datetime.fromisoformat(rows[0]["inspected_at"])
    earlier, current = shift_counters(real_history, settings, now=first, shifts=2)
    assert earlier.inspected == 0 and earlier.yield_ is None
    assert current.inspected == 3
    (yesterday,) = shift_counters(real_history, settings, now=first - timedelta(hours=1))
    assert yesterday.inspected == 0  # the rows are after the end of the shift that held an hour earlier


def test_shifts_follow_the_local_clock_across_midnight_and_daylight_saving():
    s = ShiftSettings(timezone="Europe/Berlin")
    night = shift_at(datetime(2026, 12, 2, 21, 30, tzinfo=UTC), s)  # 22:30 in Berlin
    assert night.name == "night" and night.label() == "night 2026-12-02 22:00"
    assert night.end.strftime("%Y-%m-%d %H:%M") == "2026-12-03 06:00"
    assert shift_at(datetime(2026, 12, 3, 4, 59, tzinfo=UTC), s).label() == "night 2026-12-02 22:00"  # 05:59
    assert shift_at(datetime(2026, 12, 3, 5, 0, tzinfo=UTC), s).label() == "early 2026-12-03 06:00"  # 06:00
    assert shift_at(datetime(2026, 12, 3, 13, 0, tzinfo=UTC), s).label() == "late 2026-12-03 14:00"
    # 29 March 2026: the clocks go forward at 02:00, the night shift lasts 7 hours
    spring = shift_at(datetime(2026, 3, 29, 1, 30, tzinfo=UTC), s)
    assert spring.label() == "night 2026-03-28 22:00"
    assert spring.end.astimezone(UTC) - spring.start.astimezone(UTC) == timedelta(hours=7)
    three = shifts_until(datetime(2026, 12, 3, 8, 0, tzinfo=UTC), s, 3)
    assert [x.label() for x in three] == ["late 2026-12-02 14:00", "night 2026-12-02 22:00", "early 2026-12-03 06:00"]
    assert all(a.end == b.start for a, b in zip(three, three[1:]))


def _history_with(path: Path, rows: list[tuple[str, str, str | None]], defects: list[tuple[int, float, str]]) -> Path:
    from inspector.history_store import SCHEMA

    con = sqlite3.connect(path)
    con.executescript(SCHEMA)
    for k, (at, verdict, error) in enumerate(rows, start=1):
        con.execute("INSERT INTO inspections (id, inspected_at, capture, recipe, verdict, error, n_defects) "
                    "VALUES (?, ?, ?, 'r', ?, ?, 0)", (k, at, f"part-{k}", verdict, error))
    con.executemany("INSERT INTO defects (inspection_id, kind, n_points, worst_mm, region) VALUES (?, 'missing', 9, ?, ?)",
                    defects)
    con.commit()
    con.close()
    return path


def test_regions_and_error_reasons_are_grouped(tmp_path):
    rows = [
        ("2026-12-03T06:10:00.000+00:00", "fail", None),
        ("2026-12-03T07:00:00.000+00:00", "fail", None),
        ("2026-12-03T08:00:00.000+00:00", "error", "stage 'carve.hull' exceeded 30 s (the stage_limit_s of [budget])"),
        ("2026-12-03T09:00:00.000+00:00", "error", "stage 'bcps.ray' exceeded 31.5 s (the stage_limit_s of [budget])"),
        ("2026-12-03T10:00:00.000+00:00", "error", "rig.json: not valid JSON (line 1 column 3)"),
        ("2026-12-03T11:00:00.000+00:00", "pass", None),
        ("2026-12-03T14:00:00.000+00:00", "fail", None),  # the late shift: not counted
    ]
    defects = [(1, -0.31, "bore"), (1, -0.12, "bore"), (1, 0.2, "face"), (2, -0.5, "bore"), (7, -2.0, "face")]
    path = _history_with(tmp_path / "history.sqlite", rows, defects)
    s = ShiftSettings(timezone="UTC")
    (c,) = shift_counters(path, s, now=datetime(2026, 12, 3, 13, 59, tzinfo=UTC))
    assert c.shift.label() == "early 2026-12-03 06:00"
    assert (c.inspected, c.passed, c.failed, c.errors) == (6, 1, 2, 3) and c.yield_ == pytest.approx(1 / 3)
    assert [(g.region, g.parts, g.defects, g.worst_mm) for g in c.regions] == [("bore", 2, 3, -0.5), ("face", 1, 1, 0.2)]
    assert [(e.reason, e.count) for e in c.error_groups] == [
        ("stage '…' exceeded # s (the stage_limit_s of [budget])", 2), ("rig.json: not valid JSON (line # column #)", 1)]
    assert c.error_groups[0].example.startswith("stage 'bcps.ray'")  # the latest
    assert error_key(None) == error_key("") == "no reason recorded"


def test_settings_are_checked_in_one_line(tmp_path):
    cell = tmp_path / "cell.toml"
    cell.write_text('[shifts]\nstarts = ["06:00", "18:00"]\nnames = ["day", "night"]\ntimezone = "UTC"\n'
                    '[gui]\nkiosk = true\n')
    assert shift_settings(cell) == ShiftSettings(("06:00", "18:00"), ("day", "night"), "UTC")
    assert shift_settings(None) == ShiftSettings()
    for text, words in (
        ('[shifts]\nstarts = ["6:00"]\nnames = ["a"]\n', "'6:00' is not a time HH:MM"),
        ('[shifts]\nstarts = ["14:00", "06:00"]\n', "expected ascending"),
        ('[shifts]\nstarts = ["06:00"]\n', "names: expected 1 names"),
        ('[shifts]\ntimezone = "Mars/Olympus"\n', "unknown time zone 'Mars/Olympus'"),
        ('[shift]\n', "unknown table 'shift'"),
        ('[shifts]\nstart = ["06:00"]\n', "unknown parameter 'start'"),
    ):
        cell.write_text(text)
        with pytest.raises(RecipeError, match="cell.toml") as e:
            shift_settings(cell)
        assert words in str(e.value) and "\n" not in str(e.value)


def test_print_shifts_is_the_command_and_its_errors_are_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("INSPECTOR_CONFIG_DIR", str(tmp_path / "config"))
    path = _history_with(tmp_path / "history.sqlite", [(datetime.now(UTC).isoformat(timespec="milliseconds"), "pass", None)], [])
    assert print_shifts(tmp_path) == 0
    out = capsys.readouterr().out
    assert out.startswith("shift ") and "1 inspected: 1 pass, 0 fail, 0 error; yield 100.0 %" in out
    assert path.is_file()
    assert print_shifts(tmp_path / "none") == 3
    assert capsys.readouterr().err.strip() == f"inspector: error: {tmp_path / 'none' / 'history.sqlite'}: no history " \
                                              "(inspector run writes it beside the result folders)"
    bad = tmp_path / "cell.toml"
    bad.write_text("[shifts]\nstarts = 6\n")
    assert print_shifts(tmp_path, config=bad) == 2
    assert capsys.readouterr().err.startswith("inspector: error: cell.toml: shifts.starts: expected")
    # without --config: the configuration folder's cell.toml, when there is one
    (tmp_path / "config").mkdir()
    (tmp_path / "config" / "cell.toml").write_text('[shifts]\nstarts = ["00:00"]\nnames = ["all day"]\n')
    assert print_shifts(tmp_path) == 0
    assert capsys.readouterr().out.startswith("shift all day ")
    with pytest.raises(InputError):
        shift_counters(tmp_path / "none")
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "history.sqlite").write_bytes(b"not a database" * 100)
    assert print_shifts(tmp_path / "broken") == 3
    assert "cannot be read" in capsys.readouterr().err


def test_the_worst_characteristics_of_the_shift(tmp_path):
    """The characteristics the inspections recorded (their extras): NOK first, then not
    measurable, then the most of the tolerance used; in the text of `history --shift` too."""
    from inspector.history_store import record
    from inspector.model import InspectionResult

    t0 = datetime(2026, 12, 3, 6, 0, tzinfo=UTC)
    diameters = [36.002, 35.998, 36.060, 36.001]  # the third NOK: 0.060 of a 0.05 half width
    for k, d in enumerate(diameters):
        rows = [{"id": "D1", "kind": "diameter", "nominal": 36.0, "measured": d, "deviation": d - 36.0, "lower": -0.05,
                 "upper": 0.05, "verdict": "ok" if abs(d - 36.0) <= 0.05 else "nok"},
                {"id": "T2", "kind": "distance", "nominal": 6.0, "measured": None if k == 1 else 6.004, "lower": -0.02,
                 "upper": 0.02, "verdict": "not_measurable" if k == 1 else "ok"}]
        record(InspectionResult(f"p{k}", "r", "fail" if d > 36.05 else "pass", None, {}, extras={"characteristics": rows}),
               tmp_path, now=t0 + timedelta(minutes=k))
    record(InspectionResult("plain", "r", "pass", None, {}), tmp_path, now=t0 + timedelta(minutes=9))
    settings = ShiftSettings(starts=("06:00",), names=("day",), timezone="UTC")
    (c,) = shift_counters(tmp_path, settings, now=t0 + timedelta(hours=1))
    assert c.inspected == 5
    d1, t2 = c.characteristics
    assert (d1.id, d1.parts, d1.nok, d1.not_measurable) == ("D1", 4, 1, 0)
    assert d1.worst_use == pytest.approx(0.060 / 0.05)
    assert (t2.id, t2.parts, t2.nok, t2.not_measurable) == ("T2", 4, 0, 1)
    assert t2.worst_use == pytest.approx(0.004 / 0.02)  # no deviation in the row: measured - nominal
    text = format_shifts([c])
    assert "worst characteristics" in text and "D1" in text and "120.0 %" in text


def test_the_shift_report_pdf_holds_the_counters(tmp_path, capsys):
    """`inspector history OUTDIR --shift 2 --pdf FILE`: one A4 page per shift, its text the
    counters `--shift` prints; refused without --shift; an unwritable file is one line, exit 3."""
    from pypdf import PdfReader

    from inspector.history_store import record
    from inspector.model import InspectionResult

    now = datetime.now(UTC)
    rows = [{"id": "D1", "measured": 36.06, "nominal": 36.0, "lower": -0.05, "upper": 0.05, "verdict": "nok"}]
    record(InspectionResult("p1", "r", "fail", None, {}, extras={"characteristics": rows}), tmp_path, now=now)
    record(InspectionResult("p2", "r", "pass", None, {}), tmp_path, now=now)
    record(InspectionResult("p3", "r", "error", "rig.json: not valid JSON (line 3 column 1)", {}), tmp_path, now=now)
    cell = tmp_path / "cell.toml"
    cell.write_text('[shifts]\nstarts = ["00:00", "12:00"]\nnames = ["am", "pm"]\ntimezone = "UTC"\n')
    pdf = tmp_path / "shift.pdf"
    assert main(["history", str(tmp_path), "--shift", "2", "--config", str(cell), "--pdf", str(pdf)]) == 0
    assert f"shift report written to {pdf}" in capsys.readouterr().out
    pages = PdfReader(pdf).pages
    assert len(pages) == 2
    assert all([round(float(p.mediabox.width)), round(float(p.mediabox.height))] == [595, 842] for p in pages)  # A4
    text = pages[1].extract_text()  # the current shift: the three rows
    for word in ("Shift report", "inspected", "3", "50.0 %", "D1", "rig.json: not valid JSON", "Errors by reason"):
        assert word in text, word
    assert "no inspection in this shift" in pages[0].extract_text()
    assert main(["history", str(tmp_path), "--pdf", str(pdf)]) == 2
    assert "--pdf: the shift report; give --shift too" in capsys.readouterr().err
    assert main(["history", str(tmp_path), "--shift", "--config", str(cell), "--pdf", str(tmp_path / "no" / "x.pdf")]) == 3
    assert capsys.readouterr().err.startswith(f"inspector: error: --pdf {tmp_path / 'no' / 'x.pdf'}: cannot be written")
