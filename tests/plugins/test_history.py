"""The built-in ``history`` plugin: one SQLite row per inspection, read by ``inspector history``."""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path

import pytest

from inspector_frontends.cli import main

DEFAULT = str(Path(__file__).resolve().parents[2] / "recipes" / "default.toml")


def _run(captures, out: Path) -> int:
    return main(["run", DEFAULT, "--capture", *map(str, captures), "--out", str(out), "--reference", "builtin:cube30", "-q"])


@pytest.fixture
def two_parts(tmp_path, small_capture):
    a = shutil.copytree(small_capture, tmp_path / "c" / "part-a")
    b = shutil.copytree(small_capture, tmp_path / "c" / "part-b")
    meta = json.loads((a / "capture.json").read_text()) if (a / "capture.json").exists() else {}
    (a / "capture.json").write_text(json.dumps({**meta, "part_id": "A-0001", "timestamp": "2026-12-01T08:00:00+00:00"}))
    (b / "rig.json").write_text("{ broken")  # an error result is recorded too
    return a, b


def test_every_inspection_is_a_row_and_a_rerun_adds_rows(tmp_path, two_parts):
    out = tmp_path / "out"
    _run(two_parts, out)
    _run(two_parts[:1], out)  # part-a again: its result folder is rewritten, the history is not
    con = sqlite3.connect(out / "history.sqlite")
    rows = con.execute("SELECT capture, part_id, triggered_at, verdict, error, n_points, n_defects, result_dir"
                       " FROM inspections ORDER BY id").fetchall()
    res = json.loads((out / "part-a" / "result.json").read_text())
    a = ("part-a", "A-0001", "2026-12-01T08:00:00+00:00", res["verdict"], None, res["stats"]["n_points"],
         len(res["defects"]), "part-a")
    assert rows[0] == a and rows[2] == a
    assert rows[1][:4] == ("part-b", None, None, "error") and rows[1][4].startswith("rig.json: not valid JSON")
    assert con.execute("PRAGMA user_version").fetchone() == (1,)
    tol = con.execute("SELECT tolerance_lower_mm, tolerance_upper_mm FROM inspections ORDER BY id").fetchall()
    assert tol == [(-0.1, 0.1), (None, None), (-0.1, 0.1)]  # the recipe's band; none for an error
    n_def = con.execute("SELECT COUNT(*) FROM defects").fetchone()[0]
    assert n_def == 2 * len(res["defects"])


