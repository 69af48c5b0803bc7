"""The operator window's languages: every text of the GUI's sources has a German and a
Spanish translation, the compiled files are those of the sources, and a window in German or
Spanish shows no English text (a walk over every widget's text, tooltip, title and accessible
name, compared with the same window in English); numbers and dates in the locale's format."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

pytestmark = [pytest.mark.gui, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[3]
DEMO = ROOT / "recipes" / "demo.toml"

#: Words that are the same in the translation (checked by a person, not missed).
SAME = {"de": {"Name", "OK", "U (k=2)"}, "es": {"ERROR", "U (k=2)", "nominal", "OK", "NOK"}}


def test_every_text_of_the_sources_has_a_translation():
    from inspector_frontends.gui.i18n import LANGUAGES
    from inspector_frontends.gui.i18n.build import untranslated

    assert LANGUAGES == ("en", "de", "es")
    for lang in LANGUAGES[1:]:
        assert untranslated(lang) == [], f"{lang}: run python -m inspector_frontends.gui.i18n.build and translate"


def test_the_compiled_translations_are_those_of_the_sources(tmp_path):
    from inspector_frontends.gui.i18n import FOLDER
    from inspector_frontends.gui.i18n.build import tool

    for lang in ("de", "es"):
        qm = tmp_path / f"{lang}.qm"
        subprocess.run([tool("pyside6-lrelease"), str(FOLDER / f"inspector_{lang}.ts"), "-qm", str(qm)], check=True,
                       capture_output=True)
        assert qm.read_bytes() == (FOLDER / f"inspector_{lang}.qm").read_bytes(), \
            f"inspector_{lang}.qm is stale: python -m inspector_frontends.gui.i18n.build"


def test_the_language_comes_from_the_request_or_the_system():
    from inspector_frontends.gui.i18n import choose

    assert choose("de") == choose("de_AT") == choose("de-DE") == "de"
    assert choose(None, "es_ES.UTF-8") == "es" and choose(None, "de_CH") == "de"
    assert choose(None, "fr_FR") == choose(None, "C") == choose(None, "") == "en"
    with pytest.raises(ValueError, match="language 'fr' is not available"):
        choose("fr")


def _texts(root) -> list[tuple[str, str]]:
    """(where, text) of every text a person can see or hear in ``root`` and its children."""
    from PySide6.QtWidgets import QAbstractButton, QGroupBox, QLabel, QMenu, QTableWidget, QWidget

    out: list[tuple[str, str]] = []
    for k, w in enumerate([root, *root.findChildren(QWidget)]):
        where = f"{k}:{type(w).__name__}:{w.objectName()}"
        if w.isWindow():
            out.append((where + " title", w.windowTitle()))
        out += [(where + " tooltip", w.toolTip()), (where + " accessible", w.accessibleName())]
        if isinstance(w, QLabel):
            out.append((where + " text", w.text()))
        if isinstance(w, QAbstractButton):
            out.append((where + " text", w.text()))
        if isinstance(w, QGroupBox):
            out.append((where + " title", w.title()))
        if isinstance(w, QMenu):
            out.append((where + " title", w.title()))
            out += [(f"{where} item {a.text()}", a.text()) for a in w.actions() if not a.isSeparator()]
        if isinstance(w, QTableWidget):
            for c in range(w.columnCount()):
                out.append((f"{where} header {c}", w.horizontalHeaderItem(c).text()))
            if w.objectName() == "" and w.columnCount() > 1 and w.rowCount():
                out.append((f"{where} kind", w.item(0, 1).text()))  # the defect's kind: words, not data
    return [(a, t) for a, t in out if t]


def _untranslated(en: list[tuple[str, str]], other: list[tuple[str, str]], lang: str) -> list[str]:
    assert len(en) == len(other), "the windows differ in their widgets"
    bad = []
    for (where, a), (_, b) in zip(en, other, strict=True):
        if a != b or not re.search(r"[^\W\d_]", a):  # translated, or no word in it (numbers, glyphs)
            continue
        if a in SAME[lang] or a.startswith("/"):  # the same word; a path
            continue
        bad.append(f"{where}: {a!r}")
    return bad


def _dialogs(parent):
    from inspector_frontends.gui.cameras import CameraDialog
    from inspector_frontends.gui.editor import LoginDialog
    from inspector_frontends.gui.viewmodel import CameraThumb

    thumb = CameraThumb("cam03", np.zeros((8, 8), np.uint8), 1.0, np.zeros(2), None, np.zeros((0, 2)), False, 0.0)
    return [LoginDialog(parent), CameraDialog(thumb, parent)]


@pytest.fixture(scope="module")
def fail_result(tmp_path_factory, sim_captures):
    from inspector_frontends.cli import main

    out = tmp_path_factory.mktemp("i18n") / "out"
    assert main(["run", str(DEMO), "--capture", str(sim_captures["notched"]), "--out", str(out), "-q"]) == 1
    return out / "notched"


#: One window per process: a QMainWindow made after another language's window was closed in
#: the same process crashed (segfault in its constructor) after the other GUI test files had
#: run in that process; a language is what a window is started with, so each child starts one.
_CHILD = """
import json, sys
from pathlib import Path
sys.path.insert(0, sys.argv[4])
from PySide6.QtTest import QTest
from PySide6.QtWidgets import QApplication
app = QApplication([])
import test_i18n as t
from inspector_frontends.gui.i18n import install
from inspector_frontends.gui.window import MainWindow
lang, result, config = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
install(lang)
w = MainWindow(t.DEMO, result.parent, config_dir=config)
w.show_on_screen()
assert QTest.qWaitForWindowExposed(w, 60000)
assert w.open_result(result)
w.flush_drawing()
dialogs = t._dialogs(w)
out = {"texts": t._texts(w) + [x for d in dialogs for x in t._texts(d)], "word": w.banner.word.text(),
       "detail": w.banner.detail.text(), "reason": w.banner.reason.text(), "cell": w.defects.item(0, 4).text(),
       "shift": w.history.shift.title.text()}
