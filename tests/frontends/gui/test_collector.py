"""Qt objects left in reference cycles are destroyed on the GUI thread, never by a worker
thread's garbage collection (which aborted the process in the test suite: a closed kiosk window
collected by the next inspection's worker thread). Each case runs in a process of its own: the
failure being looked for can be a crash."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

pytestmark = pytest.mark.gui

SCRIPT = textwrap.dedent("""
    import gc, json, sys, threading
    from PySide6.QtCore import Qt
    from PySide6.QtWidgets import QApplication, QWidget

    app = QApplication([])
    collector = None
    if sys.argv[1] == "collector":
        from inspector_frontends.gui.collector import GuiThreadCollector
        collector = GuiThreadCollector(app, interval_ms=20)
    main = threading.get_ident()
    where = []

    class Window(QWidget):
        def __init__(self):
            super().__init__()
            self.me = self  # a reference cycle: only the cyclic collector frees it
            self.destroyed.connect(lambda *_: where.append(threading.get_ident()), Qt.ConnectionType.DirectConnection)

    for _ in range(5):
        w = Window()
        w.show()
        app.processEvents()
        w.close()
    del w  # five windows, garbage now, that only a collection of their cycles frees

    def work():  # an inspection's allocations: the automatic collector's thresholds crossed
        for _ in range(400):
            junk = [[] for _ in range(2000)]
            for a, b in zip(junk, junk[1:]):
                a.append(b)
                b.append(a)

    t = threading.Thread(target=work)
    t.start()
    while t.is_alive():
        app.processEvents()
        t.join(0.01)
    for _ in range(20):
        app.processEvents()
    if collector is not None:
        collector.uninstall()
    gc.collect()
    print(json.dumps({"destroyed": len(where), "on_gui_thread": sum(1 for x in where if x == main),
                      "collections": collector.collections if collector else None}))
""")


def _run(mode: str) -> dict:
    done = subprocess.run([sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, (done.returncode, done.stderr[-2000:])
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_windows_in_cycles_are_destroyed_on_the_gui_thread_with_the_collector():
    d = _run("collector")
    assert d["destroyed"] == 5 and d["on_gui_thread"] == 5, d
    assert sum(d["collections"]) > 0  # the timer collected, not only the last gc.collect()


def test_without_it_the_worker_thread_destroys_them():
    """The hazard is real here (this is what the collector is for): without it, the worker's
    allocations collect the windows in the worker thread (or crash the process)."""
    done = subprocess.run([sys.executable, "-c", SCRIPT, "plain"], capture_output=True, text=True, timeout=300,
                          check=False)
    if done.returncode != 0:
        return  # the process died destroying a widget off its thread: the hazard, in its worst form
    d = json.loads(done.stdout.strip().splitlines()[-1])
    assert d["destroyed"] == 5 and d["on_gui_thread"] < 5, d