def test_inspector_history_lists_the_runs_and_the_yield(tmp_path, two_parts, capsys):
    out = tmp_path / "out"
    _run(two_parts, out)
    capsys.readouterr()
    assert main(["history", str(out)]) == 0
    text = capsys.readouterr().out
    assert "part-a" in text and "A-0001" in text and "part-b" in text and "ERROR" in text
    assert text.strip().splitlines()[-1].startswith("2 inspections: ")
    assert main(["history", str(out), "--json", "--last", "1"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["capture"] for r in rows] == ["part-b"]


def test_no_history_is_one_line(tmp_path, capsys):
    assert main(["history", str(tmp_path)]) == 3
    assert capsys.readouterr().err.strip() == (
        f"inspector: error: {tmp_path / 'history.sqlite'}: no history (inspector run writes it beside the result folders)")


def test_a_history_that_cannot_be_written_costs_only_its_row(tmp_path, two_parts, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "history.sqlite").write_bytes(b"this is not a database" * 100)
    code = _run(two_parts[:1], out)
    assert code in (0, 1)  # the part was inspected and its result written
    assert json.loads((out / "part-a" / "result.json").read_text())["verdict"] in ("pass", "fail")
    err = capsys.readouterr().err
    assert "inspector: warning: plugin 'history' failed on part-a (inspector_on_result): DatabaseError: " in err
    assert "Traceback" not in err


def test_the_trend_picture_shows_each_part_in_its_verdict_colour(tmp_path, two_parts, capsys):
    import cv2

    out = tmp_path / "out"
    _run(two_parts, out)
    png = tmp_path / "trend.png"
    assert main(["history", str(out), "--plot", str(png)]) == 0
    assert capsys.readouterr().out.strip().endswith(f"wrote {png}")
    img = cv2.imread(str(png)).astype(int)  # BGR
    verdict = json.loads((out / "part-a" / "result.json").read_text())["verdict"]
    b, g, r = img[..., 0], img[..., 1], img[..., 2]
    green = (g > 110) & (r < 80) & (b < 80)
    red = (r > 160) & (g < 60) & (b < 60)
    grey = (abs(r - 136) < 12) & (abs(g - 136) < 12) & (abs(b - 136) < 12)  # the error's cross
    assert (red if verdict == "fail" else green).sum() > 50 and (green if verdict == "fail" else red).sum() == 0
    assert grey.sum() > 10


# --------------------------------------------------------------------------- the hash chain (issue 27)


def _result(i: int):
    """A result; every third one fails with a defect."""
    from inspector.model import Defect, DeviationStats, EvaluationSummary, InspectionResult

    defects = (Defect("missing", (1.0, 2.0, 3.0 + i), (0.5, 0.5, 0.5), 12, -0.25 - i / 1000, "default"),) if i % 3 == 0 else ()
    dev = DeviationStats(mean=0.001 * i, std=0.01, min=-0.05, max=0.05, p01=-0.04, p99=0.04, mean_abs=0.02)
    return InspectionResult(
        capture=f"part-{i:04d}", recipe="cube-30", verdict="fail" if defects else "pass", error=None,
        timings_s={"total": 0.8}, defects=defects, metadata={"part_id": f"P-{i:05d}"},
        summary=EvaluationSummary(n_points=1000 + i, deviation_mm=dev, tolerance_mm=(-0.1, 0.1), within_tolerance=0.99,
                                  out_of_tolerance_points=12 if defects else 0))


def _sql(path: Path, *statements: str) -> None:
    con = sqlite3.connect(path)
    try:
        for s in statements:
            con.execute(s)
        con.commit()
    finally:
        con.close()


def test_verify_names_the_row_changed_or_removed_with_sqlite3(tmp_path, capsys):
    from inspector import history_store
    from inspector_plugins import history

    for i in range(1, 8):
        history_store.record(_result(i), tmp_path, cell="cell-1")
    db = tmp_path / "history.sqlite"
    assert main(["history", str(tmp_path), "--verify"]) == 0
    assert "chain intact: 7 rows from id 1" in capsys.readouterr().out
    # fail -> pass: the row is named, exit 1; put back, intact again (the content is what is hashed)
    _sql(db, "UPDATE inspections SET verdict = 'pass', n_defects = 0 WHERE id = 3")
    assert main(["history", str(tmp_path), "--verify"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"inspector: error: {db}: inspections: chain broken: row id 3 (capture part-0003, pass) was changed")
    assert len(err.strip().splitlines()) == 1
    _sql(db, "UPDATE inspections SET verdict = 'fail', n_defects = 1 WHERE id = 3")
    assert main(["history", str(tmp_path), "--verify"]) == 0
    capsys.readouterr()
    # a defect of the row, edited: the row is named
    _sql(db, "UPDATE defects SET worst_mm = -0.01 WHERE inspection_id = 6")
    assert main(["history", str(tmp_path), "--verify"]) == 1
    assert "row id 6 (capture part-0006, fail) was changed" in capsys.readouterr().err
    _sql(db, "UPDATE defects SET worst_mm = -0.256 WHERE inspection_id = 6")
    assert main(["history", str(tmp_path), "--verify"]) == 0
    capsys.readouterr()
    # a row removed (with its defects): named by the id missing before the next row
    _sql(db, "DELETE FROM defects WHERE inspection_id = 3", "DELETE FROM inspections WHERE id = 3")
    assert main(["history", str(tmp_path), "--verify"]) == 1
    assert "1 row removed before row id 4 (capture part-0004, pass): id 3 missing" in capsys.readouterr().err
    # a chain value edited away is a change too
    _sql(db, "UPDATE inspections SET chain = NULL WHERE id = 5")
    report = history.verify_history(tmp_path)
    assert not report.ok and report.bad_id == 4  # the first problem is still the removal


def test_an_older_file_gets_the_chain_from_its_next_row(tmp_path, capsys):
    from inspector import history_store

    con = sqlite3.connect(tmp_path / "history.sqlite")
    con.executescript(history_store.SCHEMA.replace(",\n    chain TEXT", ""))  # the version before the chain
    con.execute("CREATE UNIQUE INDEX inspections_uid ON inspections (uid)")
    for k in range(2):
        con.execute("INSERT INTO inspections (inspected_at, capture, recipe, verdict, n_defects) "
                    f"VALUES ('t', 'old-{k}', 'r', 'pass', 0)")
    con.commit()
    con.close()
    assert main(["history", str(tmp_path), "--verify"]) == 0
    assert "no row has a hash: all 2 were written before the chain" in capsys.readouterr().out
    for i in (3, 4, 5):
        history_store.record(_result(i), tmp_path, cell="cell-1")
    assert main(["history", str(tmp_path), "--verify"]) == 0
    out = capsys.readouterr().out
    assert "chain intact: 3 rows from id 3; the 2 rows before id 3 were written before the chain" in out
    assert [r["chain"] is None for r in history_store.read_history(tmp_path)] == [True, True, False, False, False]
    _sql(tmp_path / "history.sqlite", "UPDATE inspections SET verdict = 'pass' WHERE id = 3")
    assert main(["history", str(tmp_path), "--verify"]) == 1
    assert "row id 3 (capture part-0003, pass) was changed" in capsys.readouterr().err
    assert main(["history", str(tmp_path / "none"), "--verify"]) == 3
    assert main(["history", str(tmp_path), "--verify", "--send"]) == 2