print("JSON " + json.dumps(out), flush=True)
w.close()
"""


def _window_texts(tmp_path, lang: str, result: Path) -> dict:
    """What the window shows in ``lang`` for ``result``, from a process of its own."""
    import json
    import sys

    run = subprocess.run([sys.executable, "-c", _CHILD, lang, str(result), str(tmp_path / "config"),
                          str(Path(__file__).parent)], capture_output=True, text=True, timeout=600)
    line = next((x for x in run.stdout.splitlines() if x.startswith("JSON ")), None)
    assert line is not None, f"{lang}: exit {run.returncode}: {run.stderr[-2000:]}"
    data = json.loads(line[5:])
    data["texts"] = [tuple(x) for x in data["texts"]]
    return data


def test_no_visible_text_is_left_in_english(tmp_path, fail_result):
    texts = {lang: _window_texts(tmp_path, lang, fail_result)["texts"] for lang in ("en", "de", "es")}
    assert len(texts["en"]) > 60  # the walk saw the window: menus, buttons, banner, table, shift panel, dialogs
    seen = {t for _, t in texts["en"]}
    assert {"INSPECT", "FAIL", "Engineer login", "Fit (0)", "no error in this shift"} <= seen
    for lang in ("de", "es"):
        assert _untranslated(texts["en"], texts[lang], lang) == []


def test_numbers_and_dates_in_the_locale_format(tmp_path, fail_result):
    de = _window_texts(tmp_path, "de", fail_result)
    assert de["word"] == "NIO"
    assert re.search(r"Takt \d+,\d\d s", de["detail"]), de["detail"]
    assert re.search(r"Grenzen -0,10 / \+0,10", de["detail"])
    assert re.search(r"-\d,\d{3} mm, Grenze -0,100 mm", de["reason"]), de["reason"]
    assert re.fullmatch(r"[-+]\d,\d{3}", de["cell"])
    assert re.search(r"\d{2}\.\d{2}\.\d{2} \d{2}:\d{2} bis \d{2}:\d{2}", de["shift"])
    en = _window_texts(tmp_path, "en", fail_result)
    assert re.search(r"cycle \d+\.\d\d s", en["detail"])
    assert re.fullmatch(r"[-+]\d\.\d{3}", en["cell"])
