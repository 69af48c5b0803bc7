"""``inspector bench --gui``: three figures of the operator window, measured in one command.

1. **Trigger to verdict shown** (target: at most :data:`OVERHEAD_TARGET_S` over the
   headless cycle, median): the time from calling :meth:`MainWindow.inspect` to the moment
   the verdict is on screen (``verdict_shown``: the window emits it once the banner and
   the defect table are painted; the 3D view, the cameras and the history follow, one per
   event-loop turn), against the headless cycle of the same inspection
   (``result.timings_s["total"]``, carried by the ResultView as ``cycle_s``). The time until
   all is drawn (``result_shown``) is reported beside it, and a separate headless run of the
   same capture through :class:`inspector.session.Session` (no Qt involved). The figure is
   wanted with :data:`DRAW_POINTS` points drawn: a capture that gives fewer (the simulated
   cube at 16 x 1024\u00b2 gives about 20k) is inspected as it is, and the drawing of
   :data:`DRAW_POINTS` points is measured apart by calling ``show_result`` with a copy of
   the last real result whose points are tiled (with a small jitter) up to that number; the
   figure judged is then the measured overhead plus what the extra points add before the
   verdict is on screen (the worker's per-point work and the verdict's drawing step; both
   are reported, each named for what it is, and so is the extra time until all is drawn).
2. **Event-loop stall** (target: at most :data:`STALL_TARGET_MS`): a 10 ms precise
   ``QTimer`` ticks in the GUI thread during every inspection; per inspection its worst gap
   (trigger and end of the run included as bounds, and :data:`SETTLE_S` after the end for
   the last paints). Reported: the maximum and the p99 of those worst gaps over the
   inspections after the warm-up, and the p99 of every gap; apart, the gaps while the result
   is drawn (from its arrival to the end) and the worst of the other gaps (the run itself:
   worker thread, stage signals), and the longest of each drawing step.
3. **Memory** (target: at most :data:`MEMORY_TARGET_MB` of growth): the resident memory
   (``/proc``) after the first ``first_sample`` (20) inspections and after all
   ``--gui-inspections`` (200) in the same window, and the number of actors in the 3D
   view's renderer at both points (must stay bounded). Informative beside it: the growth of
   the medians of the 10 samples up to each point (RSS swings by tens of MB between
   inspections), and the growth of the live memory (RSS right after glibc's
   ``malloc_trim(0)`` at both points: freed memory the allocator kept does not count).

The first inspection in the window is a warm-up and is left out of the figures 1 and 2 (it
counts in the memory sequence). ``--runs`` inspections after it give figure 1; the
inspections go on up to ``--gui-inspections`` for figures 2 and 3. Exit 0 once measured
(the report says MET or NOT MET), 2 without a display or with invalid arguments, 3 when an
inspection failed.

Only ``inspector bench --gui`` imports this module (``inspector_tools.bench.command`` never imports Qt).
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import math
import statistics
import sys
import tempfile
import time
from array import array
from pathlib import Path
from typing import Any

from inspector.resources import recipe_path
from inspector.session import Inspected, Session, Source
from inspector_frontends.gui.app import display_problem
from inspector_frontends.gui.viewmodel import point_arrays
from inspector_tools.bench.common import default_reference, machine, recipes_dir, rss_mb, simulate_capture, write_figures

try:  # the GUI packages are optional: `bench --gui` says so when they are missing
    from PySide6.QtWidgets import QApplication

    from inspector_frontends.gui.collector import GuiThreadCollector
    from inspector_frontends.gui.window import MainWindow, freeze_startup_objects
except ImportError as _e:
    _GUI_MISSING: ImportError | None = _e
else:
    _GUI_MISSING = None

__all__ = ["run_gui_bench", "OVERHEAD_TARGET_S", "STALL_TARGET_MS", "MEMORY_TARGET_MB", "DRAW_POINTS", "FIRST_SAMPLE"]

#: Trigger-to-verdict-shown time over the headless cycle, seconds (median).
OVERHEAD_TARGET_S = 0.2
#: Worst gap of a 10 ms GUI-thread timer during an inspection, ms.
STALL_TARGET_MS = 100.0
#: Resident-memory growth between the two samples, MB.
MEMORY_TARGET_MB = 100.0
#: Points the trigger-to-shown figure is wanted with.
DRAW_POINTS = 100_000
#: The first memory sample is taken after this many inspections.
FIRST_SAMPLE = 20
#: Interval of the stall timer, ms.
TICK_MS = 10
#: An inspection that shows nothing in this long is a failure of the benchmark, s.
INSPECTION_TIMEOUT_S = 300.0
#: After a run ended, the event loop runs this long more within the inspection's figures (the
#: paints that follow the last drawing step), s.
SETTLE_S = 0.15
#: Window size (as ``inspector gui`` opens it).
WINDOW_SIZE = (1600, 960)

_DEMO_RECIPE = recipe_path("demo.toml")  # shipped as package data: works outside the source tree


def _pct(values: list[float], q: float) -> float:
    """The ``q``-th percentile (linear interpolation), NaN for no values."""
    if not values:
        return float("nan")
    v = sorted(values)
    k = (len(v) - 1) * q / 100.0
    lo, hi = math.floor(k), math.ceil(k)
    return v[lo] + (v[hi] - v[lo]) * (k - lo)


def _median(values: list[float]) -> float:
    return statistics.median(values) if values else float("nan")


def _summary(values: list[float]) -> dict[str, float]:
    return {"median": _median(values), "min": min(values) if values else float("nan"),
            "max": max(values) if values else float("nan"), "n": len(values)}


def _word(met: bool | None) -> str:
    return "MET" if met else ("NOT MEASURED" if met is None else "NOT MET")


def _recipe_path(args: argparse.Namespace) -> str:
    """``--recipe``, or recipes/demo.toml when it was left at ``bench``'s default (the
    default recipe names no reference; demo.toml names builtin:cube30)."""
    if args.recipe == str(recipes_dir() / "default.toml"):
        return str(_DEMO_RECIPE)
    return str(args.recipe)


def _tiled(view: Any, n: int, seed: int = 0) -> Any:
    """``view`` with its points tiled up to ``n`` (each copy jittered by 0.02 mm), their
    deviations and cameras with them, and what the worker computes from them
    (:func:`~inspector_frontends.gui.viewmodel.point_arrays`): the same part, drawn with ``n`` points."""
    import numpy as np

    m = len(view.points)
    if m == 0 or m >= n:
        return view
    reps = -(-n // m)
    rng = np.random.default_rng(seed)
    pts = np.tile(np.asarray(view.points, np.float32), (reps, 1))[:n]
    pts = pts + rng.normal(0.0, 0.02, pts.shape).astype(np.float32)
    dev = np.tile(np.asarray(view.deviation, np.float32), reps)[:n]
    cam = np.tile(np.asarray(view.camera), reps)[:n]
    pts, dev, cam, arrays = point_arrays(pts, dev, cam, view.tolerance)
    return dataclasses.replace(view, points=pts, deviation=dev, camera=cam, prepared={**view.prepared, **arrays})


def _worker_points_s(view: Any, runs: int) -> float:
    """Median time of the per-point work the worker does before the verdict is sent
    (:func:`~inspector_frontends.gui.viewmodel.point_arrays`) for ``view``'s points."""
    times = []
    for _ in range(max(3, runs)):
        t = time.perf_counter()
        point_arrays(view.points, view.deviation, view.camera, view.tolerance)
        times.append(time.perf_counter() - t)
    return _median(times)


