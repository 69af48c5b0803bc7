"""A feasibility study's simulation records turned into its results.

* observability per surface element (nominal captures): the share of poses with a BCPS point
  on it, and the mean and p95 distance of those points to the true surface;
* per region: observable share of its area; POD of dents and of bumps (hit: the inspection
  rejects the part for a cluster of the defect's kind at the defect); false rejects of the
  nominal part there; the type-1 gauge study of its points' deviations against its band;
  the repeatability of its deviation statistics and verdict; and a verdict in words.

A nominal capture is *misaligned* when the recipe's pose, not the points, is wrong: the mean
change of the points' distances between the estimated and the true pose (``| |deviation| -
distance to the true surface | ``) exceeds :data:`MISFIT_PX` pixel footprints (99 of 100 bracket
captures: at most 0.0024 mm; one turned the wrong way: 0.051 mm). Its verdict counts (a false
reject), but its points are left out of the gauge study, which measures the repeatability of
a correctly posed part; the report says how many there were.

A defect is *hit* when a reported defect of its kind (missing material for a dent, excess
for a bump) lies within ``radius + span / 2 + cluster radius`` of its centre, in the
reference frame through the true pose. Captures whose verdict is ``error`` (e.g. an
ambiguous pose) are counted apart: not a hit, a miss, a pass nor a false reject.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from inspector_tools.feasibility.stats import (
    CG_MIN,
    Gauge,
    PodFit,
    binomial_upper,
    gauge_type1,
    grouped_mean_quantile,
    majority_share,
    observed_fraction,
    pod_fit,
)

if TYPE_CHECKING:
    from inspector_tools.feasibility.study import Study
    from inspector_tools.feasibility.surface import SurfaceMap

__all__ = ["FRR_MAX", "MISFIT_PX", "RegionResult", "Results", "analyse", "match_defects", "band_text", "pose_misfit_mm"]

#: Largest share of nominal captures a region may falsely reject and still be inspectable.
FRR_MAX = 0.01

#: Pose misfit (pixel footprints) beyond which a nominal capture counts as misaligned.
MISFIT_PX = 0.1

#: Defect kinds: the simulator's bump kind -> (name in the report, reported defect kind).
DEFECT_KINDS = {"remove": ("dent", "missing"), "add": ("bump", "excess")}


def band_text(lower: float, upper: float) -> str:
    """``±0.1 mm`` for a symmetric band, ``[-0.05, +0.1] mm`` otherwise."""
    if math.isclose(-lower, upper):
        return f"±{upper:g} mm"
    return f"[{lower:+g}, {upper:+g}] mm"


@dataclass
class RegionResult:
    """One region's results (see the module's docstring)."""

    name: str
    lower: float
    upper: float
    area_mm2: float
    observable_share: float  # area share observed in at least one pose
    mean_observability: float  # area-weighted mean share of poses
    pod: dict[str, PodFit]  # "dent", "bump"
    gauge: Gauge
    frr_k: int  # nominal captures rejected for a defect in this region
    frr_n: int
    repeat: dict[str, tuple[float, float]]  # statistic -> (mean, std) over captures, mm
    verdict_share: tuple[str | None, float]
    misaligned: list[str] = field(default_factory=list)  # nominal captures whose pose was wrong
    reasons: list[str] = field(default_factory=list)

    @property
    def frr(self) -> float:
        return self.frr_k / self.frr_n if self.frr_n else math.nan

    @property
    def inspectable(self) -> bool:
        return not self.reasons

    @property
    def band(self) -> str:
        return band_text(self.lower, self.upper)

    def gauge_sentence(self) -> str:
        """The type-1 conclusion in plain words."""
        g = self.gauge
        if not math.isfinite(g.cg):
            return f"region '{self.name}': no point measured, no gauge study"
        can = "can" if g.capable else "cannot"
        return f"region '{self.name}' {can} be inspected at {self.band} with this rig: Cg = {g.cg:.2f}, Cgk = {g.cgk:.2f}"

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name, "lower_mm": self.lower, "upper_mm": self.upper, "area_mm2": self.area_mm2,
            "observable_share": self.observable_share, "mean_observability": self.mean_observability,
            "pod": {k: v.to_json() for k, v in self.pod.items()}, "gauge": self.gauge.to_json(),
            "false_rejects": self.frr_k, "nominal_captures": self.frr_n, "false_reject_rate": self.frr,
            "repeatability_mm": {k: {"mean": m, "std": s} for k, (m, s) in self.repeat.items()},
            "verdict_repeatability": {"verdict": self.verdict_share[0], "share": self.verdict_share[1]},
            "inspectable": self.inspectable, "reasons": self.reasons, "conclusion": self.gauge_sentence(),
        }


@dataclass
class Results:
    """Everything the report shows."""

    study: Study
    map: SurfaceMap
    observability: np.ndarray  # (E,) share of poses
    err_mean: np.ndarray  # (E,) mm, nan where never observed
    err_p95: np.ndarray  # (E,) mm
    n_points: np.ndarray  # (E,) points in all poses
    regions: list[RegionResult]
    nominal: dict[str, Any]  # n, fail, error, frr, frr_upper95, truth means
    defects: list[dict[str, Any]]  # one row per placed defect
    sims: list[dict[str, Any]]  # one summary row per simulation
    elapsed_s: float
    ran: int
    deviations: dict[str, np.ndarray] = field(default_factory=dict)  # region -> every point's deviation, mm

    def observed_share(self) -> float:
        """Area share of the whole surface observed in at least one pose."""
        a = self.map.area
        return float(a[self.observability > 0].sum() / a.sum()) if a.sum() else math.nan

    def conclusions(self) -> list[str]:
        """One line per region: the verdict and its reasons, then the gauge sentence."""
        lines = []
        for r in self.regions:
            v = "inspectable" if r.inspectable else "NOT inspectable"
            lines.append(f"region '{r.name}' at {r.band}: {v}" + (f" ({'; '.join(r.reasons)})" if r.reasons else ""))
        lines += [r.gauge_sentence() for r in self.regions]
        return lines

    def to_json(self) -> dict[str, Any]:
        return {
            "key": self.study.key, "reference": self.study.config["reference"], "rig": self.study.rig_label,
            "footprint_mm": self.study.footprint_mm, "element_mm": self.map.element_mm, "elements": self.map.n,
            "observed_share": self.observed_share(), "nominal": self.nominal,
            "regions": [r.to_json() for r in self.regions], "elapsed_s": self.elapsed_s, "simulations_run": self.ran,
            "simulations": len(self.sims),
        }


def match_defects(placed: Sequence[Mapping[str, Any]], reported: Sequence[Mapping[str, Any]], cluster_mm: float) -> list[bool]:
    """Whether each placed defect was found.

    Parameters
    ----------
    placed : sequence of {"at": (3,) mm, "radius_mm", "kind": "remove"|"add"}
        Reference frame.
    reported : sequence of {"at": (3,) mm, "span_mm", "kind": "missing"|"excess"}
        The inspection's defects, mapped into the reference frame through the true pose.
    cluster_mm : float
        The evaluate stage's cluster radius.
    """
    hits = []
    for d in placed:
        want = DEFECT_KINDS[d["kind"]][1]
        c = np.asarray(d["at"], float)
        hits.append(any(r["kind"] == want and np.linalg.norm(np.asarray(r["at"], float) - c)
                        <= d["radius_mm"] + 0.5 * r["span_mm"] + cluster_mm for r in reported))
    return hits


def _shown(rec: Mapping[str, Any], d: Mapping[str, Any], reach: float) -> float:
    """The deepest (dent) or highest (bump) deviation among the points within ``reach`` of
    a defect's sphere: how much of it the inspection shows, mm (nan: no point there)."""
    pts = rec.get("points")
    if pts is None or not len(pts):
        return math.nan
    near = np.linalg.norm(np.asarray(pts, float) - np.asarray(d["at"], float), axis=1) <= d["radius_mm"] + reach
    if not near.any():
        return math.nan
    dev = np.asarray(rec["deviation"], float)[near]
    return float(dev.min() if d["kind"] == "remove" else dev.max())


