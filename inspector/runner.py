"""Run a recipe on captures: every stage timed, every capture isolated from the others.

A capture that cannot be inspected becomes a result with verdict ``"error"`` and a one-line
reason; the batch goes on. A capture cancelled between two stages (``should_abort``) becomes
verdict ``"aborted"``: nothing is written for it, no ``inspector_on_result`` is called, and
the batch stops there. Unexpected exceptions (bugs) are reported the same way, with the
traceback written to ``traceback.txt`` in that capture's result folder, never to the user.
"""

from __future__ import annotations

import dataclasses
import time
import traceback
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from inspector.errors import InspectorError
from inspector.manager import PluginManager
from inspector.model import Capture, InspectionResult
from inspector.pipeline import InspectionContext
from inspector.recipe import Recipe
from inspector.reference import Reference
from inspector.registry import Acquisition

__all__ = ["ABORTED", "Outcome", "inspect_capture", "run_batch", "exit_status"]

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
    if ctx.bcps is not None and ctx.bcps.size is not None:
        # What the selection was made against: the part's best-fit size (scale 0.98: 2 % small).
        stats["size_fit"] = ctx.bcps.size.to_json()
    if ctx.evaluation is not None:
        stats.update(ctx.evaluation.stats)
    if ctx.capture.truth is not None:
        from inspector.truth import truth_stats

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
    ctx = InspectionContext(capture=capture, reference=reference, tolerance=recipe.tolerance)
    timings: dict[str, float] = {} if load_s is None else {"load": load_s}
    # "total" includes the time spent reading the capture, when known.
    t_start = time.perf_counter() - (load_s or 0.0)
    for step in recipe.steps:
        if should_abort is not None and should_abort():
            timings["total"] = time.perf_counter() - t_start
            aborted = _error_result(capture.name, recipe, f"cancelled before stage {step.name}", timings, capture)
            return Outcome(dataclasses.replace(aborted, verdict=ABORTED), ctx)
        pm.before_stage(ctx, step.spec, step.name)
        t0 = time.perf_counter()
        try:
            new = step.spec.run(ctx, step.params)
        except Exception as exc:  # noqa: BLE001 - one capture must never stop the batch
            timings[step.name] = time.perf_counter() - t0
            timings["total"] = time.perf_counter() - t_start
            pm.on_stage_error(ctx, step.spec, step.name, exc)
            if isinstance(exc, InspectorError):
                reason, trace = f"{step.name}: {exc}", None
            else:
                reason = f"{step.name}: internal error {type(exc).__name__}: {' '.join(str(exc).split())}"
                trace = traceback.format_exc()
            return Outcome(_error_result(capture.name, recipe, reason, timings, capture), ctx, trace)
        timings[step.name] = time.perf_counter() - t0
        ctx = new
        pm.after_stage(ctx, step.spec, step.name, timings[step.name])
    timings["total"] = time.perf_counter() - t_start
    ev = ctx.evaluation
    pose = ctx.alignment.pose if ctx.alignment is not None else None
    result = InspectionResult(
        capture=capture.name,
        recipe=recipe.name,
        verdict=ev.verdict if ev is not None else "pass",
        error=None,
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
    )
    return Outcome(result, ctx)


def _path(recipe: Recipe) -> str | None:
    return str(recipe.path) if recipe.path is not None else None


def _error_result(name: str, recipe: Recipe, reason: str, timings: dict[str, float], capture: Capture | None = None) -> InspectionResult:
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


def run_batch(
    recipe: Recipe,
    acquisitions: Iterable[Acquisition],
    pm: PluginManager,
    *,
    reference: Reference | None,
    outdir: Path | None = None,
    progress: Callable[[str], None] | None = None,
    should_abort: Callable[[], bool] | None = None,
) -> Iterator[Outcome]:
    """Inspect every acquisition in this process; yield one :class:`Outcome` each.

    Outputs are written (when ``outdir`` is given) and ``inspector_on_result`` is called
    before each outcome is yielded, so nothing is lost if a later capture fails. An aborted
    capture (``should_abort``) is yielded unwritten and ends the batch: the acquisition
    iterator is not resumed, so a hot folder keeps that capture in its inbox.
    """
    from inspector import outputs

    for acq in acquisitions:
        t0 = time.perf_counter()
        try:
            capture = acq.load()
        except InspectorError as exc:
            outcome = Outcome(_error_result(acq.name, recipe, str(exc), {"load": time.perf_counter() - t0, "total": time.perf_counter() - t0}), None)
        except Exception as exc:  # noqa: BLE001
            reason = f"internal error reading capture: {type(exc).__name__}: {' '.join(str(exc).split())}"
            outcome = Outcome(_error_result(acq.name, recipe, reason, {"total": time.perf_counter() - t0}), None, traceback.format_exc())
        else:
            outcome = inspect_capture(capture, recipe, reference, pm, load_s=time.perf_counter() - t0,
                                      should_abort=should_abort)
        if outcome.result.verdict == ABORTED:
            yield outcome
            return
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
        pm.on_result(outcome.result, folder)
        if progress is not None:
            progress(outputs.one_line(outcome.result))
        yield outcome
        outcome = capture = None  # not alive while the next capture is read and inspected


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
