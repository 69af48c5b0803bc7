"""``inspector run --capture ... --scheduler ADDRESS | --workers N``: a batch of capture folders
inspected on the workers of a Dask cluster (issue 17).

One job: spread the *inspections* over the cluster and keep everything else exactly as a
local run does it. Only the executing step differs: the client process (the one that runs
``inspector run``)

* validates the recipe and its reference (the :class:`~inspector.session.Session` the local
  run opens), expands the ``--capture`` folders and refuses two of one name
  (:func:`inspector.session.capture_folders`, as the local run), then connects (:func:`connect`);
* runs the session (:meth:`Session.run <inspector.session.Session.run>`, the one run
  envelope) with a :class:`DaskExecutor`: it submits one task per capture folder
  (:func:`inspect_folder`), with a key of its own, and yields the results as they complete
  (``as_completed``);
* so the session writes every result folder (:func:`inspector.outputs.write_result`: built
  hidden, renamed whole) and calls ``inspector_on_result`` (the ``history`` plugin's row, an
  integrator's PLC or MES hook) itself (:func:`inspector.runner.record_outcome`), once per
  capture, in the order the results arrive; ``inspector_on_run_start`` and ``_end``, the
  events and the warnings too, as for a local run.

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
import uuid
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from inspector.capture_folder import named_acquisition, read_capture
from inspector.errors import InspectorError, RecipeError
from inspector.manager import PluginManager, create_plugin_manager
from inspector.model import InspectionResult
from inspector.recipe import Recipe, load_recipe
from inspector.reference import Reference
from inspector.runner import ABORTED, Outcome, error_result, inspect_acquisition
from inspector.session import RunSummary, Session, Source, capture_folders

if TYPE_CHECKING:
    from inspector.recipe import Budget
    from inspector.registry import Acquisition

__all__ = ["WorkerSetup", "worker_setup", "inspect_folder", "connect", "DaskExecutor", "run_on_cluster"]

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
    errors one line each), then runs the stages (:func:`inspector.runner.inspect_acquisition`).
    A capture that cannot be read or inspected is a result with verdict ``error``, as in the
    local run; only a bug of this wrapper raises (and the task is retried).
    """
    acq = named_acquisition(Path(folder), read_capture)
    try:
        recipe, reference, pm = _load_on_worker(setup)
    except InspectorError as exc:  # the recipe or its reference, as this worker sees them
        return _setup_error(setup, acq.name, f"on the worker: {exc}"), None
    outcome = inspect_acquisition(acq, recipe, reference, pm)
    return outcome.result, outcome.trace


def _setup_error(setup: WorkerSetup, name: str, reason: str) -> InspectionResult:
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


