"""``inspector run --capture ... --scheduler ADDRESS | --workers N``: a batch of capture folders
inspected on the workers of a Dask cluster (issue 17).

One job: spread the *inspections* over the cluster and keep everything else exactly as a
local run does it. The client process (the one that runs ``inspector run``)

* validates the recipe and its reference (the :class:`~inspector.session.Session` the local
  run opens), expands the ``--capture`` folders and refuses two of one name, as the local run;
* submits one task per capture folder (:func:`inspect_folder`), with a key of its own, and
  collects the results as they complete (``as_completed``);
* writes every result folder (:func:`inspector.outputs.write_result`: built hidden, renamed
  whole) and calls ``inspector_on_result`` (the ``history`` plugin's row, an integrator's PLC
  or MES hook) itself, with the local run's code, once per capture, in the order the results
  arrive; ``inspector_on_run_start`` and ``_end`` too.

A worker only reads the capture folder and runs the recipe's stages (``inspector_before_stage``,
``_after_stage`` and ``_on_stage_error`` are called there, by a plugin manager the worker
builds with the client's ``--block`` list and ``--plugin`` files), then returns the
:class:`~inspector.model.InspectionResult` (the points, never the images). It writes nothing:
a worker killed mid-capture leaves no half result and no history row behind, and the scheduler
runs that task again on another worker (Dask's ``distributed.scheduler.allowed-failures``, 3);
a task that raises is retried (``retries``). A capture whose task fails for good (every
worker that ran it died, the cluster went away) gets verdict ``error`` with the reason in one
line, written and recorded like any capture that cannot be inspected. Each capture is
recorded once: a result that arrives again for a recorded capture is dropped.

Workers read the capture folders, the recipe and the reference mesh by the client's absolute
paths: they must see the same files (the same machine, or a shared file system mounted at the
same place), and have the same Inspector installed. A recipe file that differs on a worker
(its SHA-256) makes each capture an error naming it.

Importing this module is cheap: Dask and tqdm are imported when a run starts.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import sys
import time
import traceback
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from inspector.errors import InspectorError, RecipeError

if TYPE_CHECKING:
    from inspector.manager import PluginManager
    from inspector.model import InspectionResult
    from inspector.recipe import Budget, Recipe
    from inspector.reference import Reference
    from inspector.runner import Outcome
    from inspector.session import Inspected, RunSummary, Session

__all__ = ["WorkerSetup", "worker_setup", "inspect_folder", "connect", "run_on_cluster"]

#: Retries of a capture's task that raised (a worker killed mid-task is rescheduled by the
#: scheduler itself, up to its ``allowed-failures``).
RETRIES = 2


# ------------------------------------------------------------------------------ the worker side
@dataclass(frozen=True)
class WorkerSetup:
    """What a worker needs to inspect as the client would: small and picklable.

    Attributes
    ----------
    recipe_path : str
        The recipe file, absolute.
    recipe_name : str
        Its ``[recipe] name`` (for a result the worker cannot make with it).
    recipe_sha256 : str or None
        Its SHA-256 as the client read it (a worker that reads other bytes refuses).
    reference : str or None
        The reference the client resolved (``builtin:NAME`` or an absolute path).
    block : tuple of str
        Plugins not to load (the client's ``--block`` and ``INSPECTOR_BLOCK_PLUGINS``).
    files : tuple of str
        Local plugin modules to load (the client's ``--plugin FILE.py``), absolute.
    budget : Budget
        The client's stage and hook budgets (the workers' environment may differ).
    """

    recipe_path: str
    recipe_name: str
    recipe_sha256: str | None
    reference: str | None
    block: tuple[str, ...]
    files: tuple[str, ...]
    budget: Budget


def worker_setup(session: Session) -> WorkerSetup:
    """The :class:`WorkerSetup` of a session opened on the client."""
    recipe, pm = session.recipe, session.pm
    if recipe.path is None:
        raise RecipeError("a cluster run needs a recipe file (workers load it by its path)")
    files = tuple(str(Path(row["file"]).resolve()) for row in pm.plugins() if row["file"] and row["status"] == "loaded")
    return WorkerSetup(str(Path(recipe.path).resolve()), recipe.name, recipe.sha256, recipe.reference,
                       tuple(pm.blocked), files, recipe.budget)


#: Per worker process: the last setup's (recipe, reference, plugin manager), built once.
_LOADED: dict[WorkerSetup, tuple[Recipe, Reference | None, PluginManager]] = {}


def _load_on_worker(setup: WorkerSetup) -> tuple[Recipe, Reference | None, PluginManager]:
    """The recipe, reference and plugin manager of ``setup`` in this worker (cached: the
    reference's distance index is built once per worker, not once per capture)."""
    hit = _LOADED.get(setup)
    if hit is not None:
        return hit
    from inspector.manager import create_plugin_manager
    from inspector.recipe import load_recipe
    from inspector.reference import Reference

    pm = create_plugin_manager(block=setup.block, files=setup.files, warn=lambda line: None)  # the client warned
    recipe = load_recipe(setup.recipe_path, pm, reference=setup.reference)
    if recipe.sha256 != setup.recipe_sha256:
        raise RecipeError(f"{setup.recipe_path}: this worker reads another recipe than the client "
                          f"(SHA-256 {str(recipe.sha256)[:12]}, the client's {str(setup.recipe_sha256)[:12]}): "
                          "the file changed, or the worker sees another file system")
    recipe = dataclasses.replace(recipe, budget=setup.budget)
    reference = Reference.load(recipe.reference) if recipe.reference is not None else None
    _LOADED.clear()
    _LOADED[setup] = (recipe, reference, pm)
    return recipe, reference, pm


def inspect_folder(setup: WorkerSetup, folder: str) -> tuple[InspectionResult, str | None]:
    """Inspect one capture folder on a worker: ``(result, traceback or None)``; writes nothing.

    Reads the folder as the local run does (the replay driver's naming and reader, its
    errors one line each), then runs the stages (:func:`inspector.runner.inspect_capture`).
    A capture that cannot be read or inspected is a result with verdict ``error``, as in the
    local run; only a bug of this wrapper raises (and the task is retried).
    """
    from inspector.runner import _error_result, inspect_capture
    from inspector.capture_folder import named_acquisition, read_capture

    acq = named_acquisition(Path(folder), read_capture)
    t0 = time.perf_counter()
    try:
        recipe, reference, pm = _load_on_worker(setup)
    except InspectorError as exc:  # the recipe or its reference, as this worker sees them
        return _setup_error(setup, acq.name, f"on the worker: {exc}"), None
    try:
        capture = acq.load()
    except InspectorError as exc:
        dt = time.perf_counter() - t0
        return _error_result(acq.name, recipe, str(exc), {"load": dt, "total": dt}), None
    except Exception as exc:  # noqa: BLE001 - as the local run: that capture only
        reason = f"internal error reading capture: {type(exc).__name__}: {' '.join(str(exc).split())}"
        return _error_result(acq.name, recipe, reason, {"total": time.perf_counter() - t0}), traceback.format_exc()
    outcome = inspect_capture(capture, recipe, reference, pm, load_s=time.perf_counter() - t0)
    return outcome.result, outcome.trace


def _setup_error(setup: WorkerSetup, name: str, reason: str) -> InspectionResult:
    from inspector.model import InspectionResult

    return InspectionResult(capture=name, recipe=setup.recipe_name, verdict="error", error=reason,
                            timings_s={"total": 0.0}, recipe_path=setup.recipe_path, recipe_sha256=setup.recipe_sha256)


# ------------------------------------------------------------------------------ the client side
def connect(scheduler: str | None, workers: int | None) -> tuple[Any, Any]:
    """``(client, cluster or None)``: a client of the scheduler at ``scheduler``, or of a new
    :class:`~distributed.LocalCluster` of ``workers`` processes of one thread each.

    Raises
    ------
    RecipeError
        Dask is missing, ``workers`` < 1, or the scheduler cannot be reached within Dask's
        connect timeout (``distributed.comm.timeouts.connect``; one line, nothing inspected).
    """
    if workers is not None and workers < 1:
        raise RecipeError(f"--workers: expected a number >= 1, got {workers}")
    try:
        import dask
        from distributed import Client, LocalCluster
    except ImportError as e:
        raise RecipeError(f"--scheduler/--workers need {e.name} (pip install 'dask[distributed]')") from None
    import logging

    if scheduler is not None:
        timeout = dask.config.get("distributed.comm.timeouts.connect")
        try:
            with _QuietDask():  # the reason is our one line
                return Client(scheduler, timeout=timeout, set_as_default=False), None
        except Exception as e:  # noqa: BLE001 - refused, timed out, a malformed address: one line
            text = " ".join(str(e).split()) or type(e).__name__
            raise RecipeError(f"--scheduler {scheduler}: cannot connect to a Dask scheduler ({text})") from None
    # ":0": any free port for its HTTP server (8787 may be taken on a shared machine).
    cluster = LocalCluster(n_workers=workers or 1, threads_per_worker=1, processes=True, dashboard_address=":0",
                           silence_logs=logging.ERROR)
    try:
        return Client(cluster, set_as_default=False), cluster
    except BaseException:
        cluster.close()
        raise


def run_on_cluster(session: Session, captures: Sequence[str], *, scheduler: str | None = None,
                   workers: int | None = None, client: Any = None, progress: bool = False,
                   retries: int = RETRIES) -> RunSummary:
    """Inspect the capture folders ``captures`` (or folders of them) on a Dask cluster, into
    ``session.outdir``, exactly as ``session.run`` would in this process: the same result
    folders, history rows, events (to the session's subscribers) and :class:`RunSummary`.

    Parameters
    ----------
    scheduler, workers
        Where: a running scheduler's address, or a new local cluster of ``workers`` processes
        (closed at the end). Ignored when ``client`` is given (a client the caller keeps).
    progress : bool
        A progress bar on stderr when it is a terminal (the per-capture lines are the
        subscribers' business, as in a local run).

    Raises
    ------
    RecipeError
        Nothing to inspect, two captures of one name, an unusable ``--out``, or no cluster
        (nothing inspected).
    KeyboardInterrupt
        Ctrl-C: the tasks are cancelled; results written so far are kept.
    """
    with _QuietDask():
        return _run(session, captures, scheduler, workers, client, progress, retries)


def _run(session: Session, captures: Sequence[str], scheduler: str | None, workers: int | None, client: Any,
         progress: bool, retries: int) -> RunSummary:
    from inspector.runner import ABORTED, Outcome, _error_result
    from inspector.session import VERDICTS, Inspected, RunEnded, RunStarted, RunSummary, Warned, _distinct_names, _result_folder
    from inspector.capture_folder import expand, named_acquisition

    setup = worker_setup(session)
    folders = _distinct_names(expand([str(c) for c in captures]))
    if not folders:
        raise RecipeError("no capture to inspect")
    # Absolute, not resolved: a capture is named after its folder as the local run names it.
    items = [(named_acquisition(f, _unread).name, os.path.abspath(f)) for f in folders]
    own = client is None
    cluster = None
    if own:
        client, cluster = connect(scheduler, workers)
    recipe, pm = session.recipe, session.pm
    emit = session._emit
    counts = dict.fromkeys(VERDICTS, 0)
    warned: list[str] = []
    ended = "done"
    futures: dict[Any, tuple[str, str]] = {}
    try:
        outdir = _result_folder(session.outdir)
        if not client.scheduler_info().get("workers"):
            emit(Warned("run", "the scheduler has no worker yet: the captures wait until one joins"))
        slow = _slow(recipe, pm.on_run_start(recipe, outdir, "captures"))
        bar = _Bar(len(items), progress)
        try:
            emit(RunStarted("captures", len(items), outdir))
            for w in slow:
                emit(Warned("run", w))
            from distributed import as_completed

            token = uuid.uuid4().hex[:12]
            for name, folder in items:
                key = f"inspector-{hashlib.sha1(folder.encode('utf-8', 'surrogateescape')).hexdigest()[:16]}-{token}"
                fut = client.submit(inspect_folder, setup, folder, key=key, pure=False, retries=retries)
                futures[fut] = (name, folder)
            recorded: set[str] = set()
            i = 0
            for fut in as_completed(list(futures), loop=client.loop):
                name, folder = futures[fut]
                try:
                    result, trace = fut.result()
                except Exception as exc:  # noqa: BLE001 - the cluster lost this task for good
                    result, trace = _error_result(name, recipe, _lost(exc), {"total": 0.0}), None
                finally:
                    fut.release()
                if name in recorded or result.verdict == ABORTED:  # once per capture, whatever the cluster did
                    continue
                recorded.add(name)
                outcome = record(Outcome(result, None, trace), recipe, pm, outdir)
                i += 1
                counts[outcome.result.verdict] = counts.get(outcome.result.verdict, 0) + 1
                bar.show(emit, Inspected(i, len(items), outcome, outcome.folder))
                for w in outcome.result.stats.get("warnings", ()):
                    if w not in warned:
                        warned.append(w)
                        emit(Warned(outcome.result.capture, w))
                del outcome, result
        except KeyboardInterrupt:
            ended = "interrupted"
            raise
        except BaseException:
            ended = "failed"
            raise
        finally:
            bar.close()
            summary = RunSummary(dict(counts), ended, outdir, None, tuple(warned))
            for w in _slow(recipe, pm.on_run_end(recipe, outdir, summary)):
                emit(Warned("run", w))
            emit(RunEnded(summary))
        return summary
    finally:
        pending = [f for f in futures if not f.done()]
        if pending:
            try:
                client.cancel(pending)
            except Exception:  # noqa: BLE001 - closing anyway
                pass
        if own:
            client.close()
            if cluster is not None:
                cluster.close()


def _lost(exc: BaseException) -> str:
    """The one-line reason of a capture whose task the cluster could not finish."""
    kind = type(exc).__name__
    if kind == "KilledWorker":
        return "not inspected: every worker that ran it died (KilledWorker; see the workers' logs)"
    reason = getattr(exc, "reason", None)
    if reason:  # FutureCancelledError: scheduler-connection-lost ...
        return f"not inspected: the cluster cancelled it ({reason})"
    text = " ".join(str(exc).split())
    return f"not inspected on the cluster: {kind}: {text}" if text else f"not inspected on the cluster: {kind}"


class _QuietDask:
    """Dask's own log lines off in this process while a run uses the cluster (a lost
    scheduler is logged with tracebacks): what went wrong is each capture's one line."""

    def __enter__(self) -> None:
        import logging

        try:
            import distributed  # noqa: F401 - its loggers exist (and are configured) from here on
        except ImportError:
            pass  # connect() says so
        names = ["distributed", *(n for n in logging.root.manager.loggerDict if n.startswith("distributed."))]
        self.saved = [(lg, lg.level) for lg in map(logging.getLogger, names)]
        for lg, _ in self.saved:
            lg.setLevel(logging.CRITICAL + 1)

    def __exit__(self, *exc: object) -> None:
        for lg, level in self.saved:
            lg.setLevel(level)


def _unread(folder: Path) -> Any:
    raise AssertionError("the client never reads a capture")  # pragma: no cover


def record(outcome: Outcome, recipe: Recipe, pm: PluginManager, outdir: Path) -> Outcome:
    """Write one capture's result folder, its CSV exports, and call ``inspector_on_result``
    (the history row), in this process: what :func:`inspector.runner.run_batch` does after
    each inspection, step for step, with its functions."""
    from inspector import outputs
    from inspector.runner import _export_csv, _unwritten, _with, hook_warning

    folder = None
    try:
        folder = outputs.write_result(outcome.result, outdir, trace=outcome.trace)
    except InspectorError as exc:  # a name that cannot be a result folder, a full disk
        outcome = _unwritten(outcome, str(exc))
    else:
        outcome = dataclasses.replace(outcome, folder=folder)
        _export_csv(outcome.result, folder, recipe.outputs.csv)
    times = pm.on_result(outcome.result, folder)
    if times:
        slow = [hook_warning(k, recipe.budget.hook_s) for k, t in times.items() if t > recipe.budget.hook_s]
        outcome = dataclasses.replace(outcome, result=_with(outcome.result, times, slow))
        if folder is not None:
            outputs.rewrite_result_json(outcome.result, folder)
    return outcome


def _slow(recipe: Recipe, times: dict[str, float]) -> list[str]:
    from inspector.runner import hook_warning

    budget = recipe.budget.hook_s
    return [hook_warning(k, budget) for k, t in times.items() if t > budget]


class _Bar:
    """A tqdm progress bar on stderr when it is a terminal; the lines printed by the
    subscribers (stdout) go above it."""

    def __init__(self, total: int, enabled: bool) -> None:
        self.bar: Any = None
        if enabled and sys.stderr.isatty():
            try:
                from tqdm import tqdm

                self.bar = tqdm(total=total, file=sys.stderr, unit="capture", desc="inspect", dynamic_ncols=True)
            except ImportError:
                self.bar = None

    def show(self, emit: Callable[[Inspected], None], event: Inspected) -> None:
        """``emit(event)`` (whose subscribers print the capture's line), then one step."""
        if self.bar is None:
            emit(event)
            return
        from tqdm import tqdm

        with tqdm.external_write_mode(file=sys.stdout):
            emit(event)
        result = event.outcome.result
        self.bar.set_postfix_str(f"{result.capture}: {result.verdict}", refresh=False)
        self.bar.update(1)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
