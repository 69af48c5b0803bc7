"""Run a recipe on captures: every stage timed, every capture isolated from the others.

A capture that cannot be inspected becomes a result with verdict ``"error"`` and a one-line
reason; the batch goes on. A capture cancelled between two stages (``should_abort``) becomes
verdict ``"aborted"``: nothing is written for it, no ``inspector_on_result`` is called, and
the batch stops there. Unexpected exceptions (bugs) are reported the same way, with the
traceback written to ``traceback.txt`` in that capture's result folder, never to the user.
A stage that raises :class:`~inspector.errors.RecipeError` says the recipe cannot run on
that capture at all (evaluate's ``min_cameras`` above its rig's cameras): the batch ends
with it, as for an invalid recipe (exit 2), and nothing is written for that capture.

What a stage returns is checked (:func:`check_output`): a context whose output for the
stage's kind (:data:`inspector.registry.OUTPUTS`) is set and of its type; otherwise the
capture's verdict is ``"error"`` naming the step, the stage and its plugin.

What stages put in ``context.extras`` is kept: made JSON-safe (:func:`json_extras`; a value
that is not JSON is left out with a warning naming the stage and the key) into
``result.extras``, which ``result.json``, the history and ``inspector_on_result`` receive.

Time: each stage, and each plugin's lifecycle hooks (``hook:PLUGIN:HOOK``, summed over the
capture's calls), is in ``timings_s``; ``inspector_on_result`` runs after ``result.json`` is
written, which is then rewritten with its time. A stage or one hook call slower than the
recipe's :class:`~inspector.recipe.Budget` is a warning naming it in ``stats.warnings``.

One envelope, several executors: :func:`run_batch` records every outcome
(:func:`record_outcome`: the result folder, the CSV exports, ``inspector_on_result`` and its
time) whatever produced it; an :class:`Executor` does only the executing step, turning
acquisitions into unrecorded outcomes: :class:`LocalExecutor` loads and inspects them in this
process (the default), :class:`inspector_frontends.distributed.DaskExecutor` on a Dask cluster.
"""

from __future__ import annotations

import dataclasses
import math
import time
import traceback
from collections.abc import Callable, Generator, Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from inspector import exports, outputs
from inspector.errors import InspectorError, RecipeError, StageError
from inspector.manager import PluginManager
from inspector.model import (
    SUMMARY_FIELDS,
    Alignment,
    BcpsPoints,
    Capture,
    DeviationStats,
    Evaluation,
    EvaluationSummary,
    InspectionResult,
    Reconstruction,
    Silhouette,
)
from inspector.names import printable
from inspector.pipeline import InspectionContext
from inspector.recipe import BUDGET_ENV, Recipe
from inspector.reference import Reference
from inspector.registry import OUTPUTS, Acquisition, StageSpec
from inspector.truth import truth_stats
from inspector.watchdog import StageAborted, StageTimeout, call_with_limit

__all__ = ["ABORTED", "Outcome", "Executor", "LocalExecutor", "inspect_capture", "inspect_acquisition", "error_result",
           "record_outcome", "run_batch", "exit_status", "check_output", "json_extras", "hook_warning"]

#: The type of each kind's output (segment: a tuple of these).
_OUTPUT_TYPES: dict[str, type] = {
    "segment": Silhouette,
    "carve": Reconstruction,
    "classify": dict,
    "align": Alignment,
    "bcps": BcpsPoints,
    "evaluate": Evaluation,
}

#: Verdict of a capture cancelled between stages (never written, never a history row).
ABORTED = "aborted"


@dataclass(frozen=True, eq=False)
class Outcome:
    """One inspected (or failed) capture: its result, the final context, and a traceback."""

    result: InspectionResult
    context: InspectionContext | None
    trace: str | None = None
    #: The result folder written for it (None: no ``outdir``, aborted, or refused by
    #: :func:`inspector.outputs.write_result`, e.g. a capture named ``..``).
    folder: Path | None = None