class _Harness:
    """Drives one MainWindow: INSPECT, wait for the verdict on screen, for the result drawn
    everywhere and for the run's end, with a 10 ms timer recording its ticks."""

    def __init__(self, app: Any, window: Any) -> None:
        from PySide6.QtCore import QEventLoop, Qt, QTimer

        self.app, self.window = app, window
        self.loop = QEventLoop()
        self.ticks: list[float] = []
        self.shown_at: float | None = None
        self.drawn_at: float | None = None
        self.view: Any = None
        self.finished_at: float | None = None
        self.summary: Any = None
        self.timer = QTimer()
        self.timer.setTimerType(Qt.TimerType.PreciseTimer)
        self.timer.setInterval(TICK_MS)
        self.timer.timeout.connect(self._tick)
        self.guard = QTimer()
        self.guard.setSingleShot(True)
        self.guard.timeout.connect(self._give_up)
        self.timed_out = False
        window.verdict_shown.connect(self._shown)
        window.result_shown.connect(self._drawn)
        window.run_finished.connect(self._finished)
        self.timer.start()

    def _tick(self) -> None:
        self.ticks.append(time.perf_counter())

    def _shown(self, view: Any) -> None:
        # Emitted once the banner and the defect table are painted (MainWindow.show_result).
        self.shown_at = time.perf_counter()
        self.loop.quit()

    def _drawn(self, view: Any) -> None:
        self.drawn_at = time.perf_counter()
        self.view = view
        self.loop.quit()

    def _finished(self, summary: Any) -> None:
        self.finished_at = time.perf_counter()
        self.summary = summary
        self.loop.quit()

    def _give_up(self) -> None:
        self.timed_out = True
        self.loop.quit()

    def _wait(self, done: Any) -> None:
        self.guard.start(int(INSPECTION_TIMEOUT_S * 1000))
        while not done() and not self.timed_out:
            self.loop.exec()
        self.guard.stop()

    def _settle(self) -> float:
        """Run the event loop SETTLE_S more (the paints that follow the last drawing step
        happen there, and count); the time it ended."""
        from PySide6.QtCore import QTimer

        QTimer.singleShot(int(SETTLE_S * 1000), self.loop.quit)
        self.loop.exec()
        return time.perf_counter()

    def inspect_once(self) -> dict[str, Any]:
        """One INSPECT; its record (times in seconds from the trigger, worst tick gap)."""
        self.shown_at = self.drawn_at = self.view = self.finished_at = self.summary = None
        self.timed_out = False
        self.app.processEvents()  # nothing of the last run left queued
        self.ticks = []
        t0 = time.perf_counter()
        self.ticks.append(t0)
        if not self.window.inspect():
            return {"error": "INSPECT did not start (no session, or a run in progress)"}
        self._wait(lambda: self.shown_at is not None or self.finished_at is not None)
        rec: dict[str, Any] = {}
        # run_finished comes once the last result is drawn everywhere.
        self._wait(lambda: self.finished_at is not None)
        if self.view is None:
            rec["error"] = (f"no result within {INSPECTION_TIMEOUT_S:.0f} s") if self.timed_out else \
                f"the run ended without a result ({self.window.progress_label.text() or 'no reason shown'})"
        t_end = self._settle() if not self.timed_out else time.perf_counter()
        ticks = [t for t in self.ticks if t <= t_end] + [t_end]
        gaps = [(a, b) for a, b in zip(ticks, ticks[1:])]
        # The gaps from the result's arrival to the end of its drawing (the verdict's step
        # included) are the drawing; the others are the rest of the run (worker, stages, signals).
        lo = (self.shown_at - self.window.draw_times.get("verdict", 0.0)) if self.shown_at is not None else None
        hi = t_end
        drawing = [b - a for a, b in gaps if lo is not None and b >= lo and a <= hi]
        other = [b - a for a, b in gaps if lo is None or b < lo]
        steps = dict(self.window.draw_times)
        rec.update({
            "trigger_to_shown_s": (self.shown_at - t0) if self.shown_at is not None else None,
            "trigger_to_drawn_s": (self.drawn_at - t0) if self.drawn_at is not None else None,
            "trigger_to_end_s": (self.finished_at or t_end) - t0,
            "worst_gap_ms": 1000.0 * max(b - a for a, b in gaps) if gaps else None,
            "drawing_gap_ms": 1000.0 * max(drawing) if drawing else None,
            "worst_other_gap_ms": 1000.0 * max(other) if other else None,
            "steps_ms": {k: 1000.0 * v for k, v in steps.items()},
            "gaps_ms": array("d", (1000.0 * (b - a) for a, b in gaps)),
        })
        if self.timed_out and "error" not in rec:
            rec["error"] = f"the run did not end within {INSPECTION_TIMEOUT_S:.0f} s"
        v = self.view
        if v is not None:
            rec.update({"verdict": v.verdict, "cycle_s": v.cycle_s, "points": int(len(v.points)),
                        "error": rec.get("error") or (v.error if v.verdict in ("error", "aborted") else None)})
        return rec

    def timed_show(self, view: Any) -> dict[str, Any]:
        """``show_result(view)`` as after an inspection: the time until the verdict is on
        screen (``show_result`` returns then), until all is drawn (and painted), the worst
        tick gap meanwhile (the longest the GUI thread was blocked) and each step's time."""
        self.app.processEvents()
        self.drawn_at = None
        self.timed_out = False
        self.ticks = []
        t0 = time.perf_counter()
        self.ticks.append(t0)
        self.window.show_result(view)
        t1 = time.perf_counter()
        self._wait(lambda: self.drawn_at is not None)
        t2 = self.drawn_at or time.perf_counter()
        t_end = self._settle()
        ticks = [t for t in self.ticks if t <= t_end] + [t_end]
        return {"shown_s": t1 - t0, "drawn_s": t2 - t0, "worst_gap_s": max(b - a for a, b in zip(ticks, ticks[1:])),
                "steps_s": dict(self.window.draw_times)}

    def idle_gaps(self, seconds: float) -> dict[str, float]:
        """Worst and p99 tick gap (ms) over ``seconds`` with nothing running (what is on
        screen stays drawn: the 3D view's own timers keep going)."""
        from PySide6.QtCore import QTimer

        self.app.processEvents()
        self.ticks = [time.perf_counter()]
        QTimer.singleShot(int(seconds * 1000), self.loop.quit)
        self.loop.exec()
        ticks = self.ticks + [time.perf_counter()]
        gaps = [1000.0 * (b - a) for a, b in zip(ticks, ticks[1:])]
        return {"seconds": seconds, "max_ms": max(gaps), "p99_ms": _pct(gaps, 99), "median_ms": _median(gaps),
                "ticks": len(gaps)}

    def close(self) -> None:
        self.timer.stop()
        self.guard.stop()
        try:
            self.window.verdict_shown.disconnect(self._shown)
            self.window.result_shown.disconnect(self._drawn)
            self.window.run_finished.disconnect(self._finished)
        except (RuntimeError, TypeError):  # pragma: no cover - already gone
            pass


