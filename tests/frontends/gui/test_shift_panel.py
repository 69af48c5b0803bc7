"""The shift at a glance in the operator window: the panel's counters are the history's for
the same rows (a history made by real inspections: the CLI's, then one of the window's)."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path

import pytest
from PySide6.QtCore import Qt

pytestmark = [pytest.mark.gui, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[3]
DEMO = ROOT / "recipes" / "demo.toml"


def test_the_shift_panel_counts_what_the_history_has(qtbot, tmp_path, sim_captures):
    from inspector.history_store import read_history
    from inspector.shift import ShiftSettings
    from inspector_frontends.cli import main
    from inspector_frontends.gui.window import MainWindow
    from inspector_plugins.history import tally

    out = tmp_path / "out"
    assert main(["run", str(DEMO), "--capture", str(sim_captures["good"]), str(sim_captures["notched"]),
                 "--out", str(out), "-q"]) == 1
    rows = read_history(out)
    first = datetime.fromisoformat(rows[0]["inspected_at"]).astimezone(UTC)
    # One 24-hour shift from the first row's minute: every row is in it, whenever the test runs.
    shifts = ShiftSettings(starts=(first.strftime("%H:%M"),), names=("day",), timezone="UTC")
    w = MainWindow(DEMO, out, capture=sim_captures["notched"], config_dir=tmp_path / "config", shifts=shifts)
    qtbot.addWidget(w)
    w.show_on_screen()
    qtbot.waitExposed(w)
    w.activateWindow()
    qtbot.waitUntil(w.isActiveWindow, timeout=5000)

    def check() -> None:
        rows = read_history(out)
        n, share = tally(rows)
        c = w.history.shift.counters
        assert c is not None and c.ids == tuple(r["id"] for r in rows)
        assert (c.passed, c.failed, c.errors) == (n["pass"], n["fail"], n["error"]) and c.yield_ == share
        text = w.history.shift.counts.text()
        assert f"{len(rows)} inspected" in text and f"pass {n['pass']}" in text and f"fail {n['fail']}" in text
        assert w.history.shift.regions.text().startswith("worst regions: default")

    check()
    assert len(read_history(out)) == 2
    with qtbot.waitSignal(w.run_finished, timeout=240_000):
        qtbot.keyClick(w, Qt.Key.Key_Space)  # a third inspection, by the window
    qtbot.waitUntil(lambda: not w.drawing, timeout=30_000)
    assert len(read_history(out)) == 3
    check()
    w.close()


def test_the_shift_panel_names_the_worst_characteristics(qtbot, tmp_path):
    """A recipe that measures characteristics: the panel names the worst of the shift (NOK
    first, then not measurable, then the most of the tolerance used), as `history --shift`."""
    from datetime import timedelta

    from inspector.history_store import record
    from inspector.model import InspectionResult
    from inspector.shift import ShiftSettings, shift_counters
    from inspector_frontends.gui.history_strip import ShiftPanel

    t0 = datetime(2026, 12, 3, 6, 0, tzinfo=UTC)
    for k, (d, t) in enumerate([(36.002, 6.004), (36.060, None), (35.990, 6.012)]):
        rows = [{"id": "D1", "measured": d, "nominal": 36.0, "lower": -0.05, "upper": 0.05,
                 "verdict": "ok" if abs(d - 36.0) <= 0.05 else "nok"},
                {"id": "T2", "measured": t, "nominal": 6.0, "lower": -0.02, "upper": 0.02,
                 "verdict": "ok" if t is not None else "not_measurable"},
                {"id": "F3", "measured": 0.01, "nominal": 0.0, "lower": 0.0, "upper": 0.04, "verdict": "ok"}]
        record(InspectionResult(f"p{k}", "r", "pass", None, {}, extras={"characteristics": rows}), tmp_path,
               now=t0 + timedelta(minutes=k))
    (c,) = shift_counters(tmp_path, ShiftSettings(starts=("06:00",), names=("day",), timezone="UTC"),
                          now=t0 + timedelta(hours=1))
    panel = ShiftPanel()
    qtbot.addWidget(panel)
    panel.show_counters(c)
    assert not panel.chars.isHidden()
    assert panel.chars.text() == "worst characteristics: D1 1\u00d7 NOK, T2 1\u00d7 not measurable, F3 at most 50% of the tolerance"
    panel.show_counters(None)
    assert panel.chars.isHidden()