def _summary(ctx: InspectionContext) -> dict[str, Any]:
    stats: dict[str, Any] = {}
    if ctx.silhouettes is not None:
        stats["border_cameras"] = [s.camera for s in ctx.silhouettes if s.touches_border]
    if ctx.reconstruction is not None:
        stats["reconstruction_points"] = int(len(ctx.reconstruction.points))
        stats["voxel_mm"] = float(ctx.reconstruction.voxel_mm)
    if ctx.alignment is not None:
        stats["alignment"] = {
            "method": ctx.alignment.method,
            "fitness": float(ctx.alignment.fitness),
            "rmse_mm": float(ctx.alignment.rmse_mm),
        }
        if ctx.alignment.confidence is not None:
            # How firmly the images fix the turn about the part's axis of near-symmetry.
            stats["alignment"]["pose_confidence"] = ctx.alignment.confidence.to_json()
    if ctx.bcps is not None and ctx.bcps.size is not None:
        # What the selection was made against: the part's best-fit size (scale 0.98: 2 % small).
        stats["size_fit"] = ctx.bcps.size.to_json()
    if ctx.evaluation is not None:
        if ctx.evaluation.summary is not None:  # its class may be the variant's own (same fields)
            stats.update(EvaluationSummary.to_json(ctx.evaluation.summary))
        stats.update(ctx.evaluation.stats)
    if ctx.capture.truth is not None:
        t = truth_stats(
            ctx.capture,
            ctx.bcps.points if ctx.bcps is not None else None,
            ctx.reconstruction.points if ctx.reconstruction is not None else None,
        )
        if t is not None:
            stats["truth"] = t
    return stats