def _snapshot(app: Any, window: Any) -> dict[str, Any]:
    """Resident memory and the window's object counts, after deferred deletions and a GC."""
    from PySide6.QtCore import QCoreApplication, QEvent, QObject

    for _ in range(3):
        QCoreApplication.sendPostedEvents(None, QEvent.Type.DeferredDelete)
        app.processEvents()
    gc.collect()
    p = window.view3d.plotter
    return {
        "rss_mb": rss_mb(),
        "actors": len(p.renderer.actors),
        "scalar_bars": len(p.scalar_bars),
        "qobjects_in_window": len(window.findChildren(QObject)),
        "python_objects": len(gc.get_objects()) + gc.get_freeze_count(),
    }


def _trimmed_rss() -> float | None:
    """Resident memory after glibc's ``malloc_trim(0)`` gave the free heap back (informative:
    what stays is held by live objects, not freed memory kept by the allocator); None where
    there is no glibc."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.malloc_trim(0)
    except (OSError, AttributeError):
        return None
    return rss_mb()


def _headless(recipe: str, reference: str | None, folder: Path, out: Path, runs: int, say: Any) -> dict[str, Any]:
    """The same capture through a Session (no Qt): 1 warm-up + ``runs``; per run the
    timings' total and the wall time of ``Session.run`` (outputs and history row included)."""
    session = Session.open(recipe, out, reference=reference)
    got: list[Any] = []
    session.subscribe(lambda e: got.append(e.outcome.result) if isinstance(e, Inspected) else None)
    records: list[dict[str, Any]] = []
    try:
        for i in range(runs + 1):
            got.clear()
            t0 = time.perf_counter()
            session.run(Source(captures=(str(folder),), limit=1))
            wall = time.perf_counter() - t0
            res = got[-1] if got else None
            rec: dict[str, Any] = {"verdict": res.verdict if res else None, "error": res.error if res else "no result",
                   "total_s": res.timings_s.get("total") if res else None, "wall_s": wall,
                   "points": int(len(res.bcps.points)) if res is not None and res.bcps is not None else 0}
            say(f"  headless {'warm-up' if i == 0 else f'run {i}/{runs}'}: {rec['verdict']} in {wall:.3f} s "
                f"(timings total {rec['total_s'] or float('nan'):.3f} s, {rec['points']} points)")
            if i:
                records.append(rec)
            if rec["verdict"] in (None, "error"):
                break
            del res
            got.clear()
    finally:
        session.close()
    del session
    gc.collect()
    return {"runs": records,
            "total_s": _summary([r["total_s"] for r in records if r["total_s"] is not None]),
            "wall_s": _summary([r["wall_s"] for r in records])}


