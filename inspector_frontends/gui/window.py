"""The operator screen: one window over one :class:`~inspector.session.Session`.

Layout: the verdict banner and the big buttons on top; the 3D deviation view on the left;
the defect table and the camera strip on the right; the history strip at the bottom; the
recipe, the role and the stage progress in the status bar. Keyboard: Space or F5 INSPECT,
F6 LIVE, Esc CANCEL, Ctrl+O open a capture, Ctrl+Shift+O open a result, Ctrl+E export the
report, Ctrl+L engineer login, Ctrl+R choose a recipe and Ctrl+Shift+E edit it (engineer).

The window fits the screen it opens on (:meth:`~inspector_frontends.gui.screen.ScreenWindow.fit_screen`:
the available geometry in logical pixels, never larger; a portrait screen gets the portrait
layout: :meth:`MainWindow.set_portrait`). In
kiosk mode (``inspector gui --kiosk`` or the cell's ``[gui] kiosk = true``) it is full screen
without decorations, the operator cannot close it and sees no menu item that leaves the
operator's role, and it comes back to the front after a dialog. The history strip shows the
current shift's counters (:mod:`inspector.shift`). Every text goes through ``self.tr``
(:mod:`inspector_frontends.gui.i18n`).
"""

from __future__ import annotations

import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from PySide6.QtCore import QEvent, QObject, Qt, QTimer, Signal
from PySide6.QtGui import QAction, QKeySequence, QShortcut
from PySide6.QtWidgets import (
    QApplication,
    QBoxLayout,
    QDockWidget,
    QFileDialog,
    QLabel,
    QMessageBox,
    QPushButton,
    QSizePolicy,
    QSplitter,
    QVBoxLayout,
    QWidget,
)

from inspector.errors import InputError, InspectorError, RecipeError
from inspector.manager import PluginManager, create_plugin_manager
from inspector.report import render_pdf
from inspector.roles import ENGINEER, RoleSession, password_problem
from inspector.session import Session, Source
from inspector.shift import ShiftSettings
from inspector_frontends.gui.cameras import CameraDialog, CameraStrip
from inspector_frontends.gui.characteristics import CharacteristicsPanel, ResultTabs
from inspector_frontends.gui.collector import freeze_startup_objects
from inspector_frontends.gui.editor import LoginDialog, RecipeEditor
from inspector_frontends.gui.history_strip import HistoryStrip, read_shift
from inspector_frontends.gui.i18n import number
from inspector_frontends.gui.prepare import prepare_view
from inspector_frontends.gui.screen import KioskGuard, ScreenWindow
from inspector_frontends.gui.view3d import DeviationView
from inspector_frontends.gui.viewmodel import ResultView, from_folder
from inspector_frontends.gui.widgets import HISTORY, SHIFT, DefectTable, VerdictBanner, verdict_word
from inspector_frontends.gui.worker import SessionWorker

__all__ = ["MainWindow", "freeze_startup_objects"]

STYLE = """
QWidget { font-size: 12pt; }
QPushButton#inspect, QPushButton#live, QPushButton#cancel { min-width: 150px; padding: 0 14px; font-size: 18pt; font-weight: bold; }
QPushButton#inspect { background: #1557a0; color: white; border-radius: 6px; }
QPushButton#inspect:disabled { background: #9e9e9e; color: #eeeeee; }
QPushButton#live:checked { background: #2e7d32; color: white; }
QPushButton { min-height: 44px; }
QPushButton:focus { border: 3px solid #ffab00; }
QTableWidget { font-size: 13pt; }
"""


class _Activity(QObject):
    """Any key or click counts as the engineer still being at the cell."""

    def __init__(self, roles: RoleSession) -> None:
        super().__init__()
        self.roles = roles

    def eventFilter(self, obj: QObject, event: QEvent) -> bool:
        if event.type() in (QEvent.Type.KeyPress, QEvent.Type.MouseButtonPress, QEvent.Type.Wheel):
            self.roles.touch()
        return False


