"""The session in a worker thread; what it does reaches the GUI as queued Qt signals.

VTK and Qt widgets may be touched only on the GUI thread (pyvistaqt aborts the process on
an ``add_mesh`` from another thread), so the worker never touches a widget: it emits
signals whose receivers live in the GUI thread, which Qt delivers through the event loop
(a queued connection). Stage progress comes from the lifecycle hooks
(``inspector_before_stage`` / ``inspector_after_stage``) of a small plugin registered on the
session's plugin manager; results are turned into a :class:`~inspector_frontends.gui.viewmodel.ResultView`
in the worker, so the GUI thread only draws. Each result comes twice: first at once without
its camera images (``verdict``: the banner need not wait for them), then complete, with what
its drawing needs made ahead by the ``prepare`` function (``result``). With a
``drawing_gate``, the worker makes those pictures only once the GUI has drawn the 3D view (or
after :data:`GATE_S`): with software OpenGL the render runs on the same CPU cores.
"""

from __future__ import annotations

import dataclasses
import sys
import threading
from collections.abc import Callable
from typing import Any

from PySide6.QtCore import QObject, Signal

from inspector import hookimpl
from inspector.errors import InspectorError
from inspector.session import Inspected, RunEnded, RunStarted, Session, Source, Warned
from inspector_frontends.gui.viewmodel import ResultView, camera_thumbs, from_outcome

__all__ = ["SessionWorker", "GATE_S"]

#: The longest the worker waits for its ``drawing_gate`` after sending a verdict, s.
GATE_S = 2.0


class _Progress:
    """Lifecycle-hook observer: each stage's start and end as a signal."""

    def __init__(self, worker: SessionWorker) -> None:
        self.worker = worker

    @hookimpl
    def inspector_before_stage(self, context: Any, stage: Any, step: str) -> None:
        self.worker.stage.emit(context.capture.name, step, -1.0)

    @hookimpl
    def inspector_after_stage(self, context: Any, stage: Any, step: str, seconds: float) -> None:
        self.worker.stage.emit(context.capture.name, step, float(seconds))


class SessionWorker(QObject):
    """Runs :meth:`Session.run` in a Python thread, one run at a time.

    Signals
    -------
    started(str)
        A run began (its source in words).
    stage(str, str, float)
        capture, stage name, seconds (-1 when the stage starts).
    verdict(object)
        A result as soon as it is written: a :class:`~inspector_frontends.gui.viewmodel.ResultView`
        without camera thumbnails. Its ``result`` follows.
    result(object)
        The same result complete (its ``points`` are the very arrays of the ``verdict``'s
        view), with ``prepare`` applied (also for ``aborted``).
    warned(str)
        A warning of the run (each once).
    ended(object)
        The :class:`~inspector.session.RunSummary`, or None when the run could not start.
    failed(str)
        A one-line error (bad source, driver failure): nothing was lost, the GUI goes on.
    """

    started = Signal(str)
    stage = Signal(str, str, float)
    verdict = Signal(object)
    result = Signal(object)
    warned = Signal(str)
    ended = Signal(object)
    failed = Signal(str)

    def __init__(self, session: Session, parent: QObject | None = None, *,
                 prepare: Callable[[ResultView], ResultView] | None = None) -> None:
        super().__init__(parent)
        self.session = session
        #: Called in the worker thread on each complete view before ``result``: what the
        #: drawing needs, made ahead (thread-safe work only: arrays, images, files).
        self.prepare = prepare
        #: When an Event: cleared before each ``verdict``, then waited for (at most
        #: :data:`GATE_S`) before the camera pictures are made; the GUI sets it once it has
        #: drawn what needs the CPU most (the 3D view).
        self.drawing_gate: threading.Event | None = None
        self._thread: threading.Thread | None = None
        # Set from start() until ``ended`` is emitted: the run as the GUI sees it. The thread
        # itself lives a little longer (it returns from Session.run after RunEnded), so its
        # liveness would make a handler of ``ended`` see a busy worker and leave INSPECT off.
        self._running = threading.Event()
        self._progress = _Progress(self)
        session.pm.register(self._progress, name="inspector-gui-progress")
        self._unsubscribe = session.subscribe(self._on_event)

    @property
    def busy(self) -> bool:
        """True from :meth:`start` until ``ended`` is emitted."""
        return self._running.is_set()

    def start(self, source: Source | None = None) -> bool:
        """Start a run; False (nothing started) when one is in progress."""
        if self.busy:
            return False
        if self._thread is not None:  # the last run's thread, returning after its ``ended``
            self._thread.join(10.0)
        self._running.set()
        self._thread = threading.Thread(target=self._run, args=(source,), name="inspector-session", daemon=True)
        self._thread.start()
        return True

    def stop(self) -> None:
        """End the run after the capture in progress."""
        self.session.stop()

    def cancel(self) -> None:
        """End the run before the next stage (the capture in progress becomes ABORTED)."""
        self.session.cancel()

    def shutdown(self, timeout_s: float = 60.0) -> bool:
        """Cancel any run, join the thread, detach from the session; True when joined."""
        self.session.cancel()
        joined = True
        if self._thread is not None:
            self._thread.join(timeout_s)
            joined = not self._thread.is_alive()
        self._unsubscribe()
        if self.session.pm.pm.is_registered(self._progress):
            self.session.pm.pm.unregister(self._progress)
        return joined

    # -- worker thread -------------------------------------------------------------------
    def _run(self, source: Source | None) -> None:
        try:
            self.session.run(source)
        except InspectorError as e:  # RecipeError too: one line, the GUI goes on
            self.failed.emit(str(e))
            self._end(None)
        except Exception as e:  # noqa: BLE001 - a bug: one line for the operator
            self.failed.emit(f"internal error {type(e).__name__}: {' '.join(str(e).split())}")
            self._end(None)
        finally:
            self._running.clear()

    def _end(self, summary: Any) -> None:
        """Not busy any more, then ``ended``: its handlers see an idle worker."""
        self._running.clear()
        self.ended.emit(summary)

    def _on_event(self, event: Any) -> None:
        if isinstance(event, RunStarted):
            self.started.emit(event.source)
        elif isinstance(event, Inspected):
            outcome = event.outcome
            view = from_outcome(outcome, event.folder, self.session.reference, cameras=False)
            gate = self.drawing_gate
            if gate is not None:
                gate.clear()
            self.verdict.emit(view)
            if gate is not None:
                gate.wait(GATE_S)
            full = view
            try:
                full = dataclasses.replace(view, cameras=camera_thumbs(outcome.context))
                if self.prepare is not None:
                    full = self.prepare(full)
            except Exception as e:  # noqa: BLE001 - the result is written and shown; only pictures are missing
                msg = " ".join(str(e).split())
                print(f"inspector: warning: gui: preparing the drawing of {view.capture} failed: "
                      f"{type(e).__name__}: {msg}", file=sys.stderr, flush=True)
            self.result.emit(full)
        elif isinstance(event, Warned):
            self.warned.emit(f"{event.capture}: {event.text}")
        elif isinstance(event, RunEnded):
            self._end(event.summary)