def _draw_cost(harness: _Harness, view: Any, n_points: int, runs: int) -> dict[str, Any]:
    """``show_result`` of the last real view against the same view with ``n_points`` points,
    alternately, ``runs`` times each (verdict on screen, all drawn, the longest block of the
    GUI thread, each drawing step); the worker's per-point work for both; one render of the
    3D view with the big cloud; the event loop idle with each on screen."""
    window = harness.window
    big = _tiled(view, n_points)
    real, large = [], []
    for _ in range(runs):
        real.append(harness.timed_show(view))
        large.append(harness.timed_show(big))
    worker_real, worker_big = _worker_points_s(view, runs), _worker_points_s(big, runs)
    # One render of the 3D view with the big cloud on screen (what a camera move costs).
    render_big = []
    for _ in range(max(3, runs)):
        harness.app.processEvents()
        t = time.perf_counter()
        window.view3d.render()
        render_big.append(time.perf_counter() - t)

    def steps(records: list[dict[str, Any]]) -> dict[str, float]:
        names = {k for r in records for k in r["steps_s"]}
        return {k: _median([r["steps_s"][k] for r in records if k in r["steps_s"]]) for k in sorted(names)}

    # The event loop with nothing running, the big cloud on screen, then the real one.
    harness.timed_show(big)
    idle_big = harness.idle_gaps(2.0)
    harness.timed_show(view)
    idle_real = harness.idle_gaps(2.0)
    shown = {"real": _median([r["shown_s"] for r in real]), "big": _median([r["shown_s"] for r in large])}
    return {
        "idle_ticks_big": idle_big,
        "idle_ticks_real": idle_real,
        "points_real": int(len(view.points)),
        "points_big": int(len(big.points)),
        "shown_real_s": _summary([r["shown_s"] for r in real]),
        "shown_big_s": _summary([r["shown_s"] for r in large]),
        "drawn_real_s": _summary([r["drawn_s"] for r in real]),
        "drawn_big_s": _summary([r["drawn_s"] for r in large]),
        "worst_gap_real_s": _summary([r["worst_gap_s"] for r in real]),
        "worst_gap_big_s": _summary([r["worst_gap_s"] for r in large]),
        "worker_points_real_s": worker_real,
        "worker_points_big_s": worker_big,
        # What n_points instead of the real ones add before the verdict is on screen: the
        # worker's per-point work (before it sends the verdict) and the verdict's step.
        "extra_big_s": (shown["big"] - shown["real"]) + (worker_big - worker_real),
        "extra_drawn_big_s": _median([r["drawn_s"] for r in large]) - _median([r["drawn_s"] for r in real]),
        "render_big_s": _summary(render_big),
        "steps_real_s": steps(real),
        "steps_big_s": steps(large),
    }


