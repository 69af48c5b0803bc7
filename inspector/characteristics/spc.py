"""Capability of a characteristic from its measured values: SPC (Cp, Cpk) and the type-1
gauge study (Cg, Cgk).

Pure functions of numbers (no file, plot or database), so the history, the GUI, the OPC UA
server and the acceptance scripts compute the same figures:

* **process capability** (ISO 22514-2, normal distribution): ``Cp = (USL - LSL) / (6 s)``,
  ``Cpk = min(USL - mean, mean - LSL) / (3 s)``, with ``s`` the sample standard deviation
  (``ddof = 1``), and the count of values outside ``[LSL, USL]``;
* **type-1 gauge study** (VDA 5 / Bosch booklet 10, as :func:`inspector_tools.feasibility.stats.gauge_type1`):
  repeated measurements of one part whose true value ``reference`` is known;
  ``Cg = k T / (L s)`` and ``Cgk = (k T / 2 - |mean - reference|) / (L s / 2)`` with the
  tolerance width ``T = USL - LSL``, ``k = 0.2`` and ``L = 6``. The gauge is capable for the
  tolerance when both are at least 1.33; :func:`capable_tolerance` gives the smallest
  tolerance width for which it is.

A figure that the values do not define (fewer than two values, no reference) is ``nan``,
never a made-up number; ``s = 0`` gives ``inf`` (or ``-inf`` for a ``Cgk`` whose bias
alone exceeds ``k T / 2``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["CG_MIN", "Capability", "capability", "capable_tolerance", "series", "table"]

#: Cg and Cgk a capable gauge reaches (VDA 5, Bosch booklet 10).
CG_MIN = 1.33


@dataclass(frozen=True)
class Capability:
    """The capability figures of one characteristic.

    Attributes
    ----------
    n : int
        Values (finite ones).
    mean, s : float
        Their mean and sample standard deviation, in the characteristic's unit.
    cp, cpk : float
        Process capability against ``[lower, upper]``.
    out_of_tolerance : int
        Values outside ``[lower, upper]``.
    cg, cgk : float
        Type-1 gauge figures (nan without a reference value).
    lower, upper : float
        The limits, absolute (nominal + allowances).
    reference : float or None
        The true value of the part the study measured.
    """

    n: int
    mean: float
    s: float
    cp: float
    cpk: float
    out_of_tolerance: int
    cg: float
    cgk: float
    lower: float
    upper: float
    reference: float | None = None

    @property
    def capable(self) -> bool:
        """The gauge's Cg and Cgk both at least :data:`CG_MIN`."""
        return self.cg >= CG_MIN and self.cgk >= CG_MIN

    def to_json(self) -> dict[str, Any]:
        def num(v: float) -> float | None:
            return None if math.isnan(v) else float(v)

        return {"n": self.n, "mean": num(self.mean), "s": num(self.s), "cp": num(self.cp), "cpk": num(self.cpk),
                "out_of_tolerance": self.out_of_tolerance, "cg": num(self.cg), "cgk": num(self.cgk),
                "lower": self.lower, "upper": self.upper, "reference": self.reference}


def _ratio(num: float, den: float) -> float:
    if den > 0:
        return num / den
    return math.inf if num > 0 else -math.inf if num < 0 else math.nan