def pose_misfit_mm(record: Mapping[str, Any]) -> float:
    """Mean ``| |deviation| - distance to the true surface |`` of a nominal capture's points,
    mm: how much the estimated pose, rather than the points, moves them (nan without points)."""
    dev, dist = record.get("deviation"), record.get("dist_true")
    if dev is None or dist is None or not len(dev):
        return math.nan
    return float(np.mean(np.abs(np.abs(np.asarray(dev, float)) - np.asarray(dist, float))))


def analyse(study: Study, records: Sequence[Mapping[str, Any]], *, elapsed_s: float = math.nan, ran: int = 0) -> Results:
    """The study's results from its simulations' records (any order; the same records give
    the same results)."""
    m = study.map
    names = list(m.regions.names)
    cluster_mm = float(study.config["cluster_radius_mm"])
    recs = sorted(records, key=lambda r: (r["kind"], r["index"]))
    nominal = [r for r in recs if r["kind"] == "nominal" and r["status"] == "ok"]
    defect = [r for r in recs if r["kind"] == "defect" and r["status"] == "ok"]

    # observability and error per element
    ids_per_pose, all_ids, all_dist = [], [], []
    point_region: list[np.ndarray] = []
    for r in nominal:
        pts = r.get("points")
        ids = m.assign(pts) if pts is not None and len(pts) else np.zeros(0, np.int64)
        ids_per_pose.append(ids)
        point_region.append(m.region[ids])
        if len(ids) and "dist_true" in r:
            all_ids.append(ids)
            all_dist.append(np.asarray(r["dist_true"], float))
    obs = observed_fraction(ids_per_pose, m.n)
    if all_ids:
        err_mean, err_p95, npts = grouped_mean_quantile(np.concatenate(all_ids), np.concatenate(all_dist), m.n, 95.0)
    else:
        err_mean = err_p95 = np.full(m.n, np.nan)
        npts = np.zeros(m.n, np.int64)

    # per capture and region: rejecting defects, deviation statistics
    judged = [i for i, r in enumerate(nominal) if r.get("verdict") in ("pass", "fail")]
    misfit = {i: pose_misfit_mm(nominal[i]) for i in judged}
    limit = MISFIT_PX * study.footprint_mm
    misaligned = [i for i in judged if misfit[i] > limit]
    posed = [i for i in judged if i not in misaligned]
    fails_in: dict[int, set[int]] = {}
    for i in judged:
        regs = {int(m.region[m.assign(np.asarray([d["at"]]))[0]]) for d in nominal[i].get("defects", [])}
        fails_in[i] = regs

    # placed defects: hit or miss
    drows: list[dict[str, Any]] = []
    for r in defect:
        placed = r.get("placed", [])
        if r.get("verdict") == "error":
            hits: list[bool | None] = [None] * len(placed)
        else:
            hits = list(match_defects(placed, r.get("defects", []), cluster_mm))
        fp = float(r.get("footprint_mm") or study.footprint_mm)
        for d, h in zip(placed, hits):
            drows.append({"capture": r["name"], "region": d["region"], "kind": DEFECT_KINDS[d["kind"]][0],
                          "size_mm": float(d["radius_mm"]), "x": d["at"][0], "y": d["at"][1], "z": d["at"][2],
                          "hit": h, "shown_mm": _shown(r, d, fp), "verdict": r.get("verdict")})

    area_region = m.region_area()
    regions: list[RegionResult] = []
    deviations: dict[str, np.ndarray] = {}
    for name in study.studied:
        k = names.index(name)
        lower, upper = m.regions.bands[k]
        in_region = m.region == k
        area = float(area_region[k])
        a = m.area[in_region]
        observable = float(a[obs[in_region] > 0].sum() / area) if area > 0 else math.nan
        mean_obs = float((a * obs[in_region]).sum() / area) if area > 0 else math.nan
        pods = {}
        for kind in ("dent", "bump"):
            rows = [d for d in drows if d["region"] == name and d["kind"] == kind and d["hit"] is not None]
            pods[kind] = pod_fit(np.array([d["size_mm"] for d in rows], float), np.array([bool(d["hit"]) for d in rows]))
        devs = [np.asarray(nominal[i]["deviation"], float)[point_region[i] == k] for i in posed
                if nominal[i].get("deviation") is not None]
        deviations[name] = np.concatenate(devs) if devs else np.zeros(0)
        gauge = gauge_type1(deviations[name], lower, upper)
        per = [d for d in devs if len(d) >= 10]
        repeat = {}
        for stat, f in (("mean", np.mean), ("p01", lambda x: np.percentile(x, 1)), ("p99", lambda x: np.percentile(x, 99))):
            vals = np.array([float(f(d)) for d in per])
            repeat[stat] = (float(vals.mean()), float(vals.std(ddof=1))) if len(vals) > 1 else (math.nan, math.nan)
        verdicts = ["fail" if k in fails_in[i] else "pass" for i in judged]
        rr = RegionResult(name, lower, upper, area, observable, mean_obs, pods, gauge,
                          sum(v == "fail" for v in verdicts), len(verdicts), repeat, majority_share(verdicts),
                          [nominal[i]["name"] for i in misaligned])
        rr.reasons = _reasons(rr, study.config["sizes_mm"][1])
        regions.append(rr)

    n_judged = len(judged)
    n_fail = sum(nominal[i]["verdict"] == "fail" for i in judged)
    truth = [r["truth_mean_mm"] for r in nominal if r.get("truth_mean_mm") is not None]
    nom = {"captures": len(nominal), "judged": n_judged, "fail": n_fail,
           "error": sum(r.get("verdict") == "error" for r in nominal),
           "frr": n_fail / n_judged if n_judged else math.nan, "frr_upper95": binomial_upper(n_fail, n_judged),
           "misaligned": [nominal[i]["name"] for i in misaligned],
           "misaligned_failed": sum(nominal[i]["verdict"] == "fail" for i in misaligned),
           "pose_misfit_mm": {"limit": limit, "median": float(np.median([misfit[i] for i in posed])) if posed else math.nan,
                              "max_posed": float(max((misfit[i] for i in posed), default=math.nan))},
           "bcps_truth_mean_mm": float(np.mean(truth)) if truth else math.nan}
    sims = [{k: r.get(k) for k in ("name", "kind", "index", "seed", "status", "verdict", "error", "n_points", "truth_mean_mm",
                                    "truth_p99_mm", "t_simulate_s", "t_inspect_s", "t_run_s", "worker")}
            | {"defects": len(r.get("defects", [])), "placed": len(r.get("placed", [])),
               "pose_misfit_mm": pose_misfit_mm(r) if r["kind"] == "nominal" else None} for r in recs]
    return Results(study, m, obs, err_mean, err_p95, npts, regions, nom, drows, sims, elapsed_s, ran, deviations)