def inspect_capture(
    capture: Capture,
    recipe: Recipe,
    reference: Reference | None,
    pm: PluginManager,
    *,
    load_s: float | None = None,
    should_abort: Callable[[], bool] | None = None,
) -> Outcome:
    """Run every stage of ``recipe`` on ``capture``.

    Parameters
    ----------
    should_abort : callable, optional
        Asked before each stage; True ends the inspection there with verdict ``"aborted"``.

    Returns
    -------
    Outcome
        Verdict ``"pass"``/``"fail"`` from the evaluate stage (``"pass"`` when the recipe has
        none), ``"error"`` with a one-line reason naming the stage, or ``"aborted"``.
    """
    ctx = InspectionContext(capture=capture, reference=reference, tolerance=recipe.tolerance,
                            settings=recipe.plugins)
    timings: dict[str, float] = {} if load_s is None else {"load": load_s}
    hooks = _Hooks(pm, recipe)
    extras_by: dict[str, str] = {}  # extras key -> the step that set it last
    # "total" includes the time spent reading the capture, when known.
    t_start = time.perf_counter() - (load_s or 0.0)

    def failed(reason: str, trace: str | None = None) -> Outcome:
        timings["total"] = time.perf_counter() - t_start
        res = error_result(capture.name, recipe, reason, timings, capture)
        return Outcome(hooks.into(res), ctx, trace)

    def aborted(reason: str) -> Outcome:
        timings["total"] = time.perf_counter() - t_start
        res = error_result(capture.name, recipe, reason, timings, capture)
        return Outcome(dataclasses.replace(res, verdict=ABORTED), ctx)

    budget = recipe.budget
    for step in recipe.steps:
        if should_abort is not None and should_abort():
            return aborted(f"cancelled before stage {step.name}")
        hooks.add(pm.before_stage(ctx, step.spec, step.name))
        t0 = time.perf_counter()
        left = budget.inspection_limit_s - (t0 - t_start)
        limit = min(budget.stage_limit_s, max(left, 0.0))
        try:
            new = call_with_limit(step.spec.run, ctx, step.params, limit_s=limit, should_abort=should_abort,
                                  name=f"stage-{step.name}")
        except StageAborted:
            timings[step.name] = time.perf_counter() - t0
            return aborted(f"cancelled during stage {step.name}")
        except StageTimeout as exc:
            timings[step.name] = time.perf_counter() - t0
            del exc
            who = f"stage {step.spec.name} of {pm.stage_plugin(step.spec.name)}"
            if limit < budget.stage_limit_s:
                what = f"{who}: the inspection exceeded {budget.inspection_limit_s:g} s (the inspection_limit_s of [budget])"
            else:
                what = f"{who} exceeded {budget.stage_limit_s:g} s (the stage_limit_s of [budget])"
            err = StageError(f"{step.name}: {what}; the part is given up, the cell goes on")
            hooks.add(pm.on_stage_error(ctx, step.spec, step.name, err))
            return failed(str(err))
        except RecipeError:
            # The recipe cannot run on this capture's rig (evaluate's min_cameras above its
            # cameras): refused like any invalid recipe (exit 2), never a made-up verdict.
            raise
        except Exception as exc:  # noqa: BLE001 - one capture must never stop the batch
            timings[step.name] = time.perf_counter() - t0
            hooks.add(pm.on_stage_error(ctx, step.spec, step.name, exc))
            if isinstance(exc, InspectorError):
                return failed(f"{step.name}: {exc}")
            reason = f"{step.name}: internal error {type(exc).__name__}: {' '.join(str(exc).split())}"
            return failed(reason, traceback.format_exc())
        timings[step.name] = time.perf_counter() - t0
        problem = check_output(new, step.spec)
        if problem is not None:  # a plugin's bug, named: the batch goes on
            err = StageError(f"{step.name}: stage {step.spec.name} of {pm.stage_plugin(step.spec.name)} {problem}")
            hooks.add(pm.on_stage_error(ctx, step.spec, step.name, err))
            return failed(str(err))
        for key, value in new.extras.items():
            if key not in ctx.extras or ctx.extras[key] is not value:
                extras_by[str(key)] = step.name
        ctx = new
        hooks.stage_budget(step.name, step.spec, timings[step.name])
        hooks.add(pm.after_stage(ctx, step.spec, step.name, timings[step.name]))
    timings["total"] = time.perf_counter() - t_start
    try:
        result = _result(ctx, capture, recipe, timings, extras_by, hooks.warnings)
    except Exception as exc:  # noqa: BLE001 - a stage's output the summary cannot read: that capture only
        reason = f"internal error summarising the result: {type(exc).__name__}: {' '.join(str(exc).split())}"
        return failed(reason, traceback.format_exc())
    return Outcome(hooks.into(result), ctx)


def _result(ctx: InspectionContext, capture: Capture, recipe: Recipe, timings: dict[str, float],
            extras_by: Mapping[str, str], warnings: list[str]) -> InspectionResult:
    ev = ctx.evaluation
    pose = ctx.alignment.pose if ctx.alignment is not None else None
    extras, bad = json_extras(ctx.extras, extras_by)
    warnings.extend(bad)
    return InspectionResult(
        capture=capture.name,
        recipe=recipe.name,
        verdict=ev.verdict if ev is not None else "pass",
        error=ev.error if ev is not None else None,
        timings_s=timings,
        pose=pose,
        stats=_summary(ctx),
        defects=ev.defects if ev is not None else (),
        reconstruction=ctx.reconstruction,
        bcps=ctx.bcps,
        rig=capture.rig,
        metadata=dict(capture.metadata),
        recipe_path=_path(recipe),
        recipe_sha256=recipe.sha256,
        summary=ev.summary if ev is not None else None,
        extras=extras,
    )


