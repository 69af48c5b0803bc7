"""Open the operator window on the X display this process was given and describe it as JSON
(run by ``tests/frontends/gui/test_screen.py`` under an Xvfb of each size; no window manager).

    python tests/frontends/gui/screen_probe.py OUT.json [--kiosk] [--lang de] [--out DIR] [--result FOLDER] [--shot PNG]

Writes the screen's geometry, the window's, every visible button's and menu bar's on the
screen (global logical pixels), whether INSPECT has the keyboard focus and whether Space
and F5 reach it; with ``--shot`` a screenshot of the whole screen.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]


def _rect(widget) -> list[int]:
    from PySide6.QtCore import QPoint

    top_left = widget.mapToGlobal(QPoint(0, 0))
    return [top_left.x(), top_left.y(), widget.width(), widget.height()]


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("json")
    ap.add_argument("--kiosk", action="store_true")
    ap.add_argument("--lang", default="en")
    ap.add_argument("--out", default=None)
    ap.add_argument("--result", default=None, help="a result folder to show (open_result)")
    ap.add_argument("--shot", default=None)
    ap.add_argument("--config", default=None)
    args = ap.parse_args(argv)

    import tempfile

    from PySide6.QtCore import Qt
    from PySide6.QtGui import QShortcut
    from PySide6.QtTest import QTest
    from PySide6.QtWidgets import QAbstractButton, QApplication

    from inspector.shift import ShiftSettings
    from inspector_frontends.gui.i18n import install
    from inspector_frontends.gui.window import MainWindow

    app = QApplication([sys.argv[0]])  # noqa: F841 - kept alive until the end
    install(args.lang)
    tmp = Path(tempfile.mkdtemp())
    out = Path(args.out) if args.out else tmp / "out"
    window = MainWindow(ROOT / "recipes" / "demo.toml", out, config_dir=Path(args.config or tmp / "config"),
                        kiosk=args.kiosk, shifts=ShiftSettings(timezone="UTC"))
    window.show_on_screen()
    QTest.qWaitForWindowExposed(window, 10_000)
    window.activateWindow()
    QTest.qWait(600)  # the window's layout and the chart settle
    if args.result:
        window.open_result(Path(args.result))
        window.flush_drawing()
        QTest.qWait(300)
    screen = window.screen()
    doc: dict = {
        "screen": [screen.geometry().x(), screen.geometry().y(), screen.geometry().width(), screen.geometry().height()],
        "available": [screen.availableGeometry().x(), screen.availableGeometry().y(),
                      screen.availableGeometry().width(), screen.availableGeometry().height()],
        "ratio": screen.devicePixelRatio(),
        "window": [window.frameGeometry().x(), window.frameGeometry().y(), window.frameGeometry().width(),
                   window.frameGeometry().height()],
        "fullscreen": window.isFullScreen(),
        "portrait": window.portrait,
        "frameless": bool(window.windowFlags() & Qt.WindowType.FramelessWindowHint),
        "inspect_enabled": window.inspect_button.isEnabled(),
        "inspect_focus": window.inspect_button.hasFocus(),
        "buttons": {},
        "menubar": _rect(window.menuBar()),
        "statusbar": _rect(window.statusBar()),
    }
    for k, b in enumerate(window.findChildren(QAbstractButton)):
        if b.isVisibleTo(window) and b.window() is window:
            doc["buttons"][b.objectName() or f"{type(b).__name__}-{k}:{b.text()}"] = _rect(b)
    if args.shot:
        screen.grabWindow(0).save(args.shot)
    # Keyboard: Space and F5 reach INSPECT (counted on its shortcuts, the session closed
    # first so that nothing is inspected).
    hits: list[str] = []
    for sc in window.findChildren(QShortcut):
        name = sc.key().toString()
        if name in ("Space", "F5"):
            sc.activated.connect(lambda name=name: hits.append(name))
    window._close_session()
    window.activateWindow()
    QTest.qWait(100)
    doc["active"] = QApplication.activeWindow() is window
    for key in (Qt.Key.Key_Space, Qt.Key.Key_F5):
        QTest.keyClick(window, key)
    QTest.qWait(100)
    doc["keys_reaching_inspect"] = sorted(hits)
    Path(args.json).write_text(json.dumps(doc, indent=1))
    window.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