def pod_words(kind: str, fit: PodFit) -> str | None:
    """Why ``fit`` does not show the kind detected (None when a90/95 is within the sizes tested)."""
    if fit.a90_95 is not None and not fit.extrapolated:
        return None
    found = f"{fit.hits} of {fit.n} found" if fit.n else "none placed"
    if fit.status == "no-data":
        return f"{kind}s: none placed here"
    if fit.extrapolated:
        beyond = f"a90/95 = {fit.a90_95:.3g} mm" if fit.a90_95 is not None and fit.a90_95 < 3 * fit.a_max else "a90/95"
        return f"{kind}s: {beyond} beyond the largest size tested ({fit.a_max:.3g} mm; {found})"
    if fit.status in ("all-missed", "flat"):
        return f"{kind}s: not detected up to {fit.a_max:.3g} mm ({found})"
    if fit.status == "separated":
        return f"{kind}s: {fit.note}"
    return f"{kind}s: POD does not reach 90 % with 95 % confidence up to {fit.a_max:.3g} mm ({found})"


def _reasons(r: RegionResult, max_size: float) -> list[str]:
    out = []
    g = r.gauge
    if not math.isfinite(g.cg):
        out.append("no point of the nominal part measured here")
    elif not g.capable:
        out.append(f"Cg = {g.cg:.2f}, Cgk = {g.cgk:.2f}, below {CG_MIN}: the measurement spreads ±{3 * g.s:.3g} mm (3 s) "
                   f"against the band {r.band}")
    if r.misaligned and r.frr_n and len(r.misaligned) / r.frr_n > FRR_MAX:
        out.append(f"the pose was wrong in {len(r.misaligned)} of {r.frr_n} nominal captures")
    if r.frr_n and r.frr > FRR_MAX:
        out.append(f"false rejects in {r.frr_k} of {r.frr_n} nominal captures ({100 * r.frr:.1f} %, above {100 * FRR_MAX:g} %)")
    for kind in ("dent", "bump"):
        why = pod_words(kind, r.pod[kind])
        if why:
            out.append(why)
    return out
