"""GUI tests: a real X display (pytest-xvfb starts Xvfb; make installs it), pytest-qt, and a
leak check after each test in the manner of pyvistaqt's own conftest."""

from __future__ import annotations

import gc
import os

import pytest

NO_DISPLAY = None
if os.environ.get("QT_QPA_PLATFORM", "xcb") not in ("xcb", ""):
    NO_DISPLAY = f"QT_QPA_PLATFORM={os.environ['QT_QPA_PLATFORM']}: VTK's window needs a real X display"


def pytest_collection_modifyitems(config, items):
    # pytest-xvfb has set DISPLAY by now when Xvfb is installed.
    reason = NO_DISPLAY or (None if os.environ.get("DISPLAY") else
                            "no X display: install xvfb (make does it when run as root) so pytest-xvfb can start one")
    if reason is None:
        return
    for item in items:
        if "gui" in item.keywords:
            item.add_marker(pytest.mark.skip(reason=reason))


def _live_interactors() -> list:
    from pyvistaqt import QtInteractor

    live = []
    for o in gc.get_objects():
        try:
            if isinstance(o, QtInteractor) and not getattr(o, "_closed", True):
                live.append(o)
        except ReferenceError:  # a dead weakref.proxy left by an earlier test in this process
            continue
    return live


def _uses_qt(request) -> bool:
    return "gui" in request.keywords and ("qapp" in request.fixturenames or "qtbot" in request.fixturenames)


@pytest.fixture(autouse=True)
def gui_thread_collector(request):
    """As ``inspector gui`` runs: Python's garbage collector on the GUI thread only (a window
    left in a reference cycle, collected by a session's worker thread, aborts the process)."""
    if not _uses_qt(request):
        yield None
        return
    from PySide6.QtWidgets import QApplication

    from inspector_frontends.gui.collector import GuiThreadCollector

    request.getfixturevalue("qapp")
    collector = GuiThreadCollector(QApplication.instance())
    yield collector
    collector.uninstall()
    collector.deleteLater()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """After a GUI test has let go of its fixtures (``item.funcargs``, cleared after the last
    teardown): what it left in cycles collected here, on the GUI thread, not by the next
    test's worker thread."""
    try:
        return (yield)
    finally:
        if "gui" in item.keywords:
            gc.collect()


@pytest.fixture(autouse=True)
def no_leaked_windows(request, gui_thread_collector):
    """After a GUI test: no open top-level window and no plotter left unclosed."""
    yield
    if not _uses_qt(request):
        return
    from PySide6.QtWidgets import QApplication

    app = QApplication.instance()
    for _ in range(3):
        app.processEvents()
    gc.collect()
    open_windows = [w for w in app.topLevelWidgets() if w.isVisible()]
    for w in open_windows:
        w.close()
    assert not open_windows, f"windows left open: {[type(w).__name__ for w in open_windows]}"
    assert not _live_interactors(), "a QtInteractor was not closed (VTK window and actors leak)"
