"""Python's garbage collector run on the GUI thread only, while the GUI runs.

Python's cyclic collector runs in whichever thread happens to allocate when a generation's
threshold is crossed. In the GUI that is often the session's worker thread (an inspection
allocates a lot), and a Qt widget caught in a reference cycle (a closed window, a dialog) is
then destroyed there: ``QOpenGLWidget``'s destructor (the 3D view) makes its context current
and Qt aborts the process, or a later widget reads a freed screen (both seen in the test
suite, gdb backtraces: ``~QOpenGLWidget`` from ``gc_collect_main`` in a worker thread).
Qt objects must be destroyed on the thread that owns them, so while the GUI runs the
automatic collector is off and a timer on the GUI thread collects, generation by generation,
as the thresholds would have (``gc.get_count`` against ``gc.get_threshold``). Objects
without cycles are still freed at once by reference counting, in any thread.

And the objects alive once the window is up are left out of the full collections
(:func:`freeze_startup_objects`, ``gc.freeze``): scanning them blocked the GUI thread.
"""

from __future__ import annotations

import gc
from typing import TYPE_CHECKING, Any

from PySide6.QtCore import QObject, QTimer

if TYPE_CHECKING:
    from inspector_frontends.gui.window import MainWindow

__all__ = ["GuiThreadCollector", "freeze_startup_objects", "REFREEZE_OBJECTS"]

#: How often the GUI thread looks at the collector's counts (ms): garbage in cycles waits at
#: most this long; a young-generation collection costs well under a millisecond.
INTERVAL_MS = 250


class GuiThreadCollector(QObject):
    """While installed: automatic garbage collection off, collections on this (the GUI)
    thread from a timer. :meth:`uninstall` collects once more and restores the collector as
    it was."""

    def __init__(self, parent: QObject | None = None, interval_ms: int = INTERVAL_MS) -> None:
        super().__init__(parent)
        self._was_enabled = gc.isenabled()
        self._timer = QTimer(self)
        self._timer.setInterval(interval_ms)
        self._timer.timeout.connect(self.check)
        self.collections = [0, 0, 0]  # per generation, for the tests and the benchmark
        gc.disable()
        self._timer.start()

    def check(self) -> None:
        """Collect the oldest generation whose count is over its threshold (as the automatic
        collector would have at the last allocation)."""
        counts, limits = gc.get_count(), gc.get_threshold()
        generation = -1
        for g in range(3):
            if limits[g] and counts[g] > limits[g]:
                generation = g
        if generation >= 0:
            gc.collect(generation)
            self.collections[generation] += 1

    def uninstall(self) -> None:
        """Stop the timer, collect what is left (here, on the GUI thread) and switch the
        automatic collector back on if it was on."""
        self._timer.stop()
        gc.collect()
        if self._was_enabled:
            gc.enable()


#: After a result is drawn, objects left out of the garbage collector's scans again once
#: more than this many are tracked (what the first inspections import lazily).
REFREEZE_OBJECTS = 20_000


def freeze_startup_objects(window: MainWindow | None = None) -> None:
    """Leave the objects alive now (modules, Qt, VTK and matplotlib wrappers: some 420k) out
    of Python's full garbage collections from now on (``gc.freeze``). A full collection
    scans every tracked object, in whichever thread triggers it and holding the GIL: with
    them it blocked the GUI thread 300-900 ms every eleventh inspection or so (measured);
    without them it takes a few ms. The modules the first inspection imports (some 130k
    objects: 70-90 ms a full collection, every few inspections) are left out too: with
    ``window``, after each result it draws while more than :data:`REFREEZE_OBJECTS` objects
    are tracked. Call once, when the window is up (``inspector gui`` and ``bench --gui`` do;
    a test suite need not: its leak checks look for objects with ``gc.get_objects``, which
    leaves frozen ones out)."""
    gc.collect()
    gc.freeze()
    if window is not None:
        window.result_shown.connect(_refreeze)


def _refreeze(view: Any) -> None:
    if len(gc.get_objects()) > REFREEZE_OBJECTS:
        gc.freeze()  # no collection first: it would cost what is avoided (a few garbage objects stay)
