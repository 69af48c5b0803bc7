"""The characteristics on the operator screen (issue 28, point 6): the table of the current
part's characteristics (value, limits, deviation bar, OK/NOK, U) in a tab beside the
defects, and the trend of the selected one over the recorded parts; on a real X display,
from a real history.sqlite, and end to end from an inspection in the window."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PySide6.QtCore import Qt

from inspector.history_store import record
from inspector.model import InspectionResult
from inspector_frontends.gui.viewmodel import ResultView, characteristic_rows, reason_text

pytestmark = [pytest.mark.gui]

ROOT = Path(__file__).resolve().parents[3]
SHOTS = ROOT / "out" / "gui-screenshots"
DIAMETERS = [36.002, 35.998, None, 36.004, 36.061]  # the third not measurable, the last NOK


def _row(cid, kind, nominal, value, lower, upper, unit="mm", description=""):
    verdict = "not_measurable" if value is None else ("ok" if lower <= value - nominal <= upper else "nok")
    return {"id": cid, "kind": kind, "features": ["F04"], "nominal": nominal, "measured": value,
            "deviation": None if value is None else value - nominal, "lower": lower, "upper": upper,
            "u": None if value is None else 0.0015, "U": None if value is None else 0.003,
            "points": 0 if value is None else 900, "verdict": verdict,
            "reason": "too few points (12 of 50)" if value is None else "", "unit": unit, "criticality": "major",
            "description": description}


def _part(k: int, d: float | None) -> InspectionResult:
    rows = [_row("1", "diameter", 36.0, d, -0.05, 0.05, description="\u00d836 boss"),
            _row("2", "flatness", 0.0, 0.01 + 0.002 * k, 0.0, 0.05),
            _row("3", "angle", 90.0, 90.01, -0.1, 0.1, unit="deg")]
    verdict = "fail" if any(r["verdict"] == "nok" for r in rows) else "pass"
    return InspectionResult(f"p{k}", "r", verdict, None, {}, extras={"characteristics": rows})


@pytest.fixture
def history(tmp_path):
    results = [_part(k, d) for k, d in enumerate(DIAMETERS)]
    for r in results:
        record(r, tmp_path)
    from inspector.history_store import read_history

    return results, read_history(tmp_path, last=50)


def _view(result: InspectionResult) -> ResultView:
    doc = {"extras": result.extras}
    chars = characteristic_rows(doc)
    return ResultView(capture=result.capture, verdict=result.verdict, characteristics=chars,
                      reason=reason_text(result.verdict, [], (-0.1, 0.1), None, chars))


def _colours(img) -> np.ndarray:
    from PySide6.QtGui import QImage

    img = img.convertToFormat(QImage.Format.Format_RGB888)
    arr = np.frombuffer(img.constBits(), np.uint8, img.sizeInBytes())
    rows = arr.reshape(img.height(), img.bytesPerLine())[:, : img.width() * 3]
    return rows.reshape(img.height(), img.width(), 3).copy()  # a copy: the converted image dies here


def _red(a: np.ndarray) -> int:
    return int(((a[..., 0] > 150) & (a[..., 1] < 80) & (a[..., 2] < 80)).sum())


def _green(a: np.ndarray) -> int:
    return int(((a[..., 1] > 100) & (a[..., 0] < 80) & (a[..., 2] < 100)).sum())


def test_a_nok_characteristic_is_the_reason_and_the_tab_says_it(qtbot, history):
    from inspector_frontends.gui.characteristics import CharacteristicsPanel, ResultTabs
    from inspector_frontends.gui.widgets import DefectTable

    results, rows = history
    tabs = ResultTabs(DefectTable(), CharacteristicsPanel())
    qtbot.addWidget(tabs)
    tabs.resize(900, 520)
    tabs.show()
    qtbot.waitExposed(tabs)
    assert not tabs.isTabVisible(1), "no characteristics: no tab"
    view = _view(results[-1])
    assert view.reason == ("characteristic 1 (\u00d836 boss): 36.061 mm, deviation +0.061, limits -0.050 / +0.050")
    tabs.show_result(view)
    tabs.characteristics.show_history(rows)
    assert tabs.isTabVisible(1) and tabs.currentIndex() == 1, "the NOK characteristic explains the FAIL"
    assert tabs.tabText(0) == "Defects (0)" and tabs.tabText(1) == "Characteristics (3, 1 NOK)"
    table = tabs.characteristics.table
    assert table.rowCount() == 3
    texts = [[table.item(r, c).text() for c in range(table.columnCount())] for r in range(3)]
    assert texts[0][:4] == ["1", "\u00d836 boss", "36.0610", "36.0000 \u00b10.0500"]
    assert texts[1][3] == "\u2264 0.0500"  # a form characteristic: its upper limit
    assert texts[0][4:] == ["+0.0610", "0.0030", "\u2716 NOK"] and texts[1][6] == "\u2714 OK"
    assert texts[2][2] == "90.010\u00b0"
    # The worst (the NOK one) is selected; its trend holds every recorded part that measured it.
    assert [i.row() for i in table.selectionModel().selectedRows()] == [0]
    trend = tabs.characteristics.trend
    assert [p.value for p in trend.points] == DIAMETERS and trend.current == "p4"
    assert trend.title == "1 \u00d836 boss: last 5 parts"
    qtbot.wait(50)
    img = _colours(tabs.grab().toImage())
    SHOTS.mkdir(parents=True, exist_ok=True)
    tabs.grab().save(str(SHOTS / "gui-characteristics-panel.png"))
    # The deviation bar of the NOK row is red, the OK rows' green; the trend crosses the NOK value in red.
    bar = table.visualItemRect(table.item(0, 4)).translated(table.viewport().mapTo(tabs, table.viewport().rect().topLeft()))
    assert _red(img[bar.top():bar.bottom(), bar.left():bar.right()]) > 10
    bar1 = table.visualItemRect(table.item(1, 4)).translated(table.viewport().mapTo(tabs, table.viewport().rect().topLeft()))
    cell = img[bar1.top():bar1.bottom(), bar1.left():bar1.right()]
    assert _red(cell) == 0 and _green(cell) > 10
    chart = _colours(trend.grab().toImage())
    assert _red(chart) > 15, "the NOK value is not crossed in red"
    assert trend.limits() is not None and trend.limits()[0] < trend.limits()[1]


def test_the_selection_is_kept_from_part_to_part(qtbot, history):
    from inspector_frontends.gui.characteristics import CharacteristicsPanel

    results, rows = history
    panel = CharacteristicsPanel()
    qtbot.addWidget(panel)
    panel.show_result(_view(results[0]))
    panel.show_history(rows[:1])
    # Part 0: all OK; the one using most of its tolerance is selected (the flatness, 10 of 50 um).
    assert panel.trend.title.startswith("2 flatness")
    panel.table.setFocus()
    panel.table.selectRow(2)  # the operator chooses the angle
    assert panel.chosen == "3" and panel.trend.title.startswith("3 angle")
    panel.show_result(_view(results[3]))
    panel.show_history(rows[:4])
    assert panel.trend.title == "3 angle: last 4 parts" and panel.trend.unit == "deg"
    assert [i.row() for i in panel.table.selectionModel().selectedRows()] == [2]
    # A not measurable value: no value, the reason in the tooltip, a gap in the trend.
    panel.show_result(_view(results[2]))
    assert panel.table.item(0, 6).text() == "\u2014 not measurable"
    assert panel.table.item(0, 6).toolTip() == "too few points (12 of 50)"
    assert panel.table.item(0, 2).text() == "-"


@pytest.mark.slow
def test_the_window_shows_the_measured_characteristics(qtbot, sim_captures, tmp_path, monkeypatch):
    """An inspection in the window of a recipe measuring the cube: a NOK distance (nominal
    set 20 um off) fails the part, the banner says which, the characteristics' tab comes
    forward with the values result.json holds, and the trend grows with each part."""
    from inspector_frontends.gui.window import MainWindow

    for name in ("INSPECTOR_STAGE_LIMIT_S", "INSPECTOR_INSPECTION_LIMIT_S"):
        monkeypatch.setenv(name, "86400")
    demo = (ROOT / "recipes" / "demo.toml").read_text()
    head = demo[:demo.index("[driver]")] + demo[demo.index("[[stages]]"):demo.index("[tolerance]")]
    recipe = tmp_path / "cube-chars.toml"
    recipe.write_text(
        head + '[[stages]]\nname = "characteristics"\nuse = "evaluate.characteristics"\n\n'
        + demo[demo.index("[tolerance]"):]
        + '\n[[characteristics]]\nid = "1"\nkind = "distance"\nfeatures = ["F01", "F06"]\nlower = -0.05\nupper = 0.05\n'
        + 'description = "width 30"\n'
        + '\n[[characteristics]]\nid = "2"\nkind = "distance"\nfeatures = ["F02", "F05"]\nnominal = 29.98\n'
        + 'lower = -0.01\nupper = 0.01\ndescription = "depth 29.98"\n'
        + '\n[[characteristics]]\nid = "3"\nkind = "flatness"\nfeatures = ["F04"]\nlower = 0\nupper = 0.05\n')
    out = tmp_path / "gui"
    w = MainWindow(recipe, out, capture=sim_captures["good"], config_dir=tmp_path / "config")
    qtbot.addWidget(w)
    w.resize(1600, 960)
    w.show()
    qtbot.waitExposed(w)
    try:
        for k in (1, 2):
            with qtbot.waitSignal(w.result_shown, timeout=300_000):
                w.inspect()
            qtbot.waitUntil(lambda: not w.worker.busy, timeout=60_000)
            doc = json.loads((out / "good" / "result.json").read_text())
            measured = {r["id"]: r for r in doc["extras"]["characteristics"]}
            assert doc["verdict"] == "fail" and measured["2"]["verdict"] == "nok"
            assert w.banner.reason.text().startswith("characteristic 2 (depth 29.98): ")
            assert w.tables.currentWidget() is w.characteristics
            assert w.tables.tabText(1) == "Characteristics (3, 1 NOK)"
            table = w.characteristics.table
            assert table.item(1, 2).text() == f"{measured['2']['measured']:.4f}"
            assert table.item(1, 5).text() == f"{measured['2']['U']:.4f}"
            assert w.characteristics.trend.title == f"2 depth 29.98: last {k} parts"
        SHOTS.mkdir(parents=True, exist_ok=True)
        w.grab().save(str(SHOTS / "gui-characteristics.png"))
        qtbot.mouseClick(table.viewport(), Qt.MouseButton.LeftButton, pos=table.visualItemRect(table.item(0, 1)).center())
        assert w.characteristics.chosen == "1"
        assert [p.value for p in w.characteristics.trend.points] == [measured["1"]["measured"]] * 2
    finally:
        w.close()