def check_output(new: object, spec: StageSpec) -> str | None:
    """What is wrong with what stage ``spec`` returned, in words, or None.

    A stage returns an :class:`InspectionContext` whose output for its kind
    (:data:`inspector.registry.OUTPUTS`) is set and of its type, with ``extras`` a dict; an
    evaluate stage's evaluation has a verdict ``pass``/``fail`` and a summary of the class
    it declared, its contract fields set.
    """
    if not isinstance(new, InspectionContext):
        return f"returned {type(new).__name__}, not an InspectionContext (return context.evolve(...))"
    if not isinstance(new.extras, dict):
        return f"set extras to a {type(new.extras).__name__}, not a dict"
    attr = OUTPUTS[spec.kind]
    value = getattr(new, attr)
    expected = _OUTPUT_TYPES[spec.kind]
    if value is None:
        return f"did not set {attr} (the output of a {spec.kind} stage)"
    if spec.kind == "segment":
        if not isinstance(value, tuple) or not all(isinstance(v, Silhouette) for v in value):
            return f"set {attr} to {type(value).__name__}, not a tuple of Silhouette"
    elif not isinstance(value, expected):
        return f"set {attr} to a {type(value).__name__}, not a {expected.__name__}"
    if isinstance(value, Evaluation):
        if value.verdict not in ("pass", "fail", "error"):
            return f"set the verdict {value.verdict!r}, not 'pass', 'fail' or 'error'"
        if (value.verdict == "error") != bool(value.error):
            return "set the verdict 'error' without its reason (Evaluation(error=...)), or a reason without it"
        summary = value.summary
        if summary is None:
            return "set no evaluation summary (Evaluation(summary=EvaluationSummary(...)))"
        if spec.summary is not None and not isinstance(summary, spec.summary):
            return f"set a summary of type {type(summary).__name__}, not the declared {spec.summary.__name__}"
        unset = [f for f in SUMMARY_FIELDS if not hasattr(summary, f)
                 or (getattr(summary, f) is None and f != "deviation_mm")]
        if unset:
            return f"left the summary's {unset[0]!r} unset"
        return _summary_types(summary)
    return None


def _summary_types(s: Any) -> str | None:
    """What of an evaluation summary's contract fields has the wrong type, or None."""
    def number(x: Any) -> bool:
        return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))

    if not number(s.n_points) or s.n_points != int(s.n_points) or s.n_points < 0:
        return f"set the summary's 'n_points' to {s.n_points!r}, not a count"
    if not number(s.out_of_tolerance_points) or s.out_of_tolerance_points != int(s.out_of_tolerance_points):
        return f"set the summary's 'out_of_tolerance_points' to {s.out_of_tolerance_points!r}, not a count"
    if not number(s.within_tolerance):
        return f"set the summary's 'within_tolerance' to {s.within_tolerance!r}, not a number"
    if s.deviation_mm is not None and not isinstance(s.deviation_mm, DeviationStats):
        return f"set the summary's 'deviation_mm' to a {type(s.deviation_mm).__name__}, not a DeviationStats"
    tol = s.tolerance_mm
    if not isinstance(tol, (tuple, list)) or len(tol) != 2 or not all(map(number, tol)):
        return f"set the summary's 'tolerance_mm' to {tol!r}, not (lower, upper)"
    return None


#: Nesting depth of an extras value beyond which it is not kept (as JSON input files).
_EXTRAS_DEPTH = 64


class _NotJson(Exception):
    def __init__(self, where: str, what: str) -> None:
        super().__init__(f"{where} is {what}")


def _json_value(value: Any, where: str, depth: int = 0) -> Any:
    """``value`` as JSON (numpy to Python, non-finite floats to None), or _NotJson naming
    the first part of it that is not."""
    if depth > _EXTRAS_DEPTH:
        raise _NotJson(where, f"nested deeper than {_EXTRAS_DEPTH} levels")
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        f = float(value)
        return f if math.isfinite(f) else None
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "biuf":
            raise _NotJson(where, f"an array of dtype {value.dtype}, not JSON")
        return _json_value(value.tolist(), where, depth)
    if isinstance(value, Mapping):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise _NotJson(f"{where}[{k!r}]", "under a key that is not a string, not JSON")
            out[k] = _json_value(v, f"{where}[{k!r}]", depth + 1)
        return out
    if isinstance(value, (list, tuple)):
        return [_json_value(v, f"{where}[{i}]", depth + 1) for i, v in enumerate(value)]
    raise _NotJson(where, f"of type {type(value).__name__}, not JSON")