def run_gui_bench(args: argparse.Namespace, *, first_sample: int = FIRST_SAMPLE, draw_points: int = DRAW_POINTS) -> int:
    """Run ``inspector bench --gui``; see the module docstring.

    ``first_sample``: inspections before the first memory sample (the test makes it small);
    ``draw_points``: points the trigger-to-shown figure is wanted with.
    """
    problem = display_problem()
    if problem:
        print(f"inspector: error: bench --gui: {problem}", file=sys.stderr)
        return 2
    total = max(int(args.gui_inspections), 1 + int(args.runs))
    for what, ok in ((f"--runs {args.runs}: expected a number >= 1", args.runs >= 1),
                     (f"--gui-inspections {args.gui_inspections}: expected more than {first_sample} "
                      f"(the first memory sample is taken after {first_sample})", args.gui_inspections > first_sample >= 1),
                     (f"--capture {args.capture}: not a folder", args.capture is None or Path(args.capture).is_dir())):
        if not ok:
            print(f"inspector: error: bench --gui {what}", file=sys.stderr)
            return 2
    if _GUI_MISSING is not None:
        e = _GUI_MISSING
        print(f"inspector: error: bench --gui: {e.name or e} is not installed (make setup installs the GUI packages)",
              file=sys.stderr)
        return 2

    say = (lambda s: None) if args.quiet else (lambda s: print(s, flush=True))
    figures_machine = machine()
    recipe = _recipe_path(args)
    reference = args.reference or default_reference(recipe, args.part)

    with tempfile.TemporaryDirectory(prefix="inspector-bench-gui-") as tmp:
        work = Path(args.keep) if args.keep else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        if args.capture:
            folder = Path(args.capture).resolve()
            source = str(folder)
        else:
            table = {"part": args.part, "seed": args.seed, "cameras": args.cameras, "width": args.size,
                     "height": args.size, "mm_per_px": args.mm_per_px}
            say(f"Simulating {args.part}: {args.cameras} cameras, {args.size}x{args.size} px at {args.mm_per_px} mm/px ...")
            folder = simulate_capture(work / "captures" / f"{args.part}-s{args.seed:04d}", table)
            source = f"simulated: part {args.part}, seed {args.seed}, {args.mm_per_px} mm/px"

        say(f"Headless reference: {folder.name} through a Session, 1 + {args.runs} runs ...")
        headless = _headless(recipe, reference, folder, work / "headless", args.runs, say)
        bad = [r for r in headless["runs"] if r["verdict"] in (None, "error")]
        if bad or not headless["runs"]:
            print(f"inspector: error: bench --gui: the headless inspection failed: "
                  f"{bad[0]['error'] if bad else 'no run'}", file=sys.stderr)
            return 3
        measured = _in_window(args, recipe, reference, folder, work, total, first_sample, draw_points, say)
        if isinstance(measured, int):
            return measured
        reference, records, samples, draw, loop_s, rss_trace = measured

    doc = _document(args, figures_machine, recipe, reference, folder, source, headless, records, samples, draw,
                    first_sample, draw_points, loop_s, rss_trace)
    if not args.quiet:
        _print_report(doc)
    if args.json:
        say(f"\n  figures written to {write_figures(args.json, doc)}")
    return 0


def _in_window(args: argparse.Namespace, recipe: str, reference: str | None, folder: Path, work: Path, total: int,
               first_sample: int, draw_points: int, say: Any) -> int | tuple[Any, ...]:
    """``total`` inspections in one MainWindow, then the drawing cost: an exit status (2 no
    session, 3 an inspection failed), or (reference, records, memory samples, drawing cost,
    seconds of the inspections, RSS trace)."""
    app = QApplication.instance() or QApplication([sys.argv[0]])
    collector = GuiThreadCollector(app)  # as `inspector gui` runs: garbage collected on this thread only
    window = MainWindow(Path(recipe), work / "gui", capture=folder, reference=reference,
                        config_dir=work / "config")
    harness = None
    try:
        if window.session is None:
            print(f"inspector: error: bench --gui: recipe {recipe}: {window.recipe_error}", file=sys.stderr)
            return 2
        reference = window.session.recipe.reference or reference
        window.resize(*WINDOW_SIZE)
        window.show()
        for _ in range(20):  # mapped and painted before the first trigger
            app.processEvents()
            time.sleep(0.01)
        freeze_startup_objects(window)  # as `inspector gui` does once its window is up
        harness = _Harness(app, window)
        say(f"GUI: {total} inspections in one window (1 warm-up, {args.runs} timed, memory after "
            f"{first_sample} and {total}) ...")
        records: list[dict[str, Any]] = []
        samples: dict[str, Any] = {}
        rss_trace: list[tuple[int, float | None]] = []
        t_start = time.perf_counter()
        for i in range(1, total + 1):
            rec = harness.inspect_once()
            rec["index"] = i
            records.append(rec)
            if rec.get("error") or rec.get("verdict") in (None, "error", "aborted"):
                print(f"inspector: error: bench --gui: inspection {i} failed: {rec.get('error')}", file=sys.stderr)
                return 3
            if i == 1 or i <= 1 + args.runs or i % 20 == 0 or i == total:
                say(f"  {'warm-up' if i == 1 else f'{i}/{total}'}: {rec['verdict']}, shown "
                    f"{rec['trigger_to_shown_s']:.3f} s after the trigger (cycle {rec['cycle_s']:.3f} s, "
                    f"{rec['points']} points), worst tick gap {rec['worst_gap_ms']:.0f} ms")
            rss_trace.append((i, rss_mb()))
            if i in (first_sample, total):
                # The figure first, then the live memory (glibc's free heap given back).
                samples["first" if i == first_sample else "last"] = {
                    "after": i, **_snapshot(app, window), "rss_after_malloc_trim_mb": _trimmed_rss()}
        loop_s = time.perf_counter() - t_start
        say(f"Drawing cost: show_result with {draw_points} points against the real view ...")
        draw = _draw_cost(harness, harness.view, draw_points, args.runs)
    finally:
        if harness is not None:
            harness.close()
        window.close()
        for _ in range(3):
            app.processEvents()
        window.deleteLater()
        app.processEvents()
        collector.uninstall()
        collector.deleteLater()
        gc.unfreeze()  # the process as it was (a test suite's leak checks see every object again)
    return reference, records, samples, draw, loop_s, rss_trace


