"""One inspection session: the Qt-free model that every front end drives.

A :class:`Session` holds a validated recipe, its reference and plugin manager, and a result
folder. :meth:`Session.run` inspects captures from one source (capture folders, a hot
folder, or the recipe's own driver), writes every result and history row through the runner
(:func:`inspector.runner.run_batch`), and tells its subscribers what happens as plain events
(:class:`RunStarted`, :class:`Inspected`, :class:`Warned`, :class:`RunEnded`). The CLI prints
them; the GUI turns them into queued Qt signals from its worker thread. It is the one run
envelope: the run hooks, the events, the verdict counts and the warnings (once per run) are
the same whatever inspects the captures, this process (the default
:class:`~inspector.runner.LocalExecutor`, in the calling thread) or another
:class:`~inspector.runner.Executor` (a Dask cluster: :mod:`inspector_frontends.distributed`). Stage progress
comes from the lifecycle hooks (``inspector_before_stage`` ...), which a front end observes
by registering a plugin on :attr:`Session.pm`.

Another thread may call :meth:`Session.stop` (end the run after the capture in progress) or
:meth:`Session.cancel` (end it between two stages: that capture's verdict is ``"aborted"``,
nothing is written for it, no history row, and a hot folder keeps it: in
``INBOX/processing/``, first in line when the watch starts again).
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from inspector import capture_folder, outputs, runner
from inspector.capture_folder import expand
from inspector.errors import InspectorError, RecipeError
from inspector.history_store import recorded as in_history
from inspector.manager import PluginManager, create_plugin_manager
from inspector.names import folder_name
from inspector.recipe import Recipe, load_recipe
from inspector.reference import Reference
from inspector.registry import Acquisition
from inspector.runner import ABORTED, Executor, Outcome, exit_status

__all__ = [
    "Source",
    "RunSummary",
    "RunStarted",
    "Inspected",
    "Warned",
    "RunEnded",
    "Event",
    "Session",
    "capture_folders",
]

VERDICTS = ("pass", "fail", "error", ABORTED)


@dataclass(frozen=True)
class Source:
    """Where a run's captures come from.

    Attributes
    ----------
    captures : tuple of str
        Capture folders, or folders of capture folders (a batch).
    watch : mapping, optional
        A hot folder: the ``hotfolder`` driver's parameters (``folder``, ``count``,
        ``idle_exit_s`` ...).
    limit : int, optional
        At most this many captures, then the run ends (the GUI's INSPECT: 1).

    With neither ``captures`` nor ``watch``, the recipe's own driver: it is opened once per
    session and kept open, so each run continues where the last one stopped (a simulated
    rig renders the next part, a camera waits for the next trigger).
    """

    captures: tuple[str, ...] = ()
    watch: Mapping[str, Any] | None = None
    limit: int | None = None

    def __post_init__(self) -> None:
        if self.captures and self.watch is not None:
            raise RecipeError("a run reads capture folders or watches a hot folder, not both")
        if self.limit is not None and self.limit < 1:
            raise RecipeError(f"limit: expected a number >= 1, got {self.limit}")


@dataclass(frozen=True)
class RunSummary:
    """How a run ended.

    Attributes
    ----------
    counts : mapping of str to int
        Captures per verdict (``pass``, ``fail``, ``error``, ``aborted``).
    ended : str
        ``"done"`` (the source ran out or the limit was reached), ``"stopped"``
        (:meth:`Session.stop`), ``"cancelled"`` (:meth:`Session.cancel`), ``"interrupted"``
        (Ctrl-C during a watch) or ``"failed"`` (the driver raised).
    outdir : Path
    inbox : Path or None
        The watched folder, for a hot-folder run.
    warnings : tuple of str
        The run's warnings, each once.
    """

    counts: Mapping[str, int]
    ended: str
    outdir: Path
    inbox: Path | None = None
    warnings: tuple[str, ...] = ()

    @property
    def inspected(self) -> int:
        """Captures with a written result (aborted ones are not)."""
        return sum(n for v, n in self.counts.items() if v != ABORTED)

    @property
    def exit_status(self) -> int:
        """The CONTRACT exit status of the written results (0, 1 or 3)."""
        return exit_status([v for v, n in self.counts.items() if n and v != ABORTED])


@dataclass(frozen=True)
class RunStarted:
    """A run began; ``total`` is the number of captures when known."""

    source: str
    total: int | None
    outdir: Path
    inbox: Path | None = None


@dataclass(frozen=True, eq=False)
class Inspected:
    """One capture is done: its result is written (unless aborted) and its hooks called.

    ``outcome.context`` holds the last stage's context (images, silhouettes, points): a
    subscriber takes what it needs now, the session drops it before the next capture.
    """

    index: int
    total: int | None
    outcome: Outcome
    folder: Path | None


@dataclass(frozen=True)
class Warned:
    """A warning of the run (each text once per run), about ``capture``."""

    capture: str
    text: str


@dataclass(frozen=True)
class RunEnded:
    summary: RunSummary


Event = RunStarted | Inspected | Warned | RunEnded


class _Stopped(Exception):
    """Raised inside a waiting driver when the run is asked to end."""


@dataclass
class Session:
    """A recipe ready to run, and the runs made with it.

    Build one with :meth:`Session.open`; call :meth:`run` from one thread at a time;
    :meth:`stop` and :meth:`cancel` may be called from any thread; :meth:`close` closes the
    recipe's driver.
    """

    recipe: Recipe
    reference: Reference | None
    pm: PluginManager
    outdir: Path
    _subscribers: list[Callable[[Event], None]] = field(default_factory=list)
    _stop: threading.Event = field(default_factory=threading.Event)
    _cancel: threading.Event = field(default_factory=threading.Event)
    _driver: Any = None
    _stream: Iterator[Acquisition] | None = None
    _running: threading.Lock = field(default_factory=threading.Lock)

    # -- building --------------------------------------------------------------------------
    @classmethod
    def open(cls, recipe: str | Path, out: str | Path, *, reference: str | None = None,
             pm: PluginManager | None = None, csv: bool = False) -> Session:
        """Load and validate ``recipe`` (and its reference); RecipeError on any problem.

        ``out`` is checked and created by :meth:`run`, not here: a front end may open a
        session before it knows where results go. ``csv``: write the CSV exports whatever
        the recipe's ``[outputs] csv`` says (``inspector run --csv``).
        """
        import dataclasses

        pm = pm if pm is not None else create_plugin_manager()
        rec = load_recipe(recipe, pm, reference=reference)
        if csv:
            rec = dataclasses.replace(rec, outputs=dataclasses.replace(rec.outputs, csv=True))
        ref = None
        if rec.reference is not None:
            try:
                ref = Reference.load(rec.reference)
            except InspectorError as e:
                raise RecipeError(str(e)) from None
        return cls(rec, ref, pm, Path(out))

    def subscribe(self, callback: Callable[[Event], None]) -> Callable[[], None]:
        """Call ``callback(event)`` for every event, in the running thread; returns an
        unsubscribe function. A subscriber that raises is reported, never fatal."""
        self._subscribers.append(callback)
        return lambda: self._subscribers.remove(callback) if callback in self._subscribers else None

    # -- control (any thread) ---------------------------------------------------------------
    def stop(self) -> None:
        """End the run after the capture in progress (its result is written)."""
        self._stop.set()

    def cancel(self) -> None:
        """End the run before the next stage: the capture in progress is ``aborted``."""
        self._cancel.set()
        self._stop.set()

    @property
    def running(self) -> bool:
        return self._running.locked()

    def close(self) -> None:
        """Close the recipe's driver if a run opened it."""
        stream, driver, self._stream, self._driver = self._stream, self._driver, None, None
        if stream is not None and hasattr(stream, "close"):
            stream.close()
        if driver is not None:
            driver.close()

    # -- running ----------------------------------------------------------------------------
    def run(self, source: Source | None = None, *, executor: Executor | None = None) -> RunSummary:
        """Inspect the captures of ``source`` (default: the recipe's driver) until it ends.

        ``executor`` inspects them (default: :class:`~inspector.runner.LocalExecutor`, in
        this thread); the session records each outcome and emits the events the same way
        whatever the executor.

        Raises
        ------
        RecipeError
            The source or ``outdir`` is unusable; nothing was inspected.
        InspectorError
            The driver failed while acquiring (results written before are kept).
        KeyboardInterrupt
            Ctrl-C outside a watch (a watch ends with ``ended="interrupted"``).
        """
        source = source or Source()
        if not self._running.acquire(blocking=False):
            raise RecipeError("a run is already in progress in this session")
        try:
            self._stop.clear()
            self._cancel.clear()
            return self._run(source, executor if executor is not None else runner.LocalExecutor())
        finally:
            self._running.release()

    def _run(self, source: Source, executor: Executor) -> RunSummary:
        driver, acquisitions, total, what, own = self._open_source(source)
        counts = dict.fromkeys(VERDICTS, 0)
        warned: list[str] = []
        inbox = getattr(driver, "inbox", None)
        ended = "done"
        try:
            if inbox is not None and _inside(self.outdir, inbox):
                raise RecipeError(f"--out {self.outdir}: inside the inbox {inbox} (its result folders would be taken for captures)")
            outdir = _result_folder(self.outdir)
            if hasattr(driver, "taken"):  # a reused capture name must not overwrite a result
                self._hand_off(driver, outdir)
            if hasattr(driver, "sleep"):  # a waiting driver notices stop() and cancel()
                driver.sleep = self._waker(driver.sleep)
            for w in executor.warnings():  # e.g. a cluster without a worker yet
                self._emit(Warned("run", w))
            slow = self._slow(self.pm.on_run_start(self.recipe, outdir, what))
            summary = None
            try:
                self._emit(RunStarted(what, total, outdir, inbox))
                for w in slow:
                    self._emit(Warned("run", w))
                batch = runner.run_batch(self.recipe, self._until_stopped(acquisitions, source.limit), self.pm,
                                         reference=self.reference, outdir=outdir, should_abort=self._cancel.is_set,
                                         executor=executor)
                with contextlib.closing(batch):  # an executor's work ends with the run (a cluster's tasks)
                    i = 0
                    # No enumerate(): it keeps its last (index, outcome) tuple for reuse, which
                    # would hold each inspection (5 MB) in memory until the next one is done.
                    for outcome in batch:
                        i += 1
                        result = outcome.result
                        counts[result.verdict] = counts.get(result.verdict, 0) + 1
                        folder = outcome.folder  # None: nothing was written (aborted, or a refused name)
                        self._emit(Inspected(i, total, outcome, folder))
                        for w in result.stats.get("warnings", ()):
                            if w not in warned:  # once per run, not once per part
                                warned.append(w)
                                self._emit(Warned(result.capture, w))
                        del outcome, result
                        if self._stop.is_set():
                            break  # after the capture in progress, also for an executor that works ahead (a cluster)
                if self._cancel.is_set():
                    ended = "cancelled"
                elif self._stop.is_set():
                    ended = "stopped"
            except _Stopped:
                ended = "cancelled" if self._cancel.is_set() else "stopped"
            except KeyboardInterrupt:
                if inbox is None:
                    ended = "interrupted"
                    raise
                ended = "interrupted"  # Ctrl-C is how a watch ends: the capture in progress stays in INBOX/processing/
            except BaseException:
                ended = "failed"
                raise
            finally:
                summary = RunSummary(dict(counts), ended, outdir, inbox, tuple(warned))
                for w in self._slow(self.pm.on_run_end(self.recipe, outdir, summary)):
                    self._emit(Warned("run", w))
                self._emit(RunEnded(summary))
            return summary
        finally:
            if own:
                driver.close()
            elif ended in ("failed", "interrupted"):
                self.close()  # a driver that raised is not trusted for the next run

    def _slow(self, times: Mapping[str, float]) -> list[str]:
        """Budget warnings for a run hook's times (``inspector_on_run_start``/``_end``)."""
        budget = self.recipe.budget.hook_s
        return [runner.hook_warning(k, budget) for k, t in times.items() if t > budget]

    def _hand_off(self, driver: Any, outdir: Path) -> None:
        """Tell a driver that files capture folders away (the hot folder) what is downstream:
        which names are taken (a result folder, or a history row), whether a capture is
        settled (its result.json and, with the history plugin, its history row), and how to
        discard what an unfinished inspection left (after a crash)."""
        import os

        def recorded(name: str) -> bool | None:
            if "history" not in self.pm.plugin_names():
                return None

            return in_history(outdir, name)

        driver.taken = lambda name: os.path.lexists(outdir / name) or recorded(name) is True
        if hasattr(driver, "settled"):
            driver.settled = lambda name: outputs.result_written(outdir, name) and recorded(name) is not False
            driver.discard = lambda name: outputs.discard_result(outdir, name)

    def _open_source(self, source: Source) -> tuple[Any, Iterator[Acquisition], int | None, str, bool]:
        """(driver, acquisitions, total, what, whether this run owns the driver)."""
        if source.watch is not None:
            folder = source.watch.get("folder")
            if not folder or not Path(folder).is_dir():
                raise RecipeError(f"--watch {folder}: not a folder")
            # The hot folder is a driver like any other, found through the plugin manager.
            if "hotfolder" not in self.pm.drivers:
                raise RecipeError(f"--watch {folder}: {self.pm.missing('driver', 'hotfolder')}")
            spec = self.pm.driver("hotfolder")
            driver = spec.open(spec.params(**source.watch))
            total = source.watch.get("count") or source.limit or None
            return driver, driver.acquire(), total, f"watch {folder}", True
        if source.captures:
            folders = capture_folders(source.captures)
            acquisitions = (capture_folder.named_acquisition(f, capture_folder.read_capture) for f in folders)
            total = min(len(folders), source.limit or len(folders))
            return None, acquisitions, total, "captures", False
        if self._stream is None:
            self._open_stream()
        count = getattr(self.recipe.driver.params, "count", None)
        total = source.limit or (count if isinstance(count, int) and count > 0 else None)
        assert self._stream is not None
        return self._driver, self._stream, total, f"driver {self.recipe.driver.spec.name}", False

    def _open_stream(self) -> Iterator[Acquisition]:
        self._driver = self.recipe.driver.spec.open(self.recipe.driver.params)
        self._stream = iter(self._driver.acquire())
        return self._stream

    def _until_stopped(self, acquisitions: Iterator[Acquisition], limit: int | None) -> Iterator[Acquisition]:
        """The acquisitions, until :meth:`stop` or ``limit``; never pulls one more than it
        hands out (the recipe's driver continues there next run)."""
        n = 0
        while not self._stop.is_set() and (limit is None or n < limit):
            try:
                acq = next(acquisitions)
            except StopIteration:
                if acquisitions is not self._stream:
                    return
                # The recipe's driver ran out (a simulated rig's count): it starts over, once
                # per run, so INSPECT always inspects something.
                self.close()
                if n:
                    return
                acquisitions = self._open_stream()
                try:
                    acq = next(acquisitions)
                except StopIteration:
                    self.close()
                    return
            n += 1
            yield acq

    def _waker(self, sleep: Callable[[float], None]) -> Callable[[float], None]:
        """The driver's own sleep (one poll interval), ended by :meth:`stop` or :meth:`cancel`."""

        def wake(seconds: float) -> None:
            if self._stop.is_set():
                raise _Stopped
            sleep(seconds)
            if self._stop.is_set():
                raise _Stopped

        return wake

    def _emit(self, event: Event) -> None:
        import sys

        for callback in list(self._subscribers):
            try:
                callback(event)
            except Exception as e:  # noqa: BLE001 - a front end's bug must not lose a result
                msg = " ".join(str(e).split())
                print(f"inspector: warning: a session subscriber failed on {type(event).__name__}: "
                      f"{type(e).__name__}: {msg}", file=sys.stderr, flush=True)


def _inside(path: Path, folder: Path) -> bool:
    """Whether ``path`` is ``folder`` or lies under it (resolved)."""
    p, f = Path(path).resolve(), Path(folder).resolve()
    return p == f or f in p.parents


def _result_folder(out: Path) -> Path:
    """``out``, created now: a folder that cannot be written is a command error, before
    anything is inspected."""
    import os

    outdir = Path(out)
    if outdir.exists() and not outdir.is_dir():
        raise RecipeError(f"--out {out}: is a file, not a folder")
    try:
        outdir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise RecipeError(f"--out {out}: cannot create the result folder ({e.strerror or e})") from None
    if not os.access(outdir, os.W_OK | os.X_OK):
        raise RecipeError(f"--out {out}: the result folder is not writable")
    return outdir


def capture_folders(captures: Sequence[str]) -> list[Path]:
    """The capture folders of ``captures`` (capture folders, or folders of them: expanded),
    each once; two different folders with the same name would write the same result folder
    (OUTDIR/<name>/): RecipeError, naming both."""
    seen: dict[str, Path] = {}
    out = []
    for f in expand(list(captures)):
        key = folder_name(f) or str(f)
        if key in seen:
            if seen[key].resolve() == f.resolve():
                continue  # the same capture given twice: inspected once
            raise RecipeError(f"--capture: {seen[key]} and {f} are both named {key!r}; "
                              f"their results would overwrite each other in OUTDIR/{key}/")
        seen[key] = f
        out.append(f)
    return out