def capability(values: Iterable[float | None] | np.ndarray, lower: float, upper: float, reference: float | None = None, *,
               k: float = 0.2, spread: float = 6.0) -> Capability:
    """SPC and type-1 figures of ``values`` against the absolute limits ``[lower, upper]``.

    Parameters
    ----------
    values : (N,) float
        Measured values (None and non-finite ones are left out: a characteristic not
        measurable on a part has no value).
    lower, upper : float
        Specification limits (absolute), ``upper > lower``.
    reference : float, optional
        The true value (type-1 study); without it Cg and Cgk are nan.
    k, spread : float
        Share of the tolerance the gauge may use and the spread, in standard deviations,
        that stands for it (0.2 and 6: VDA 5).

    Returns
    -------
    Capability
    """
    lo, hi = float(lower), float(upper)
    if not hi > lo:
        raise ValueError(f"the limits must have upper > lower, got [{lower}, {upper}]")
    v = np.array([x for x in values if x is not None], float).ravel()
    v = v[np.isfinite(v)]
    n = len(v)
    out = int(np.sum((v < lo) | (v > hi)))
    if n == 0:
        return Capability(0, math.nan, math.nan, math.nan, math.nan, 0, math.nan, math.nan, lo, hi, reference)
    mean = float(v.mean())
    if n < 2:
        return Capability(n, mean, math.nan, math.nan, math.nan, out, math.nan, math.nan, lo, hi, reference)
    s = float(v.std(ddof=1))
    T = hi - lo
    cp = _ratio(T, spread * s)
    cpk = _ratio(min(hi - mean, mean - lo), spread * s / 2)
    cg = cgk = math.nan
    if reference is not None:
        cg = _ratio(k * T, spread * s)
        cgk = _ratio(k * T / 2 - abs(mean - float(reference)), spread * s / 2)
    return Capability(n, mean, s, cp, cpk, out, cg, cgk, lo, hi, None if reference is None else float(reference))


def capable_tolerance(values: Iterable[float | None] | np.ndarray, reference: float, *, cg_min: float = CG_MIN,
                      k: float = 0.2, spread: float = 6.0) -> float:
    """The smallest tolerance width ``T`` for which a type-1 study of ``values`` is capable
    (Cg and Cgk at least ``cg_min``): ``T = max(cg_min L s / k, (cg_min L s / 2 + |bias|) 2 / k)``
    -- the second (Cgk) binds whenever there is a bias. nan with fewer than two values."""
    v = np.array([x for x in values if x is not None], float).ravel()
    v = v[np.isfinite(v)]
    if len(v) < 2:
        return math.nan
    s = float(v.std(ddof=1))
    bias = abs(float(v.mean()) - float(reference))
    return max(cg_min * spread * s / k, (cg_min * spread * s / 2 + bias) * 2 / k)


def series(results: Sequence[Sequence[Mapping[str, Any]]]) -> dict[str, list[float | None]]:
    """Per characteristic id (in first-seen order), its measured value on each part (None:
    not measurable there, or not measured).

    ``results``: each part's characteristics rows (``result.json`` ``extras.characteristics``,
    or what the history keeps), in the parts' order."""
    ids: dict[str, None] = {}
    for rows in results:
        for r in rows:
            ids.setdefault(str(r["id"]), None)
    out: dict[str, list[float | None]] = {cid: [] for cid in ids}
    for rows in results:
        got = {str(r["id"]): r for r in rows}
        for cid in ids:
            row = got.get(cid)
            out[cid].append(None if row is None or row.get("measured") is None else float(row["measured"]))
    return out


def table(results: Sequence[Sequence[Mapping[str, Any]]]) -> list[dict[str, Any]]:
    """Per characteristic (in first-seen order): id, kind, unit, nominal, absolute limits and
    :func:`capability` of its values over ``results`` (each part's rows), with Cg/Cgk
    against the nominal as reference (a study on a master part whose value is the
    nominal; pass the true value to :func:`capability` otherwise)."""
    out = []
    values = series(results)
    first: dict[str, Mapping[str, Any]] = {}
    for rows in results:
        for r in rows:
            first.setdefault(str(r["id"]), r)
    for cid, vals in values.items():
        r = first[cid]
        nom = float(r["nominal"])
        cap = capability(vals, nom + float(r["lower"]), nom + float(r["upper"]), reference=nom)
        out.append({"id": cid, "kind": r.get("kind"), "unit": r.get("unit", "mm"), "nominal": nom,
                    "not_measurable": sum(v is None for v in vals), **cap.to_json()})
    return out