def _document(args: argparse.Namespace, machine: dict[str, Any], recipe: str, reference: str | None, folder: Path,
              source: str, headless: dict[str, Any], records: list[dict[str, Any]], samples: dict[str, Any],
              draw: dict[str, Any], first_sample: int, draw_points: int, loop_s: float,
              rss_trace: list[tuple[int, float | None]]) -> dict[str, Any]:
    timed = records[1:1 + args.runs]
    after_warmup = records[1:]
    shown = [r["trigger_to_shown_s"] for r in timed]
    drawn = [r["trigger_to_drawn_s"] for r in timed if r.get("trigger_to_drawn_s") is not None]
    overhead = [r["trigger_to_shown_s"] - r["cycle_s"] for r in timed]
    overhead_drawn = [r["trigger_to_drawn_s"] - r["cycle_s"] for r in timed if r.get("trigger_to_drawn_s") is not None]
    overhead_all = [r["trigger_to_shown_s"] - r["cycle_s"] for r in after_warmup]
    points = timed[0]["points"] if timed else 0
    extra = draw["extra_big_s"] if points < draw_points else 0.0
    over_med = _median(overhead)
    judged = over_med + max(extra, 0.0)
    worst = [r["worst_gap_ms"] for r in after_warmup]
    all_gaps = [g for r in after_warmup for g in r["gaps_ms"]]
    stall_max, stall_p99 = (max(worst) if worst else float("nan")), _pct(worst, 99)
    first, last = samples.get("first", {}), samples.get("last", {})
    growth = (last["rss_mb"] - first["rss_mb"]) if first.get("rss_mb") is not None and last.get("rss_mb") is not None \
        else None
    per_inspection_kb = 1000.0 * growth / (last["after"] - first["after"]) if growth is not None else None
    trimmed = (last["rss_after_malloc_trim_mb"] - first["rss_after_malloc_trim_mb"]) \
        if first.get("rss_after_malloc_trim_mb") is not None and last.get("rss_after_malloc_trim_mb") is not None else None
    # RSS swings by tens of MB from one inspection to the next (freed images kept by the
    # allocator): the medians of the 10 samples up to each point, less noisy (informative).
    rss = {i: r for i, r in rss_trace if r is not None}
    win = {k: _median([rss[j] for j in range(max(1, s["after"] - 9), s["after"] + 1) if j in rss])
           for k, s in (("first", first), ("last", last)) if s}
    windowed = win["last"] - win["first"] if len(win) == 2 else None
    ticks = {
        "max_ms": stall_max,
        "p99_of_worst_ms": stall_p99,
        "median_of_worst_ms": _median(worst),
        "p99_all_gaps_ms": _pct(all_gaps, 99),
        "ticks": len(all_gaps),
        "inspections": len(worst),
        "max_drawing_ms": max((r["drawing_gap_ms"] for r in after_warmup if r["drawing_gap_ms"] is not None),
                              default=float("nan")),
        "max_outside_drawing_ms": max((r["worst_other_gap_ms"] for r in after_warmup
                                       if r["worst_other_gap_ms"] is not None), default=float("nan")),
        "p99_outside_drawing_ms": _pct([r["worst_other_gap_ms"] for r in after_warmup
                                        if r["worst_other_gap_ms"] is not None], 99),
        "worst_inspection": max(after_warmup, key=lambda r: r["worst_gap_ms"])["index"] if after_warmup else None,
        "warmup_worst_gap_ms": records[0]["worst_gap_ms"] if records else None,
        "draw_big_worst_gap_ms": 1000.0 * draw["worst_gap_big_s"]["max"],
        # Per drawing step (verdict, 3d scene, 3d render, cameras, history, done): its longest.
        "steps_max_ms": {k: max(r["steps_ms"][k] for r in after_warmup if k in r.get("steps_ms", {}))
                         for k in sorted({k for r in after_warmup for k in r.get("steps_ms", {})})},
    }
    targets = {
        "trigger_to_shown": {
            "target": f"median trigger-to-verdict-shown minus the headless cycle <= {OVERHEAD_TARGET_S} s, with "
                      f"{draw_points} points drawn",
            "value_s": judged,
            "how": ("measured" if points >= draw_points else
                    f"measured with {points} points + extra drawing time of {draw_points} points measured apart"),
            "met": judged <= OVERHEAD_TARGET_S if math.isfinite(judged) else None,
        },
        "stall": {"target": f"worst gap of a {TICK_MS} ms GUI timer during an inspection <= {STALL_TARGET_MS:g} ms",
                  "value_ms": stall_max, "p99_ms": stall_p99,
                  "met": stall_max <= STALL_TARGET_MS if math.isfinite(stall_max) else None,
                  "p99_met": stall_p99 <= STALL_TARGET_MS if math.isfinite(stall_p99) else None},
        "memory": {"target": f"RSS growth from {first.get('after')} to {last.get('after')} inspections <= "
                             f"{MEMORY_TARGET_MB:g} MB",
                   "value_mb": growth, "met": growth <= MEMORY_TARGET_MB if growth is not None else None},
    }
    for r in records:
        r.pop("gaps_ms", None)
        r.pop("steps_ms", None)
    return {
        "config": {"recipe": recipe, "reference": reference, "capture": {"name": folder.name, "source": source},
                   "runs": args.runs, "inspections": len(records), "first_sample": first_sample,
                   "draw_points": draw_points, "tick_ms": TICK_MS, "window": list(WINDOW_SIZE)},
        "machine": machine,
        "headless": headless,
        "trigger_to_shown": {
            "points": points,
            "shown_s": _summary(shown),
            "drawn_s": _summary(drawn),
            "drawn_overhead_s": _summary(overhead_drawn),
            "cycle_s": _summary([r["cycle_s"] for r in timed]),
            "overhead_s": _summary(overhead),
            "overhead_all_inspections_s": _summary(overhead_all),
            "shown_minus_headless_wall_s": _median(shown) - headless["wall_s"]["median"],
            "shown_minus_headless_total_s": _median(shown) - headless["total_s"]["median"],
            "extra_draw_s": extra,
            "overhead_with_draw_points_s": judged,
        },
        "stall": ticks,
        "memory": {"first": first, "last": last, "growth_mb": growth, "per_inspection_kb": per_inspection_kb,
                   "growth_after_malloc_trim_mb": trimmed, "growth_of_10_sample_medians_mb": windowed,
                   "rss_trace_mb": [[i, r] for i, r in rss_trace],
                   "actors_bounded": (first.get("actors") == last.get("actors")) if first and last else None},
        "draw": draw,
        "gui_loop_s": loop_s,
        "inspections": records,
        "targets": targets,
    }