def json_extras(extras: Mapping[Any, Any], set_by: Mapping[str, str] | None = None) -> tuple[dict[str, Any], list[str]]:
    """The JSON-safe part of ``context.extras``, and a warning for each key left out.

    Parameters
    ----------
    extras : mapping
        What the stages put in ``context.extras``.
    set_by : mapping, optional
        Key -> the recipe step that set it (named in the warnings).

    Returns
    -------
    (dict, list of str)
        Every key whose value is JSON (numpy numbers and arrays converted, NaN and
        infinities as None); one warning line per key that is not, naming the step and the key.
    """
    out: dict[str, Any] = {}
    warnings: list[str] = []
    for key, value in extras.items():
        step = (set_by or {}).get(str(key))
        who = f"stage {step!r}" if step else "a stage"
        if not isinstance(key, str):
            warnings.append(f"{who}: extras[{key!r}] is under a key that is not a string, not JSON; "
                            "left out of result.json and history")
            continue
        try:
            out[key] = _json_value(value, f"extras[{key!r}]")
        except _NotJson as e:
            warnings.append(f"{who}: {e}; left out of result.json and history")
    return out, warnings


class _Hooks:
    """One capture's lifecycle-hook times (summed per plugin and hook) and budget warnings."""

    def __init__(self, pm: PluginManager, recipe: Recipe) -> None:
        self.pm = pm
        self.budget = recipe.budget
        self.times: dict[str, float] = {}
        self.warnings: list[str] = []

    def add(self, times: Mapping[str, float]) -> None:
        for key, seconds in times.items():
            self.times[key] = self.times.get(key, 0.0) + seconds
            if seconds > self.budget.hook_s:
                self.warnings.append(hook_warning(key, self.budget.hook_s))

    def stage_budget(self, step: str, spec: StageSpec, seconds: float) -> None:
        if seconds > self.budget.stage_s:
            self.warnings.append(
                f"stage {step!r} ({spec.name} of {self.pm.stage_plugin(spec.name)}) took longer than its "
                f"{self.budget.stage_s:g} s budget (timings_s[{step!r}]); raise it with [budget] stage_s or "
                f"{BUDGET_ENV['stage_s']}")

    def into(self, result: InspectionResult) -> InspectionResult:
        """``result`` with the hook times in ``timings_s`` and the warnings in ``stats``."""
        return _with(result, self.times, self.warnings)


def hook_warning(key: str, budget_s: float) -> str:
    """The budget warning of hook time ``key`` (``hook:PLUGIN:HOOK``), one line, the same
    for every capture (printed once per run)."""
    _, plugin, hook = key.split(":", 2)
    who = "a hook wrapper" if plugin == "*" else f"plugin {plugin!r}"
    return (f"{who} took longer than the {budget_s:g} s hook budget in inspector_{hook} (timings_s[{key!r}]); "
            f"raise it with [budget] hook_s or {BUDGET_ENV['hook_s']}")


def _with(result: InspectionResult, times: Mapping[str, float], warnings: Iterable[str]) -> InspectionResult:
    """``result`` with ``times`` added to its timings and ``warnings`` to ``stats.warnings``
    (each once)."""
    warnings = list(warnings)
    if not times and not warnings:
        return result
    stats = dict(result.stats)
    if warnings:
        old = list(stats.get("warnings", ()))
        stats["warnings"] = old + [w for w in dict.fromkeys(warnings) if w not in old]
    return dataclasses.replace(result, timings_s={**result.timings_s, **times}, stats=stats)


def _path(recipe: Recipe) -> str | None:
    return str(recipe.path) if recipe.path is not None else None


