"""Stage ``evaluate.characteristics``: the recipe's characteristics measured on each part.

It runs after ``evaluate.tolerance`` (it is an evaluate stage that ``requires`` one before
it, so the recipe refuses the other order) and leaves that stage's evaluation as it was but
for two things:

* the verdict: a ``pass`` becomes ``fail`` when a characteristic is ``nok`` (and, with
  ``fail_not_measurable``, when one is ``not_measurable``); ``fail`` and ``error`` stay;
* ``stats.characteristics``: how many are ok, nok and not measurable, and the ids of the
  nok ones (a failed part whose defect list is empty says why here).

Every characteristic's row goes to ``context.extras["characteristics"]`` -- ``result.json``
``extras.characteristics``, the history's extras and ``InspectionResult.extras`` -- as
``{id, kind, features, nominal, measured, deviation, lower, upper, u, U, points, verdict,
reason, unit, criticality, description}`` (:meth:`CharacteristicResult.to_json` plus the
definition's unit, criticality and description), and the stage's time to ``timings_s``
under the stage's name in the recipe (``characteristics`` in the examples).

The characteristics come from the recipe's ``[[characteristics]]`` (checked against the
reference's features when the recipe is loaded: :mod:`inspector.characteristics.definitions`),
which reach the stage as ``context.settings["characteristics"]``. The points are the BCPS
points in the reference frame of the aligned reference, weighted by the bcps per-point
confidence (:func:`inspector.kernels.bcps.confidence`); see
:func:`inspector.characteristics.measure.measure` for the fits, the uncertainties and the
``not_measurable`` reasons.

Recipe::

    [[stages]]
    name = "characteristics"
    use = "evaluate.characteristics"
    params = { band_mm = 0.5 }
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from inspector import hookimpl
from inspector.kernels.bcps import confidence
from inspector.model import EvaluationSummary
from inspector.params import param
from inspector.pipeline import InspectionContext
from inspector.registry import StageRegistry, StageSpec

#: The ``context.extras`` and ``stats`` key.
KEY = "characteristics"


@dataclass(frozen=True)
class CharacteristicsParams:
    band_mm: float = param(0.5, "a BCPS point belongs to the feature of its nearest reference triangle when it lies "
                                "within this distance of it, mm", min=0.001, max=100.0)
    max_u_fraction: float = param(0.5, "a characteristic whose expanded uncertainty U exceeds this fraction of its "
                                       "tolerance width is not measurable (the measurement cannot decide)",
                                  min=0.001, max=100.0)
    weighted: bool = param(True, "weight the points by the bcps per-point confidence (a grazing ray's point less)")
    u_surface_px: float = param(0.01, "standard uncertainty of the offset the silhouettes give the whole part's surface, "
                                      "in pixel footprints (added to each diameter's and thickness's u: 2 x this for "
                                      "both; see docs/characteristics.md for how it was measured)", min=0.0, max=10.0)
    per_camera: bool = param(True, "count the points of one camera's contour as erring together: each fit's "
                                   "uncertainty grows by their between-camera scatter (a plane seen only along "
                                   "edges that few cameras show is held by a few observations, not thousands)")
    snap_edges: bool = param(True, "move the points near a sharp edge between two planes along their contour rays "
                                   "onto the edge the rays show (the hull places them outside the faces; "
                                   "docs/characteristics.md)")
    fail_not_measurable: bool = param(False, "a characteristic the silhouettes cannot measure fails the part "
                                             "(default: reported with its reason, the verdict unchanged)")


def rows(ctx: InspectionContext, p: CharacteristicsParams) -> list[dict[str, Any]]:
    """The characteristics of ``ctx``'s part, as ``result.json`` rows (see the module)."""
    from inspector.characteristics.definitions import SETTINGS_KEY, features_and_edges
    from inspector.characteristics.measure import measure

    chars = tuple(ctx.settings.get(SETTINGS_KEY, ()))
    if not chars:
        return []
    sel = ctx.need("bcps", "characteristics")
    pose = ctx.need("alignment", "characteristics").pose
    ref = ctx.need("reference", "characteristics")
    feats, ref_edges = features_and_edges(ref.vertices, ref.faces)
    local = ref.to_reference_frame(sel.points, pose)
    weights = None
    fp = ctx.capture.rig.footprint_mm() if len(ctx.capture.rig) else None
    if p.weighted and fp is not None and len(sel.segment_mm):
        weights = confidence(sel.segment_mm, fp)
    u_surface = p.u_surface_px * fp if fp is not None else 0.0
    groups = np.asarray(sel.camera) if p.per_camera and len(sel.camera) == len(local) else None
    origins, edges = None, ()
    if p.snap_edges and len(sel.camera) == len(local) and len(ctx.capture.rig):
        centres = np.stack([cam.centre for cam in ctx.capture.rig])
        origins = ref.to_reference_frame(centres, pose)[np.asarray(sel.camera, np.int64)]
        edges = ref_edges
    results = measure(chars, feats, local, weights, ref, band_mm=p.band_mm, max_u_fraction=p.max_u_fraction,
                      u_surface_mm=u_surface, groups=groups, origins=origins, edges=edges)
    out = []
    for c, r in zip(chars, results):
        out.append({**r.to_json(), "unit": c.unit, "criticality": c.criticality, "description": c.label})
    return out


def run_characteristics(ctx: InspectionContext, p: CharacteristicsParams) -> InspectionContext:
    ev = ctx.need("evaluation", "characteristics")
    found = rows(ctx, p)
    count = {v: sum(r["verdict"] == v for r in found) for v in ("ok", "nok", "not_measurable")}
    nok = [r["id"] for r in found if r["verdict"] == "nok"]
    unmeasured = [r["id"] for r in found if r["verdict"] == "not_measurable"]
    summary: dict[str, Any] = {**count, "nok_ids": nok, "not_measurable_ids": unmeasured}
    verdict = ev.verdict
    if verdict == "pass" and (nok or (p.fail_not_measurable and unmeasured)):
        verdict = "fail"
    stats = {**ev.stats, KEY: summary}
    if unmeasured:
        # A drawing's characteristic the cell cannot measure is worth a line in the run, not
        # only a field: the reason says what to change (a camera, the band, the tolerance).
        reasons = {r["id"]: r["reason"] for r in found if r["verdict"] == "not_measurable"}
        warn = [f"characteristic {cid}: not measurable: {why}" for cid, why in reasons.items()]
        stats["warnings"] = [*ev.stats.get("warnings", []), *warn]
    evaluation = dataclasses.replace(ev, verdict=verdict, stats=stats)
    return ctx.evolve(evaluation=evaluation, extras={**ctx.extras, KEY: found})


def characteristic_rows(result: Any) -> list[dict[str, Any]]:
    """The characteristics rows of one result (:func:`inspector.characteristics.definitions.rows_of`)."""
    from inspector.characteristics.definitions import rows_of

    return rows_of(result)


@hookimpl
def inspector_register_stages(registry: StageRegistry) -> None:
    registry.add(
        StageSpec(
            name="evaluate.characteristics",
            run=run_characteristics,
            params=CharacteristicsParams,
            requires=("bcps", "evaluate"),
            doc="The recipe's [[characteristics]] (diameters, distances, angles, positions, form) measured with their "
                "uncertainty; a NOK one fails the part",
            summary=EvaluationSummary,
        )
    )