def _print_report(doc: dict[str, Any]) -> None:
    cfg, m, h = doc["config"], doc["machine"], doc["headless"]
    ts, st, mem, d, t = doc["trigger_to_shown"], doc["stall"], doc["memory"], doc["draw"], doc["targets"]
    print()
    print(f"inspector bench --gui: recipe {cfg['recipe']}, reference {cfg['reference']}")
    print(f"  capture {cfg['capture']['name']} ({cfg['capture']['source']}), {ts['points']} BCPS points; "
          f"window {cfg['window'][0]}x{cfg['window'][1]}")
    print(f"  machine: {m['usable_cpus']} usable CPUs, load average {m['loadavg_1_5_15']} at start "
          "(timings depend on other jobs on this machine)")
    print(f"  {cfg['inspections']} inspections in one window (1 warm-up), {cfg['runs']} timed")
    print()
    print(f"  1. trigger -> verdict shown, median of {ts['shown_s']['n']}: {ts['shown_s']['median']:.3f} s "
          f"(min {ts['shown_s']['min']:.3f}, max {ts['shown_s']['max']:.3f})")
    print(f"     headless cycle of the same inspections (timings total): {ts['cycle_s']['median']:.3f} s")
    print(f"     overhead (shown - cycle), median: {ts['overhead_s']['median']:.3f} s with {ts['points']} points "
          f"(over all {doc['trigger_to_shown'].get('overhead_all_inspections_s', {}).get('n')} inspections: "
          f"{ts['overhead_all_inspections_s']['median']:.3f} s)")
    print(f"     separate headless Session run: timings total {h['total_s']['median']:.3f} s, "
          f"Session.run wall {h['wall_s']['median']:.3f} s (outputs and history included); "
          f"shown - headless wall: {ts['shown_minus_headless_wall_s']:+.3f} s")
    print(f"     trigger -> all drawn (3D view, cameras, history), median: {ts['drawn_s']['median']:.3f} s, "
          f"{ts['drawn_overhead_s']['median']:.3f} s over the cycle")
    print(f"     drawing, measured apart: verdict on screen {1000 * d['shown_real_s']['median']:.0f} ms / all drawn "
          f"{d['drawn_real_s']['median']:.3f} s with {d['points_real']} points, {1000 * d['shown_big_s']['median']:.0f} ms / "
          f"{d['drawn_big_s']['median']:.3f} s with {d['points_big']}; the worker's per-point work "
          f"{1000 * d['worker_points_real_s']:.1f} / {1000 * d['worker_points_big_s']:.1f} ms; extra before the verdict "
          f"{1000 * d['extra_big_s']:+.1f} ms, before all drawn {d['extra_drawn_big_s']:+.3f} s")
    print(f"     one render of the 3D view with {d['points_big']} points: {d['render_big_s']['median']:.3f} s")
    for label, key in (("real", "steps_real_s"), ("big", "steps_big_s")):
        parts = ", ".join(f"{k} {1000 * v:.0f}" for k, v in d[key].items())
        print(f"     drawing steps ({label}, ms, each its own event-loop turn): {parts}")
    print(f"     overhead with {cfg['draw_points']} points ({t['trigger_to_shown']['how']}): "
          f"{ts['overhead_with_draw_points_s']:.3f} s")
    print(f"  2. event-loop stall ({cfg['tick_ms']} ms timer) over {st['inspections']} inspections: worst gap max "
          f"{st['max_ms']:.0f} ms (inspection {st['worst_inspection']}), p99 of the per-inspection worst "
          f"{st['p99_of_worst_ms']:.0f} ms, median {st['median_of_worst_ms']:.0f} ms; p99 of all "
          f"{st['ticks']} gaps {st['p99_all_gaps_ms']:.0f} ms")
    print(f"     gaps while the result is drawn (its arrival to the paints after the last step): max "
          f"{st['max_drawing_ms']:.0f} ms; "
          f"every other gap of the runs (worker, stages, signals): max {st['max_outside_drawing_ms']:.0f} ms, "
          f"p99 of the per-inspection worst {st['p99_outside_drawing_ms']:.0f} ms")
    ib, ir = d["idle_ticks_big"], d["idle_ticks_real"]
    print(f"     idle (no inspection, {ib['seconds']:.0f} s): worst gap {ir['max_ms']:.0f} ms with {d['points_real']} points "
          f"on screen, {ib['max_ms']:.0f} ms with {d['points_big']} (median gap {ir['median_ms']:.0f} / "
          f"{ib['median_ms']:.0f} ms)")
    print(f"     (warm-up's worst gap {st['warmup_worst_gap_ms']:.0f} ms, left out; drawing {d['points_big']} points "
          f"blocks the GUI thread {st['draw_big_worst_gap_ms']:.0f} ms at worst)")
    print("     longest of each drawing step over the inspections (ms): "
          + ", ".join(f"{k} {v:.0f}" for k, v in st["steps_max_ms"].items()))
    f, la = mem["first"], mem["last"]
    if f and la:
        print(f"  3. memory: RSS {f['rss_mb']:.0f} MB after {f['after']} inspections, {la['rss_mb']:.0f} MB after "
              f"{la['after']}: {mem['growth_mb']:+.1f} MB ({mem['per_inspection_kb']:+.0f} kB per inspection)")
        every = max(1, len(mem["rss_trace_mb"]) // 20)
        trace = " ".join(f"{i}:{r:.0f}" for i, r in mem["rss_trace_mb"] if r is not None and (i % every == 0 or i == 1))
        print(f"     RSS (MB) after inspection i: {trace}")
        if mem["growth_of_10_sample_medians_mb"] is not None:
            print(f"     informative: median of the 10 samples up to each point {mem['growth_of_10_sample_medians_mb']:+.1f} MB"
                  + (f"; live memory (after malloc_trim(0), free heap given back) {f['rss_after_malloc_trim_mb']:.0f} -> "
                     f"{la['rss_after_malloc_trim_mb']:.0f} MB: {mem['growth_after_malloc_trim_mb']:+.1f} MB"
                     if mem["growth_after_malloc_trim_mb"] is not None else ""))
        print(f"     3D view actors {f['actors']} -> {la['actors']}, QObjects in the window {f['qobjects_in_window']} -> "
              f"{la['qobjects_in_window']}, Python objects {f['python_objects']} -> {la['python_objects']}")
    print("\n  targets:")
    tt, ss, mm = t["trigger_to_shown"], t["stall"], t["memory"]
    print(f"    trigger->shown overhead <= {OVERHEAD_TARGET_S:g} s with {cfg['draw_points']} points: "
          f"{_word(tt['met'])} ({tt['value_s']:.3f} s)")
    print(f"    event-loop stall <= {STALL_TARGET_MS:g} ms: {_word(ss['met'])} (max {ss['value_ms']:.0f} ms; "
          f"p99 {ss['p99_ms']:.0f} ms: {_word(ss['p99_met'])})")
    print(f"    memory growth <= {MEMORY_TARGET_MB:g} MB: {_word(mm['met'])}"
          + (f" ({mm['value_mb']:+.1f} MB)" if mm["value_mb"] is not None else ""))