def error_result(name: str, recipe: Recipe, reason: str, timings: dict[str, float],
                 capture: Capture | None = None) -> InspectionResult:
    """The result of capture ``name`` that could not be inspected: verdict ``"error"`` and the
    one-line ``reason``, with the capture's rig and metadata when it was read."""
    return InspectionResult(
        capture=name,
        recipe=recipe.name,
        verdict="error",
        error=reason,
        timings_s=timings,
        rig=capture.rig if capture is not None else None,
        metadata=dict(capture.metadata) if capture is not None else {},
        recipe_path=_path(recipe),
        recipe_sha256=recipe.sha256,
    )


def inspect_acquisition(acq: Acquisition, recipe: Recipe, reference: Reference | None, pm: PluginManager, *,
                        should_abort: Callable[[], bool] | None = None) -> Outcome:
    """Read ``acq`` and inspect it (:func:`inspect_capture`); a capture that cannot be read is
    an :class:`Outcome` with verdict ``"error"`` and a one-line reason (and, for a bug of its
    reader, the traceback). Writes nothing."""
    t0 = time.perf_counter()
    try:
        capture = acq.load()
    except InspectorError as exc:
        dt = time.perf_counter() - t0
        return Outcome(error_result(acq.name, recipe, str(exc), {"load": dt, "total": dt}), None)
    except Exception as exc:  # noqa: BLE001 - that capture only
        reason = f"internal error reading capture: {type(exc).__name__}: {' '.join(str(exc).split())}"
        return Outcome(error_result(acq.name, recipe, reason, {"total": time.perf_counter() - t0}), None,
                       traceback.format_exc())
    return inspect_capture(capture, recipe, reference, pm, load_s=time.perf_counter() - t0, should_abort=should_abort)


class Executor(Protocol):
    """The executing step of a run: acquisitions in, unrecorded :class:`Outcome` objects out.

    :func:`run_batch` (and :meth:`inspector.session.Session.run` through it) is the envelope
    around it: it records each outcome as it comes (:func:`record_outcome`) and ends the batch
    at the first ``"aborted"`` one. An executor writes nothing and calls no
    ``inspector_on_result``; it yields each capture at most once, in any order, and stops its
    work when its iterator is closed.
    """

    def warnings(self) -> list[str]:
        """Warnings about the run about to start (the session emits each as
        ``Warned("run", text)`` before ``inspector_on_run_start``)."""
        ...

    def execute(self, recipe: Recipe, acquisitions: Iterable[Acquisition], pm: PluginManager, *,
                reference: Reference | None, should_abort: Callable[[], bool] | None = None) -> Iterator[Outcome]:
        """One unrecorded outcome per acquisition (``should_abort``: asked between stages,
        where the executor can)."""
        ...


class LocalExecutor:
    """Load and inspect each acquisition in this process, one after the other (the default
    :class:`Executor`). A capture cancelled between two stages (``should_abort``) is yielded
    with verdict ``"aborted"`` and ends it: the acquisition iterator is not resumed."""

    def warnings(self) -> list[str]:
        return []

    def execute(self, recipe: Recipe, acquisitions: Iterable[Acquisition], pm: PluginManager, *,
                reference: Reference | None, should_abort: Callable[[], bool] | None = None) -> Iterator[Outcome]:
        for acq in acquisitions:
            outcome = inspect_acquisition(acq, recipe, reference, pm, should_abort=should_abort)
            yield outcome
            if outcome.result.verdict == ABORTED:
                return
            outcome = None  # type: ignore[assignment]  # not alive while the next capture is read and inspected