class MainWindow(ScreenWindow):
    """The operator's window.

    Parameters
    ----------
    recipe : Path
        Recipe file; an invalid one is shown greyed with its reason and INSPECT is disabled.
    out : Path
        Result folder (``history.sqlite`` and the audit table live there).
    capture, watch : Path, optional
        A capture folder to inspect with INSPECT, or an inbox for LIVE.
    idle_logout_s : float
        Engineer mode falls back to operator after this long without a key or a click.
    kiosk : bool
        The cell's kiosk: full screen without decorations, the operator cannot close the
        window (Alt+F4, Ctrl+Q and the window's close are refused; the Quit item is hidden),
        the engineer can; the window comes back to the front after any dialog.
    shifts : ShiftSettings, optional
        The cell's shift times (:mod:`inspector.shift`) of the shift panel.

    Signals
    -------
    verdict_shown(object)
        A result's verdict is on screen (banner and defect table painted); the 3D view, the
        cameras and the history follow, one per event-loop turn.
    result_shown(object)
        A result is drawn everywhere (the complete :class:`ResultView`).
    run_finished(object)
        A run ended (its :class:`~inspector.session.RunSummary`, or None), once its last
        result is drawn.
    """

    verdict_shown = Signal(object)
    result_shown = Signal(object)
    run_finished = Signal(object)

    def __init__(self, recipe: Path, out: Path, *, capture: Path | None = None, watch: Path | None = None,
                 reference: str | None = None, idle_logout_s: float = 300.0, config_dir: Path | None = None,
                 pm: PluginManager | None = None, kiosk: bool = False, shifts: ShiftSettings | None = None) -> None:
        super().__init__()
        self.kiosk = kiosk
        self.shifts = shifts or ShiftSettings()
        self._leaving = False  # set by shutdown(): a close the role rules do not stop
        self.setWindowTitle(self.tr("Inspector: operator"))
        self.setStyleSheet(STYLE)
        self.out = Path(out)
        self.capture = Path(capture) if capture else None
        self.watch = Path(watch) if watch else None
        self.reference_arg = reference
        self.pm = pm if pm is not None else create_plugin_manager()
        self.roles = RoleSession(self.out, idle_s=idle_logout_s, config_dir=config_dir)
        self.config_dir = config_dir
        self.session: Session | None = None
        self.worker: SessionWorker | None = None
        self.recipe_path = Path(recipe)
        self.recipe_error: str | None = None
        self.current_result: ResultView | None = None
        self.live = False
        self.plugin_warnings: list[str] = []
        self._closing = False
        # Drawing a result is split into steps, one per event-loop turn (no turn blocks the
        # GUI thread long): (name, call) still to run, and how long each took last time.
        self._steps: list[tuple[str, Any]] = []
        self._early: ResultView | None = None  # a verdict shown whose complete view is awaited
        self._ended: Any = None  # a run's end, told once its last result is drawn
        self._ended_pending = False
        self._selected: tuple[str, ...] | None = None  # cameras of the selected defect
        self._waited = 0  # turns the "3d shown" step waited for the frame's paint
        self.draw_times: dict[str, float] = {}
        self._step_timer = QTimer(self)
        self._step_timer.setSingleShot(True)
        self._step_timer.setInterval(0)
        self._step_timer.timeout.connect(self._step)
        # Set once the 3D view of a result is drawn: the worker then makes its pictures (not
        # while the software OpenGL render needs the CPU).
        self._gate = threading.Event()
        self._build()
        self._activity = _Activity(self.roles)
        app = QApplication.instance()
        assert app is not None  # a widget exists, so does the application
        app.installEventFilter(self._activity)
        self._guard: KioskGuard | None = None
        if kiosk:
            self.setWindowFlag(Qt.WindowType.FramelessWindowHint, True)
            self._guard = KioskGuard(self)
            app.installEventFilter(self._guard)
        self._idle = QTimer(self)
        self._idle.setInterval(1000)
        self._idle.timeout.connect(self._check_idle)
        self._idle.start()
        self.open_recipe(self.recipe_path, audit=False)
        self.history.refresh(self.out, self.shifts)
        self._add_plugin_panels()
        # The shift panel rolls over to the next shift by itself, and counts what another
        # process (a CLI run on the same OUTDIR) added.
        self._shift_timer = QTimer(self)
        self._shift_timer.setInterval(60_000)
        self._shift_timer.timeout.connect(self.refresh_shift)
        self._shift_timer.start()
        self._fitted_for: tuple[int, int, int, int] | None = None

    # -- building -----------------------------------------------------------------------------
    def _build(self) -> None:
        self.banner = VerdictBanner()
        self.inspect_button = QPushButton(self.tr("INSPECT"))
        self.inspect_button.setObjectName("inspect")
        self.inspect_button.setToolTip(self.tr("Inspect the next part (Space or F5)"))
        self.inspect_button.clicked.connect(self.inspect)
        self.live_button = QPushButton(self.tr("LIVE"))
        self.live_button.setObjectName("live")
        self.live_button.setCheckable(True)
        self.live_button.setToolTip(self.tr("Inspect continuously until stopped (F6)"))
        self.live_button.clicked.connect(self.toggle_live)
        self.cancel_button = QPushButton(self.tr("CANCEL"))
        self.cancel_button.setObjectName("cancel")
        self.cancel_button.setToolTip(self.tr("Abort the inspection in progress (Esc)"))
        self.cancel_button.clicked.connect(self.cancel)
        self.cancel_button.setEnabled(False)
        # The buttons' box: a column beside the banner (landscape), a row under it (portrait).
        self.portrait = False
        self.buttons = QBoxLayout(QBoxLayout.Direction.TopToBottom)
        for b in (self.inspect_button, self.live_button, self.cancel_button):
            b.setMinimumHeight(64)
            self.buttons.addWidget(b)
        top = QBoxLayout(QBoxLayout.Direction.LeftToRight)
        top.addWidget(self.banner, 1)
        top.addLayout(self.buttons)
        self.top_box = top

        self.view3d = DeviationView()
        self.defects = DefectTable()
        self.defects.defect_selected.connect(self.select_defect)
        self.characteristics = CharacteristicsPanel()
        self.tables = ResultTabs(self.defects, self.characteristics)
        self.cameras = CameraStrip()
        self.cameras.opened.connect(self.open_camera)
        right = QSplitter(Qt.Orientation.Vertical)
        right.addWidget(self.tables)
        right.addWidget(self.cameras)
        right.setSizes([220, 520])
        middle = QSplitter(Qt.Orientation.Horizontal)
        middle.addWidget(self.view3d)
        middle.addWidget(right)
        middle.setSizes([1100, 800])
        self.middle, self.right = middle, right
        self.history = HistoryStrip()

        central = QWidget()
        lay = QVBoxLayout(central)
        lay.setContentsMargins(8, 8, 8, 4)
        lay.addLayout(top)
        lay.addWidget(middle, 1)
        lay.addWidget(self.history)
        self.setCentralWidget(central)

        self.recipe_label = QLabel()
        self.role_label = QLabel()
        self.progress_label = QLabel()
        for label in (self.recipe_label, self.progress_label):
            # Long texts (paths): never wider than the screen; the whole text in the tooltip.
            label.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Preferred)
            label.setMinimumWidth(1)
        sb = self.statusBar()
        sb.addWidget(self.recipe_label, 2)
        sb.addWidget(self.progress_label, 2)
        sb.addPermanentWidget(self.role_label)

        file_menu = self.menuBar().addMenu(self.tr("&File"))
        self.act_open_capture = self._action(file_menu, self.tr("Open capture folder…"), "Ctrl+O", self.ask_capture)
        self.act_open_result = self._action(file_menu, self.tr("Open result folder…"), "Ctrl+Shift+O", self.ask_result)
        self.act_export = self._action(file_menu, self.tr("Export report (PDF)"), "Ctrl+E", self.export_report)
        file_menu.addSeparator()
        self.act_quit = self._action(file_menu, self.tr("Quit"), "Ctrl+Q", self.close)
        role_menu = self.menuBar().addMenu(self.tr("&Role"))
        self.act_login = self._action(role_menu, self.tr("Engineer login…"), "Ctrl+L", self.ask_login)
        self.act_logout = self._action(role_menu, self.tr("Back to operator"), "Ctrl+Shift+L", self.logout)
        recipe_menu = self.menuBar().addMenu(self.tr("Re&cipe"))
        self.act_choose = self._action(recipe_menu, self.tr("Choose recipe…"), "Ctrl+R", self.ask_recipe)
        self.act_edit = self._action(recipe_menu, self.tr("Edit recipe…"), "Ctrl+Shift+E", self.edit_recipe)
        view_menu = self.menuBar().addMenu(self.tr("&View"))
        self._action(view_menu, self.tr("Reset 3D view"), "Home", self.view3d.reset_camera)
        self.view_menu = view_menu

        for key in ("Space", "F5"):
            QShortcut(QKeySequence(key), self, context=Qt.ShortcutContext.WindowShortcut).activated.connect(self.inspect)
        QShortcut(QKeySequence("F6"), self).activated.connect(self.toggle_live_key)
        QShortcut(QKeySequence("Escape"), self).activated.connect(self.cancel)
        self._update_role()

    def _action(self, menu: Any, text: str, key: str, slot: Any) -> QAction:
        act = QAction(text, self)
        act.setShortcut(QKeySequence(key))
        act.triggered.connect(slot)
        menu.addAction(act)
        self.addAction(act)
        return act

    def _add_plugin_panels(self) -> None:
        """Docks from the ``inspector_gui_panel`` hook; a plugin that fails is disabled with
        a warning naming it, and the GUI goes on."""
        for name, value in self.pm.gui_panels(self):
            if isinstance(value, Exception):
                self._plugin_warning(self.tr("plugin {name} disabled: its panel raised {error}").format(
                    name=repr(name), error=f"{type(value).__name__}: {value}"))
                continue
            if value is None:
                continue
            if not (isinstance(value, tuple) and len(value) == 2 and isinstance(value[0], str) and isinstance(value[1], QWidget)):
                self._plugin_warning(self.tr("plugin {name} disabled: its panel must be (title, QWidget), got {type}").format(
                    name=repr(name), type=type(value).__name__))
                continue
            dock = QDockWidget(value[0], self)
            dock.setObjectName(f"plugin-{name}")
            dock.setWidget(value[1])
            self.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, dock)
            self.view_menu.addAction(dock.toggleViewAction())

    def _plugin_warning(self, text: str) -> None:
        self.plugin_warnings.append(text)
        print(f"inspector: warning: {text}", file=sys.stderr, flush=True)
        self.progress_label.setText(f"\u26a0 {text}")

    # -- recipe and session -------------------------------------------------------------------
    def open_recipe(self, path: Path, *, audit: bool = True) -> bool:
        """Use ``path``; an invalid recipe leaves the screen greyed with its reason."""
        before = self.recipe_path if audit else None
        self._close_session()
        self.recipe_path = Path(path)
        try:
            self.session = Session.open(self.recipe_path, self.out, reference=self.reference_arg, pm=self.pm)
        except InspectorError as e:
            self.session = None
            self.recipe_error = str(e)
        else:
            self.recipe_error = None
            self.worker = SessionWorker(self.session, self, prepare=self._prepare)
            self.worker.drawing_gate = self._gate
            self.worker.started.connect(self._on_started)
            self.worker.stage.connect(self._on_stage)
            self.worker.verdict.connect(self._on_verdict)
            self.worker.result.connect(self.show_result)
            self.worker.warned.connect(lambda t: self.progress_label.setText("\u26a0 " + self.tr("warning: {text}").format(text=t)))
            self.worker.failed.connect(self._on_failed)
            self.worker.ended.connect(self._on_ended)
        if audit and before is not None and before != self.recipe_path:
            self.roles.record_recipe_change(self.roles.user or "?", before, self.recipe_path)
        self._update_recipe_label()
        self._update_buttons()
        return self.recipe_error is None

    def _close_session(self) -> None:
        if self.worker is not None:
            self.worker.shutdown()
            self.worker.deleteLater()
            self.worker = None
        if self.session is not None:
            self.session.close()
            self.session = None

    def _update_recipe_label(self) -> None:
        if self.recipe_error:
            self.recipe_label.setText(self.tr("recipe {name}: INVALID: {error}").format(name=self.recipe_path.name, error=self.recipe_error))
            self.recipe_label.setStyleSheet("color: #9e9e9e;")
            self.recipe_label.setToolTip(self.recipe_error)
            self.banner.set_state("invalid", f"{self.recipe_path}", self.recipe_error)
        else:
            s = self.session
            if s is None:  # closed (a valid recipe always has a session while open)
                return
            src = (self.tr("capture {path}").format(path=self.capture) if self.capture else
                   self.tr("watch {path}").format(path=self.watch) if self.watch else
                   self.tr("driver {name}").format(name=s.recipe.driver.spec.name))
            self.recipe_label.setText(self.tr("recipe {name} ({file}, sha256 {sha}) \u00b7 {source} \u00b7 results in {out}").format(
                name=s.recipe.name, file=self.recipe_path.name, sha=(s.recipe.sha256 or "")[:10], source=src, out=self.out))
            self.recipe_label.setStyleSheet("")
            self.recipe_label.setToolTip(str(self.recipe_path))

    def _update_buttons(self) -> None:
        busy = self.worker is not None and self.worker.busy
        ok = self.session is not None
        self.inspect_button.setEnabled(ok and not busy)
        self.live_button.setEnabled(ok and (not busy or self.live))
        self.cancel_button.setEnabled(busy)
        self.act_open_capture.setEnabled(ok and not busy)
        engineer = self.roles.role == ENGINEER
        if self.kiosk:  # the operator's kiosk shows no item that leaves the operator's role
            for act in (self.act_quit, self.act_choose, self.act_edit, self.act_logout):
                act.setVisible(engineer)
        self.act_quit.setEnabled(engineer or not self.kiosk)
        self.act_choose.setEnabled(engineer and not busy)
        self.act_edit.setEnabled(engineer and not busy and self.recipe_path.is_file())
        self.act_login.setEnabled(not engineer)
        self.act_logout.setEnabled(engineer)
        self.act_export.setEnabled(self.current_result is not None and self.current_result.folder is not None)

    # -- running ------------------------------------------------------------------------------
    def _source(self, *, continuous: bool) -> Source:
        if self.capture is not None:
            return Source(captures=(str(self.capture),), limit=None if continuous else 1)
        if self.watch is not None:
            return Source(watch={"folder": str(self.watch)}, limit=None if continuous else 1)
        return Source(limit=None if continuous else 1)

    def _refused_for_role(self) -> bool:
        """On a production station the operator runs only recipes an engineer approved
        (issue 27, :meth:`~inspector.roles.RoleSession.run_problem`): the banner says why."""
        if self.session is None:
            return False
        problem = self.roles.run_problem(self.session.recipe)
        if problem is None:
            return False
        self.banner.set_state("error", self.tr("this recipe may not run in the operator role"), problem)
        return True

    def inspect(self) -> bool:
        """INSPECT: one part from the source; False when nothing could start."""
        if self.worker is None or self.worker.busy or self._refused_for_role():
            return False
        self.live = False
        started = self.worker.start(self._source(continuous=False))
        self._update_buttons()
        return started

    def toggle_live_key(self) -> None:
        self.live_button.setChecked(not self.live_button.isChecked())
        self.toggle_live()

    def toggle_live(self) -> None:
        if self.worker is None:
            self.live_button.setChecked(False)
            return
        if self.live_button.isChecked() and not self.worker.busy:
            if self._refused_for_role():
                self.live_button.setChecked(False)
                return
            self.live = True
            self.worker.start(self._source(continuous=True))
        elif not self.live_button.isChecked() and self.live:
            self.worker.stop()  # ends after the part in progress
            self.progress_label.setText(self.tr("LIVE stopping after the part in progress…"))
        self._update_buttons()

    def cancel(self) -> None:
        if self.worker is not None and self.worker.busy:
            self.worker.cancel()
            self.progress_label.setText(self.tr("cancelling before the next stage…"))

    def _on_started(self, what: str) -> None:
        self.banner.set_state("busy", f"{self.tr('LIVE') if self.live else self.tr('INSPECT')}: {what}")
        self._update_buttons()

    def _on_stage(self, capture: str, step: str, seconds: float) -> None:
        if seconds < 0:
            self.progress_label.setText(f"{capture}: {step} …")
            if self.banner.state != "busy":
                self.banner.set_state("busy", f"{capture}: {step} …")
        else:
            self.progress_label.setText(self.tr("{capture}: {step} done ({seconds} s)").format(
                capture=capture, step=step, seconds=number(seconds, 2)))

    def _on_failed(self, message: str) -> None:
        self.banner.set_state("error", self.tr("the run could not go on"), message)
        self.progress_label.setText(self.tr("error: {message}").format(message=message))

    def _on_ended(self, summary: Any) -> None:
        self.live = False
        self.live_button.setChecked(False)
        self._update_buttons()
        if summary is not None and not summary.inspected and not summary.counts.get("aborted"):
            self.progress_label.setText(self.tr("no capture arrived") if summary.inbox is not None else self.tr("nothing to inspect"))
            if self.banner.state == "busy":
                self.banner.set_state("ready", self.tr("nothing was inspected"))
        self.inspect_button.setFocus()
        if self._early is not None:  # its complete view never came (the worker sends it before the end)
            self._early = None
            self._steps.append(("done", self._drawn))
        if self._steps:  # told once the last result is drawn
            self._ended, self._ended_pending = summary, True
            self._step_timer.start()
        else:
            self.run_finished.emit(summary)

    # -- showing a result ---------------------------------------------------------------------
    def _prepare(self, view: ResultView) -> ResultView:
        """In the worker thread: the drawing of ``view`` made ahead (camera pictures, history
        rows and chart). Reads no widget: the chart's size is a value the strip keeps."""
        return prepare_view(view, self.out, self.history.chart_size(), self.shifts)

    def _on_verdict(self, view: ResultView) -> None:
        """A result without its camera images, as soon as it is written: the verdict now, the
        3D view next; the cameras and the history with its complete view (show_result)."""
        if self._closing:
            return
        self._begin(view, complete=False)

    def show_result(self, view: ResultView) -> None:
        """Draw one result everywhere (on the GUI thread): the verdict at once (banner and
        defect table painted before this returns, then ``verdict_shown``), then the 3D
        scene, its render, the cameras and the history strip, each in its own event-loop
        turn, then ``result_shown``. A newer result drops what is left of an older one."""
        if self._closing:  # a result queued while the window closed: written, not drawn
            return
        early = self._early
        if early is not None and view.points is early.points and view.capture == early.capture:
            # The complete view of the verdict on screen: what was left to draw.
            self._early = None
            self.current_result = view
            self._steps += self._rest(view)
            self._step_timer.start()
            return
        self._begin(view, complete=True)

    def _begin(self, view: ResultView, *, complete: bool) -> None:
        t0 = time.perf_counter()
        if self._ended_pending:  # the last run's end: told now, its drawing is replaced
            summary, self._ended, self._ended_pending = self._ended, None, False
            self.run_finished.emit(summary)
        self._early = None if complete else view
        self._selected = None
        self._waited = 0
        self.current_result = view
        self.banner.show_result(view)
        self.tables.show_result(view)
        if view.characteristics and self.right.sizes()[0] < 400 and not self.portrait:
            # Room for the characteristics' table (its labels) and their trend, once.
            self.right.setSizes([420, sum(self.right.sizes()) - 420])
            wide = min(760, sum(self.middle.sizes()) // 2)
            if self.middle.sizes()[1] < wide:
                self.middle.setSizes([sum(self.middle.sizes()) - wide, wide])
        word = verdict_word(view.verdict)
        self.progress_label.setText(self.tr("{capture}: {verdict} in {seconds} s").format(
            capture=view.capture, verdict=word, seconds=number(view.cycle_s, 2)) if view.cycle_s is not None
            else f"{view.capture}: {word}")
        self._update_buttons()
        self.inspect_button.setFocus()
        self.banner.repaint()  # on screen now, before anything else is drawn
        self.draw_times = {"verdict": time.perf_counter() - t0}
        self.verdict_shown.emit(view)
        self._steps = [("3d scene", lambda: self.view3d.update_scene(view)), ("3d render", self.view3d.render),
                       ("3d shown", self._after_3d)]
        if complete:
            self._steps += self._rest(view)
        self._step_timer.start()

    def _after_3d(self) -> bool:
        """Once the 3D view's frame is on screen (False: not yet, again next turn; a few
        turns at most), the worker may make its pictures: not while software OpenGL renders
        and shows the frame on the same CPU cores."""
        self._waited += 1
        if self.view3d.frame_pending and self._waited < 10:
            return False
        self._waited = 0
        self._gate.set()
        return True

    def _rest(self, view: ResultView) -> list[tuple[str, Any]]:
        return [("cameras", lambda: self._show_cameras(view)), ("history", lambda: self._show_history(view)),
                ("done", self._drawn)]

    def _show_cameras(self, view: ResultView) -> None:
        self.cameras.show_result(view)
        if self._selected is not None:
            self.cameras.highlight(self._selected)

    def _show_history(self, view: ResultView) -> None:
        prepared = view.prepared.get(HISTORY)
        if prepared is None:  # a result opened from its folder: read here
            self.history.refresh(self.out, self.shifts)
        else:
            self.history.show_rows(*prepared)
            self.history.shift.show_counters(view.prepared.get(SHIFT))
        self.characteristics.show_history(self.history.rows)

    def _drawn(self) -> None:
        self.result_shown.emit(self.current_result)
        if self._ended_pending:
            summary, self._ended, self._ended_pending = self._ended, None, False
            self.run_finished.emit(summary)

    def _step(self) -> None:
        """One step of the drawing (the timer calls it once per event-loop turn)."""
        if self._closing or not self._steps:
            return
        name, call = self._steps.pop(0)
        t0 = time.perf_counter()
        if call() is False:  # not yet: again in the next turn
            self._steps.insert(0, (name, call))
        self.draw_times[name] = time.perf_counter() - t0
        if self._steps:
            self._step_timer.start()

    def flush_drawing(self) -> None:
        """Draw what is left of the result now (before the view is used: a defect selected,
        a camera opened, a report exported)."""
        self._step_timer.stop()
        self._gate.set()  # drawn here and now: the worker need not wait for it
        self._waited = 0
        while self._steps and not self._closing:
            name, call = self._steps.pop(0)
            if name != "3d shown":
                call()

    @property
    def drawing(self) -> bool:
        """Whether a result is still being drawn."""
        return bool(self._steps) or self._early is not None

    def select_defect(self, index: int) -> None:
        self.flush_drawing()
        v = self.current_result
        if v is None or not 0 <= index < len(v.defects):
            return
        self.view3d.fly_to(index)
        self._selected = tuple(v.defects[index].cameras)
        self.cameras.highlight(self._selected)
        d = v.defects[index]
        text = (self.tr("defect {n}: missing material {worst} mm, seen by {cameras}") if d.kind == "missing"
                else self.tr("defect {n}: excess material {worst} mm, seen by {cameras}"))
        self.progress_label.setText(text.format(n=d.number, worst=number(d.worst_mm, 3, sign=True),
                                                cameras=", ".join(d.cameras) or self.tr("no camera")))

    def open_camera(self, name: str) -> CameraDialog | None:
        self.flush_drawing()
        v = self.current_result
        thumb = next((t for t in (v.cameras if v else ()) if t.name == name), None)
        if thumb is None:
            return None
        dlg = CameraDialog(thumb, self)
        dlg.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
        dlg.open()
        return dlg

    # -- files --------------------------------------------------------------------------------
    def ask_capture(self) -> None:
        path = QFileDialog.getExistingDirectory(self, self.tr("Open capture folder"), options=self._dialog_options())
        if path:
            self.open_capture(Path(path))

    def _dialog_options(self, *, folders: bool = True) -> QFileDialog.Option:
        """Folders only (or files), and in kiosk mode Qt's own file dialog (a desktop's
        native one opens the file manager's way out of the operator's screen)."""
        options = QFileDialog.Option.ShowDirsOnly if folders else QFileDialog.Option(0)
        return options | QFileDialog.Option.DontUseNativeDialog if self.kiosk else options

    def open_capture(self, path: Path) -> None:
        """INSPECT now reads this capture folder (or folder of captures)."""
        self.capture, self.watch = Path(path), None
        self._update_recipe_label()
        self.inspect()

    def ask_result(self) -> None:
        path = QFileDialog.getExistingDirectory(self, self.tr("Open result folder"), str(self.out),
                                                options=self._dialog_options())
        if path:
            self.open_result(Path(path))

    def open_result(self, folder: Path) -> bool:
        """Show a result folder written earlier, without inspecting again."""
        try:
            view = from_folder(folder, self.session.reference if self.session else None)
        except InputError as e:
            self.banner.set_state("error", self.tr("cannot open {folder}").format(folder=folder), str(e))
            return False
        self.show_result(view)
        return True

    def export_report(self) -> Path | None:
        """report.pdf in the shown result's folder, with the 3D view as its picture."""
        self.flush_drawing()
        v = self.current_result
        if v is None or v.folder is None:
            self.progress_label.setText(self.tr("no written result to export"))
            return None
        try:
            with tempfile.TemporaryDirectory() as tmp:
                picture = self.view3d.screenshot(Path(tmp) / "view.png") if len(v.points) else None
                pdf = render_pdf(v.folder, picture=picture,
                                 recipe=self.recipe_path if self.session and self.session.recipe.name == v.recipe else None)
        except (InspectorError, OSError) as e:
            self.progress_label.setText(self.tr("export failed: {error}").format(error=e))
            return None
        self.progress_label.setText(self.tr("report written: {path}").format(path=pdf))
        return pdf

    # -- roles --------------------------------------------------------------------------------
    def ask_login(self) -> None:
        dlg = LoginDialog(self, password_problem(config_dir=self.config_dir))
        if dlg.exec():
            self.login(dlg.who.text().strip() or "engineer", dlg.password.text())

    def login(self, who: str, password: str) -> bool:
        ok = self.roles.login_engineer(password, who)
        if not ok:
            QMessageBox.warning(self, self.tr("Engineer login"), self.tr("Wrong password, or no engineer password is set "
                                                                        "(`inspector roles set-password`)."))
        self._update_role()
        return ok

    def logout(self) -> None:
        self.roles.logout()
        self._update_role()

    # -- the screen and the kiosk -------------------------------------------------------------
    def set_portrait(self, portrait: bool) -> None:
        """The portrait layout (a screen higher than wide): the buttons in a row under the
        banner, the 3D view above the defects and cameras, which sit side by side."""
        self.portrait = portrait
        self.top_box.setDirection(QBoxLayout.Direction.TopToBottom if portrait else QBoxLayout.Direction.LeftToRight)
        self.buttons.setDirection(QBoxLayout.Direction.LeftToRight if portrait else QBoxLayout.Direction.TopToBottom)
        self.middle.setOrientation(Qt.Orientation.Vertical if portrait else Qt.Orientation.Horizontal)
        self.right.setOrientation(Qt.Orientation.Horizontal if portrait else Qt.Orientation.Vertical)
        self.right.setSizes([400, 400] if portrait else [220, 520])

    def shutdown(self) -> bool:
        """Close the window whatever the role (the application quitting, a test's end)."""
        self._leaving = True
        return self.close()

    def refresh_shift(self) -> None:
        """Read the current shift's counters again (also once a minute: a new shift begins
        by itself)."""
        self.history.shift.show_counters(read_shift(self.out, self.shifts))

    def _check_idle(self) -> None:
        if self.roles.check_idle():
            self.progress_label.setText(self.tr("engineer idle: back to operator"))
        self._update_role()

    def _update_role(self) -> None:
        if self.roles.role == ENGINEER:
            left = self.roles.idle_remaining()
            self.role_label.setText(self.tr("ENGINEER {user}  (operator in {time})").format(
                user=self.roles.user, time=f"{int(left) // 60}:{int(left) % 60:02d}"))
            self.role_label.setStyleSheet("color: #b86e00; font-weight: bold;")
        else:
            self.role_label.setText(self.tr("OPERATOR"))
            self.role_label.setStyleSheet("font-weight: bold;")
        self._update_buttons()

    def ask_recipe(self) -> None:
        if self.roles.role != ENGINEER:
            return
        path, _ = QFileDialog.getOpenFileName(self, self.tr("Choose recipe"), str(self.recipe_path.parent),
                                              self.tr("Recipes (*.toml)"), options=self._dialog_options(folders=False))
        if path:
            self.open_recipe(Path(path))

    def edit_recipe(self) -> Any:
        """The recipe editor (engineer only); a saved recipe is used at once."""
        if self.roles.role != ENGINEER:
            self.progress_label.setText(self.tr("the recipe editor needs engineer mode (Ctrl+L)"))
            return None
        try:
            editor = RecipeEditor(self.recipe_path, self.pm, self.out / "recipes", self)
        except RecipeError as e:
            self.progress_label.setText(self.tr("cannot edit: {error}").format(error=e))
            return None
        (self.out / "recipes").mkdir(parents=True, exist_ok=True)
        editor.accepted.connect(lambda: editor.saved and self.open_recipe(editor.saved))
        editor.open()
        return editor

    def resizeEvent(self, event: Any) -> None:
        super().resizeEvent(event)
        small = self.height() < 900
        self.banner.set_compact(small)
        self.history.canvas.setMaximumHeight(110 if small else 170)
        for b in (self.inspect_button, self.live_button, self.cancel_button):
            b.setMinimumHeight(48 if small else 64)

    # -- closing ------------------------------------------------------------------------------
    def closeEvent(self, event: Any) -> None:
        """Closing during an inspection cancels it and joins the worker."""
        if self.kiosk and not self._leaving and self.roles.role != ENGINEER:
            # The operator's kiosk stays: Alt+F4 (the window manager's close), Ctrl+Q and
            # any other close are refused; the engineer (or shutdown()) may leave.
            event.ignore()
            self.progress_label.setText(self.tr("the kiosk stays open: closing needs engineer mode (Ctrl+L)"))
            return
        self._closing = True
        self._step_timer.stop()
        self._steps = []
        self._gate.set()
        self._idle.stop()
        self._close_session()
        app = QApplication.instance()
        assert app is not None  # a widget exists, so does the application
        app.removeEventFilter(self._activity)
        if self._guard is not None:
            app.removeEventFilter(self._guard)
        self.view3d.close_plotter()
        super().closeEvent(event)
