"""Kiosk mode (``inspector gui --kiosk``, ``[gui] kiosk = true``): the operator has no way
out by keyboard or the window's close, sees no menu item that leaves the operator's role, and
gets the window back in front after a dialog; the engineer can leave."""

from __future__ import annotations

import argparse
import signal
from pathlib import Path

import pytest
from PySide6.QtCore import QObject, Qt, Signal

pytestmark = [pytest.mark.gui, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[3]
DEMO = ROOT / "recipes" / "demo.toml"
PASSWORD = "kiosk-engineer-1"


@pytest.fixture
def kiosk(qtbot, tmp_path):
    from inspector.roles import set_password
    from inspector_frontends.gui.window import MainWindow

    set_password(PASSWORD, config_dir=tmp_path / "config")
    w = MainWindow(DEMO, tmp_path / "out", config_dir=tmp_path / "config", kiosk=True)
    w.show_on_screen()
    qtbot.waitExposed(w)
    w.activateWindow()
    qtbot.waitUntil(w.isActiveWindow, timeout=5000)
    yield w
    w.shutdown()


def _visible_items(w) -> set[str]:
    items = set()
    for menu_action in w.menuBar().actions():
        for act in menu_action.menu().actions():
            if act.isVisible() and not act.isSeparator():
                items.add(act.text())
    return items


# The keys a desktop or Qt uses to close a window or quit.
CLOSE_KEYS = [(Qt.Key.Key_F4, Qt.KeyboardModifier.AltModifier), (Qt.Key.Key_Q, Qt.KeyboardModifier.ControlModifier),
              (Qt.Key.Key_W, Qt.KeyboardModifier.ControlModifier), (Qt.Key.Key_F4, Qt.KeyboardModifier.ControlModifier),
              (Qt.Key.Key_Escape, Qt.KeyboardModifier.NoModifier)]


def test_the_operator_cannot_leave_the_kiosk(kiosk, qtbot):
    w = kiosk
    assert w.isFullScreen() and w.windowFlags() & Qt.WindowType.FramelessWindowHint
    assert w.geometry() == w.screen().geometry()
    items = _visible_items(w)
    assert "Quit" not in items and "Choose recipe…" not in items and "Edit recipe…" not in items
    assert "Back to operator" not in items and "Engineer login…" in items
    assert not w.act_quit.isEnabled()
    for key, mod in CLOSE_KEYS:
        qtbot.keyClick(w, key, mod)
        qtbot.wait(50)
        assert w.isVisible(), f"{key} {mod} closed the kiosk"
    # What a window manager's Alt+F4 or close button sends: a close event, refused.
    assert w.close() is False and w.isVisible()
    assert "closing needs engineer mode" in w.progress_label.text()


def test_the_engineer_can_leave_by_keyboard(kiosk, qtbot):
    w = kiosk
    assert w.login("eng", PASSWORD)
    items = _visible_items(w)
    assert {"Quit", "Choose recipe…", "Edit recipe…", "Back to operator"} <= items
    qtbot.keyClick(w, Qt.Key.Key_Q, Qt.KeyboardModifier.ControlModifier)
    qtbot.waitUntil(lambda: not w.isVisible(), timeout=5000)


def test_back_to_operator_locks_again(kiosk, qtbot):
    w = kiosk
    assert w.login("eng", PASSWORD)
    w.logout()
    assert "Quit" not in _visible_items(w)
    assert w.close() is False and w.isVisible()


def test_the_window_comes_back_to_the_front_after_a_dialog(kiosk, qtbot):
    from PySide6.QtWidgets import QApplication

    from inspector_frontends.gui.editor import LoginDialog

    w = kiosk
    dlg = LoginDialog(w)
    dlg.open()
    qtbot.waitExposed(dlg)
    dlg.activateWindow()
    qtbot.waitUntil(lambda: QApplication.activeWindow() is dlg, timeout=5000)
    dlg.reject()
    qtbot.waitUntil(lambda: QApplication.activeWindow() is w, timeout=5000)
    assert w.isFullScreen()
    # and after the window lost the focus to nothing (another program's window closed)
    w.clearFocus()
    dlg2 = LoginDialog(w)
    dlg2.show()
    qtbot.waitExposed(dlg2)
    dlg2.activateWindow()
    qtbot.waitUntil(lambda: QApplication.activeWindow() is dlg2, timeout=5000)
    dlg2.hide()
    qtbot.waitUntil(lambda: QApplication.activeWindow() is w, timeout=5000)
    dlg2.deleteLater()


def test_a_window_without_kiosk_closes_as_before(qtbot, tmp_path):
    from inspector_frontends.gui.window import MainWindow

    w = MainWindow(DEMO, tmp_path / "out", config_dir=tmp_path / "config")
    w.show_on_screen()
    qtbot.waitExposed(w)
    assert not w.isFullScreen() and "Quit" in _visible_items(w)
    assert w.close() is True


class _FakeWindow(QObject):
    """Stands in for MainWindow in ``inspector gui``'s run: records what it was given."""

    made: list[dict] = []
    result_shown = Signal(object)

    def __init__(self, recipe, out, **kw):
        super().__init__()
        _FakeWindow.made.append(kw)

    def show_on_screen(self):
        from PySide6.QtCore import QTimer
        from PySide6.QtWidgets import QApplication

        QTimer.singleShot(0, QApplication.instance().quit)

    def inspect(self):
        return True

    def shutdown(self):
        return True


def _args(**kw):
    base = dict(recipe=str(DEMO), capture=None, watch=None, out=None, reference=None, idle_logout=300.0, kiosk=None,
                lang=None, config=None)
    base.update(kw)
    return argparse.Namespace(**base)


def test_kiosk_and_language_come_from_the_command_line_or_the_cell_settings(qapp, tmp_path, monkeypatch, capsys):
    from inspector_frontends.gui import app, i18n, window

    monkeypatch.setattr(window, "MainWindow", _FakeWindow)
    monkeypatch.setattr(window, "freeze_startup_objects", lambda w: None)
    monkeypatch.setenv("INSPECTOR_CONFIG_DIR", str(tmp_path / "config"))
    _FakeWindow.made.clear()
    term = signal.getsignal(signal.SIGTERM)  # inspector gui installs its own: restored after
    cell = tmp_path / "cell.toml"
    cell.write_text('[gui]\nkiosk = true\nlang = "es"\n[shifts]\nstarts = ["07:00", "19:00"]\nnames = ["day", "night"]\n')
    try:
        assert app.run(_args(config=str(cell))) == 0
        assert _FakeWindow.made[-1]["kiosk"] is True
        assert _FakeWindow.made[-1]["shifts"].starts == ("07:00", "19:00")
        assert i18n.number(1.5, 2) == "1,50"  # Spanish numbers
        assert app.run(_args(config=str(cell), lang="de")) == 0  # --lang wins
        from PySide6.QtCore import QCoreApplication

        assert QCoreApplication.translate("MainWindow", "INSPECT") == "PRÜFEN"
        assert app.run(_args(kiosk=True, lang="en")) == 0  # --kiosk without a cell file
        assert _FakeWindow.made[-1]["kiosk"] is True
        assert app.run(_args(lang="en")) == 0
        assert _FakeWindow.made[-1]["kiosk"] is False
        # the cell file of the configuration folder is read when there is one
        (tmp_path / "config").mkdir()
        (tmp_path / "config" / "cell.toml").write_text("[gui]\nkiosk = true\n")
        assert app.run(_args(lang="en")) == 0
        assert _FakeWindow.made[-1]["kiosk"] is True
        capsys.readouterr()
        assert app.run(_args(lang="fr")) == 2
        assert capsys.readouterr().err.strip() == "inspector: error: language 'fr' is not available (available: en, de, es)"
        cell.write_text("[gui]\nkiosk = 1\n")
        assert app.run(_args(config=str(cell))) == 2
        assert capsys.readouterr().err.strip().startswith("inspector: error: cell.toml: gui.kiosk: expected")
    finally:
        i18n.install("en")
        signal.signal(signal.SIGTERM, term)