def record_outcome(outcome: Outcome, recipe: Recipe, pm: PluginManager, outdir: Path | None) -> Outcome:
    """Record one inspected capture, in this process: its result folder in ``outdir``
    (:func:`inspector.outputs.write_result`; none when ``outdir`` is None), its CSV exports,
    then ``inspector_on_result`` (the history row), whose times (and budget warnings) go into
    the result and its ``result.json``.

    Returns
    -------
    Outcome
        ``outcome`` with its ``folder`` and the hooks' times; an ``"error"`` in one line when
        its result folder could not be written (a name such as ``..``, a full disk).
    """
    folder = None
    if outdir is not None:
        try:
            folder = outputs.write_result(outcome.result, Path(outdir), trace=outcome.trace)
        except InspectorError as exc:
            # A name that cannot be a result folder (``..``, ``history.sqlite``...):
            # nothing is written, the capture is an error in one line, the batch goes on.
            outcome = _unwritten(outcome, str(exc))
        else:
            outcome = dataclasses.replace(outcome, folder=folder)
            _export_csv(outcome.result, folder, recipe.outputs.csv)
    times = pm.on_result(outcome.result, folder)
    if times:  # the hooks' time (and budget) into the result, and its result.json
        slow = [hook_warning(k, recipe.budget.hook_s) for k, t in times.items() if t > recipe.budget.hook_s]
        outcome = dataclasses.replace(outcome, result=_with(outcome.result, times, slow))
        if folder is not None:
            outputs.rewrite_result_json(outcome.result, folder)
    return outcome


def run_batch(
    recipe: Recipe,
    acquisitions: Iterable[Acquisition],
    pm: PluginManager,
    *,
    reference: Reference | None,
    outdir: Path | None = None,
    progress: Callable[[str], None] | None = None,
    should_abort: Callable[[], bool] | None = None,
    executor: Executor | None = None,
) -> Generator[Outcome, None, None]:
    """Inspect every acquisition with ``executor`` (default: :class:`LocalExecutor`, in this
    process); yield one recorded :class:`Outcome` each, in the order the executor gives them.

    Outputs are written (when ``outdir`` is given) and ``inspector_on_result`` is called
    (:func:`record_outcome`) before each outcome is yielded, so nothing is lost if a later
    capture fails. An aborted capture (``should_abort``) is yielded unwritten and ends the
    batch: the executor is closed, the acquisition iterator is not resumed, so a hot folder
    keeps that capture (in ``INBOX/processing/``, inspected again at the watcher's next start).
    """
    executor = executor if executor is not None else LocalExecutor()
    outcomes = executor.execute(recipe, acquisitions, pm, reference=reference, should_abort=should_abort)
    try:
        for outcome in outcomes:
            if outcome.result.verdict == ABORTED:
                yield outcome
                return
            outcome = record_outcome(outcome, recipe, pm, outdir)
            if progress is not None:
                progress(outputs.one_line(outcome.result))
            yield outcome
            outcome = None  # type: ignore[assignment]  # not alive while the next capture is read and inspected
    finally:
        close = getattr(outcomes, "close", None)
        if close is not None:
            close()


def _export_csv(result: InspectionResult, folder: Path, csv: bool) -> None:
    """The CSV exports of a written result (``[outputs] csv``, ``--csv``), or no stale ones
    from an earlier run. They are extras: a failure (a full disk) is one warning line, the
    result stands."""
    import sys

    try:
        if csv:
            exports.write_csv(result, folder)
        else:
            exports.remove_csv(folder)
    except OSError as exc:
        print(f"inspector: warning: capture '{printable(result.capture)}': CSV export not written: "
              f"{exc.filename or folder}: {exc.strerror or exc}", file=sys.stderr, flush=True)


def _unwritten(outcome: Outcome, reason: str) -> Outcome:
    """``outcome`` as an error whose result could not be written: an error keeps its own
    reason (for a capture refused by its driver, the same name problem); a verdict becomes
    an error, so no part passes without its result."""
    result = outcome.result
    if result.verdict != "error":
        result = dataclasses.replace(result, verdict="error", error=reason)
    return Outcome(result, outcome.context, outcome.trace)


def exit_status(results: Iterable[InspectionResult | str]) -> int:
    """CONTRACT exit status: 3 if any capture errored, else 1 if any failed, else 0.

    ``results``: the results, or only their verdicts.
    """
    verdicts = {r if isinstance(r, str) else r.verdict for r in results}
    if "error" in verdicts:
        return 3
    if "fail" in verdicts:
        return 1
    return 0