class DaskExecutor:
    """The :class:`~inspector.runner.Executor` of a Dask cluster: one task per capture folder
    (:func:`inspect_folder` on a worker), the outcomes yielded as the tasks complete, for the
    session to record.

    Parameters
    ----------
    client : distributed.Client
        The cluster's client (the caller keeps and closes it).
    setup : WorkerSetup
        What the workers inspect with (:func:`worker_setup`).
    folders : mapping of str to str
        Each capture's folder, absolute, by the name its acquisition has.
    retries : int
        Retries of a task that raised.
    progress : bool
        A progress bar on stderr when it is a terminal.
    """

    def __init__(self, client: Any, setup: WorkerSetup, folders: Mapping[str, str], *, retries: int = RETRIES,
                 progress: bool = False) -> None:
        self.client = client
        self.setup = setup
        self.folders = dict(folders)
        self.retries = retries
        self.progress = progress
        self._futures: dict[Any, str] = {}
        self._bar: _Bar | None = None

    def warnings(self) -> list[str]:
        """A scheduler without a worker: the run waits (for ever, if none joins)."""
        if not self.client.scheduler_info().get("workers"):
            return ["the scheduler has no worker yet: the captures wait until one joins"]
        return []

    def execute(self, recipe: Recipe, acquisitions: Iterable[Acquisition], pm: PluginManager, *,
                reference: Reference | None, should_abort: Callable[[], bool] | None = None) -> Iterator[Outcome]:
        """Submit every acquisition's task at once, then yield each capture's outcome as it
        completes, once (a result that comes again is dropped). A task the cluster could not
        finish is an ``error`` outcome with the reason in one line. The workers inspect with
        :attr:`setup` (``pm``, ``reference`` and ``should_abort`` are the client's: unused);
        closing the iterator cancels the tasks not done."""
        from distributed import as_completed

        recorded: set[str] = set()
        try:
            futures = self._submit(acquisitions)
            bar = self._bar = _Bar(len(futures), self.progress)
            for fut in as_completed(list(futures), loop=self.client.loop):
                name = futures[fut]
                try:
                    result, trace = fut.result()
                except Exception as exc:  # noqa: BLE001 - the cluster lost this task for good
                    result, trace = error_result(name, recipe, _lost(exc), {"total": 0.0}), None
                finally:
                    fut.release()
                if name in recorded or result.verdict == ABORTED:  # once per capture, whatever the cluster did
                    continue
                recorded.add(name)
                bar.clear()  # the session records it and its subscribers print its lines
                yield Outcome(result, None, trace)
                bar.step(result)
                del result, trace
        finally:
            self.close()

    def _submit(self, acquisitions: Iterable[Acquisition]) -> dict[Any, str]:
        """One task per acquisition, keyed by its folder and this run: future -> capture name."""
        token = uuid.uuid4().hex[:12]
        self._futures = {}
        for acq in acquisitions:
            folder = self.folders.get(acq.name)
            if folder is None:
                raise RecipeError(f"{acq.name}: not a capture folder of this cluster run")
            key = f"inspector-{hashlib.sha1(folder.encode('utf-8', 'surrogateescape')).hexdigest()[:16]}-{token}"
            fut = self.client.submit(inspect_folder, self.setup, folder, key=key, pure=False, retries=self.retries)
            self._futures[fut] = acq.name
        return dict(self._futures)

    def close(self) -> None:
        """Cancel the tasks not done yet (a run that ended early: Ctrl-C, a failure) and
        close the progress bar."""
        pending = [f for f in self._futures if not f.done()]
        self._futures = {}
        if pending:
            try:
                self.client.cancel(pending)
            except Exception:  # noqa: BLE001 - closing anyway
                pass
        if self._bar is not None:
            self._bar.close()
            self._bar = None


def run_on_cluster(session: Session, captures: Sequence[str], *, scheduler: str | None = None,
                   workers: int | None = None, client: Any = None, progress: bool = False,
                   retries: int = RETRIES) -> RunSummary:
    """Inspect the capture folders ``captures`` (or folders of them) on a Dask cluster, into
    ``session.outdir``, exactly as ``session.run`` would in this process: the same result
    folders, history rows, events (to the session's subscribers) and :class:`RunSummary`.
    It is ``session.run`` with a :class:`DaskExecutor`.

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
        setup = worker_setup(session)
        folders = capture_folders([str(c) for c in captures])
        if not folders:
            raise RecipeError("no capture to inspect")
        # Absolute, not resolved: a capture is named after its folder as the local run names it.
        paths = [os.path.abspath(f) for f in folders]
        by_name = {named_acquisition(f, _unread).name: p for f, p in zip(folders, paths)}
        own = client is None
        cluster = None
        if own:
            client, cluster = connect(scheduler, workers)
        executor = DaskExecutor(client, setup, by_name, retries=retries, progress=progress)
        try:
            return session.run(Source(captures=tuple(paths)), executor=executor)
        finally:
            executor.close()
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


class _Bar:
    """A tqdm progress bar on stderr when it is a terminal: cleared while the session records
    a capture and its subscribers print its lines (stdout, stderr), then drawn again one step on."""

    def __init__(self, total: int, enabled: bool) -> None:
        self.bar: Any = None
        if enabled and sys.stderr.isatty():
            try:
                from tqdm import tqdm

                self.bar = tqdm(total=total, file=sys.stderr, unit="capture", desc="inspect", dynamic_ncols=True)
            except ImportError:
                self.bar = None

    def clear(self) -> None:
        if self.bar is not None:
            self.bar.clear()

    def step(self, result: InspectionResult) -> None:
        """One capture more, named with its verdict."""
        if self.bar is not None:
            self.bar.set_postfix_str(f"{result.capture}: {result.verdict}", refresh=False)
            self.bar.update(1)
            self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
