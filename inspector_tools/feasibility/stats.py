"""The statistics of a feasibility study, on plain arrays.

* observability: per surface element, the share of poses in which a BCPS point lands on
  it, and the error of those points (mean, p95);
* probability of detection from hit/miss data (MIL-HDBK-1823A, section 5 and appendix G):
  ``logit(POD(a)) = b0 + b1 ln a`` fitted by maximum likelihood (a binomial GLM), its
  one-sided 95 % lower confidence bound (Wald, on the linear predictor), and the sizes
  a50, a90 and a90/95;
* a type-1 gauge study (capability of the measurement against a tolerance, ``Cg``, ``Cgk``);
* binomial bounds (false-reject rates from a few dozen parts).

Pure functions of numpy arrays: no file, mesh or plugin (an import-linter contract checks
it). ``statsmodels`` is imported by :func:`pod_fit` only.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

__all__ = [
    "CG_MIN",
    "Z95",
    "PodFit",
    "pod_fit",
    "Gauge",
    "gauge_type1",
    "observed_fraction",
    "grouped_mean_quantile",
    "binomial_upper",
    "majority_share",
]

#: Capability a type-1 gauge study asks of Cg and Cgk (VDA 5, Bosch booklet 10).
CG_MIN = 1.33

#: One-sided 95 % standard normal quantile.
Z95 = 1.6448536269514722

#: Hits of as many defects, all found, that show POD >= 0.9 with 95 % confidence
#: (0.9 ** 29 < 0.05: the "29 of 29" demonstration of MIL-HDBK-1823A).
N_29 = 29

_LOGIT90 = math.log(0.9 / 0.1)


# --------------------------------------------------------------------------- POD


@dataclass(frozen=True)
class PodFit:
    """A hit/miss probability-of-detection model, ``logit POD(a) = b0 + b1 ln a``.

    Attributes
    ----------
    n, hits : int
        Defects judged, and how many were found.
    a_min, a_max : float
        Smallest and largest size tested, mm (nan without data).
    b0, b1 : float or None
        Intercept and slope (per unit of ln a); None when not fitted.
    cov : (2, 2) tuple or None
        Their covariance (the inverse Fisher information).
    a50, a90 : float or None
        Sizes (mm) at which the fitted POD is 0.5 and 0.9.
    a90_95 : float or None
        Size (mm) at which the one-sided 95 % lower confidence bound of POD reaches 0.9;
        None when it never does.
    status : str
        ``"fit"`` (the model was fitted), ``"29/29"`` (the sizes separate hits from misses,
        so no curve can be fitted; a90/95 is the smallest size from which at least 29
        defects were all found), or why nothing could be said: ``"no-data"``,
        ``"all-missed"``, ``"separated"`` (as ``"29/29"`` with fewer than 29 hits),
        ``"flat"`` (POD does not rise with size).
    note : str
        The status in words.
    """

    n: int
    hits: int
    a_min: float
    a_max: float
    b0: float | None = None
    b1: float | None = None
    cov: tuple[tuple[float, float], tuple[float, float]] | None = None
    a50: float | None = None
    a90: float | None = None
    a90_95: float | None = None
    status: str = "no-data"
    note: str = ""

    @property
    def extrapolated(self) -> bool:
        """a90/95 lies beyond the largest size tested (MIL-HDBK-1823A: do not extrapolate)."""
        return self.a90_95 is not None and self.a90_95 > self.a_max * (1 + 1e-9)

    def pod(self, a: np.ndarray) -> np.ndarray:
        """Fitted POD at sizes ``a`` (mm, any shape); nan when not fitted."""
        a = np.asarray(a, float)
        if self.b0 is None or self.b1 is None:
            return np.full(a.shape, np.nan)
        return _expit(self.b0 + self.b1 * np.log(a))

    def lower(self, a: np.ndarray, z: float = Z95) -> np.ndarray:
        """One-sided lower confidence bound of POD at sizes ``a`` (mm): the Wald bound
        ``b0 + b1 x - z sqrt(var)`` of the linear predictor, ``x = ln a``, through the logistic."""
        a = np.asarray(a, float)
        if self.b0 is None or self.b1 is None or self.cov is None:
            return np.full(a.shape, np.nan)
        x = np.log(a)
        (v00, v01), (_, v11) = self.cov
        sd = np.sqrt(np.maximum(v00 + 2 * v01 * x + v11 * x * x, 0.0))
        return _expit(self.b0 + self.b1 * x - z * sd)

    def to_json(self) -> dict:
        return {k: getattr(self, k) for k in ("n", "hits", "a_min", "a_max", "b0", "b1", "cov", "a50", "a90", "a90_95",
                                               "status", "note")} | {"extrapolated": self.extrapolated}


def _expit(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * np.asarray(x, float)))


def _a90_95(b0: float, b1: float, cov: np.ndarray, z: float) -> float | None:
    """Size where ``b0 + b1 x - z sqrt(v00 + 2 v01 x + v11 x^2) = logit 0.9``, ``x = ln a``
    (the larger root of the squared equation on the side where the bound rises)."""
    c = b0 - _LOGIT90
    v00, v01, v11 = float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])
    qa = b1 * b1 - z * z * v11
    qb = 2.0 * (b1 * c - z * z * v01)
    qc = c * c - z * z * v00
    if qa <= 0:  # the slope is not significant: the bound never reaches 0.9
        return None
    disc = qb * qb - 4 * qa * qc
    if disc < 0:
        return None
    roots = sorted(((-qb - math.sqrt(disc)) / (2 * qa), (-qb + math.sqrt(disc)) / (2 * qa)))
    for x in reversed(roots):
        if b1 * x + c >= -1e-9:  # b0 + b1 x >= logit 0.9: the root of the unsquared equation
            return math.exp(x)
    return None


def _separation(a: np.ndarray, hit: np.ndarray) -> PodFit | None:
    """The fit when the sizes separate the hits from the misses (no finite MLE), else None."""
    largest_miss = a[~hit].max() if (~hit).any() else -np.inf
    smallest_hit = a[hit].min()
    if largest_miss >= smallest_hit:
        return None
    n, hits = len(a), int(hit.sum())
    above = np.sort(a[hit])  # every defect above the largest miss was found
    base = PodFit(n=n, hits=hits, a_min=float(a.min()), a_max=float(a.max()))
    if len(above) >= N_29:
        a9095 = float(above[-N_29])  # the 29 largest were all found
        return replace(base, a90_95=a9095, status="29/29",
                       note=f"every defect of {smallest_hit:.3g} mm or more was found, every smaller one missed: no curve "
                            f"can be fitted; the {N_29} largest ({a9095:.3g} mm and up) were all found, which shows "
                            "POD >= 0.9 with 95 % confidence")
    return replace(base, status="separated",
                   note=f"every defect of {smallest_hit:.3g} mm or more was found ({hits}), every smaller one missed: "
                        f"no curve can be fitted, and fewer than {N_29} hits show nothing at 95 % confidence")


def pod_fit(sizes: np.ndarray, hits: np.ndarray, *, z: float = Z95) -> PodFit:
    """Fit the hit/miss POD model of MIL-HDBK-1823A to defects of known size.

    Parameters
    ----------
    sizes : (N,) float
        Defect sizes, mm, > 0 (here the radius of a spherical dent or bump: its depth or
        height on a flat face).
    hits : (N,) bool
        Whether each defect was found.
    z : float
        Normal quantile of the one-sided lower bound (1.645: 95 %).

    Returns
    -------
    PodFit
        The logit model on ln(size) fitted by a binomial GLM (statsmodels), with a50, a90 and
        a90/95; or, when the data do not allow a fit (none found, the sizes separate hits
        from misses, POD falling with size), the reason, and a90/95 by the 29-of-29 rule
        where it applies.
    """
    a = np.asarray(sizes, float).ravel()
    hit = np.asarray(hits, bool).ravel()
    if a.shape != hit.shape:
        raise ValueError(f"sizes and hits differ in length: {a.shape} and {hit.shape}")
    if np.any(~np.isfinite(a)) or np.any(a <= 0):
        raise ValueError("sizes must be finite and > 0 (mm)")
    n, k = len(a), int(hit.sum())
    base = PodFit(n=n, hits=k, a_min=float(a.min()) if n else math.nan, a_max=float(a.max()) if n else math.nan)
    if n == 0:
        return replace(base, status="no-data", note="no defect was placed here")
    if k == 0:
        return replace(base, status="all-missed", note=f"none of the {n} defects up to {a.max():.3g} mm was found")
    sep = _separation(a, hit)
    if sep is not None:
        return sep
    import statsmodels.api as sm
    from statsmodels.tools.sm_exceptions import PerfectSeparationWarning

    x = np.log(a)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PerfectSeparationWarning)
        warnings.simplefilter("ignore", RuntimeWarning)
        res = sm.GLM(hit.astype(float), sm.add_constant(x, has_constant="add"), family=sm.families.Binomial()).fit()
    b0, b1 = (float(v) for v in res.params)
    cov = np.asarray(res.cov_params(), float)
    if not (np.all(np.isfinite(cov)) and math.isfinite(b0) and math.isfinite(b1)):
        return replace(base, status="separated", note="the fit does not converge: too few sizes near the threshold")
    fitted = replace(base, b0=b0, b1=b1, cov=((float(cov[0, 0]), float(cov[0, 1])), (float(cov[1, 0]), float(cov[1, 1]))))
    if b1 <= 0:
        return replace(fitted, status="flat", note=f"POD does not rise with size ({k} of {n} found at every size alike)")
    a50 = math.exp(-b0 / b1)
    a90 = math.exp((_LOGIT90 - b0) / b1)
    a9095 = _a90_95(b0, b1, cov, z)
    note = "fitted" if a9095 is not None else "the lower 95 % bound never reaches POD 0.9"
    return replace(fitted, a50=a50, a90=a90, a90_95=a9095, status="fit", note=note)


# --------------------------------------------------------------------------- gauge study


@dataclass(frozen=True)
class Gauge:
    """A type-1 gauge study of one characteristic against its tolerance.

    Attributes
    ----------
    n : int
        Measurements.
    mean, s : float
        Their mean and standard deviation, mm.
    bias : float
        ``mean - reference``, mm.
    tolerance : float
        ``T = upper - lower``, mm.
    cg, cgk : float
        ``Cg = k T / (L s)`` and ``Cgk = (k T / 2 - |bias|) / (L s / 2)``, with k = 0.2 and
        L = 6 (inf when s = 0; nan without measurements).
    """

    n: int
    mean: float
    s: float
    bias: float
    tolerance: float
    cg: float
    cgk: float

    @property
    def capable(self) -> bool:
        """Cg and Cgk both at least :data:`CG_MIN`."""
        return self.cg >= CG_MIN and self.cgk >= CG_MIN

    def to_json(self) -> dict:
        return {k: getattr(self, k) for k in ("n", "mean", "s", "bias", "tolerance", "cg", "cgk")} | {"capable": self.capable}


def gauge_type1(values: np.ndarray, lower: float, upper: float, reference: float = 0.0, *, k: float = 0.2,
                spread: float = 6.0) -> Gauge:
    """Type-1 gauge study (VDA 5 / Bosch booklet 10): repeated measurements of a reference
    whose true value is known.

    Parameters
    ----------
    values : (N,) float
        Measured values, mm (here: the signed deviation of each BCPS point of a region, in
        every capture of the nominal part, whose true deviation is 0).
    lower, upper : float
        Tolerance limits, mm; ``T = upper - lower``.
    reference : float
        The true value, mm.
    k, spread : float
        Share of the tolerance the gauge may use (0.2) and the spread that stands for it,
        in standard deviations (6).

    Returns
    -------
    Gauge
    """
    v = np.asarray(values, float).ravel()
    v = v[np.isfinite(v)]
    T = float(upper) - float(lower)
    if T <= 0:
        raise ValueError(f"tolerance must be upper > lower, got [{lower}, {upper}]")
    if len(v) < 2:
        return Gauge(len(v), math.nan, math.nan, math.nan, T, math.nan, math.nan)
    mean, s = float(v.mean()), float(v.std(ddof=1))
    bias = mean - float(reference)
    if s == 0:
        return Gauge(len(v), mean, s, bias, T, math.inf, math.inf if abs(bias) < k * T / 2 else -math.inf)
    return Gauge(len(v), mean, s, bias, T, k * T / (spread * s), (k * T / 2 - abs(bias)) / (spread * s / 2))


# --------------------------------------------------------------------------- observability


def observed_fraction(element_ids: Sequence[np.ndarray], n_elements: int) -> np.ndarray:
    """Share of poses in which at least one point lands on each element.

    Parameters
    ----------
    element_ids : sequence of (M_i,) int
        For each pose, the element of each of its points (repeats allowed).
    n_elements : int

    Returns
    -------
    (n_elements,) float
        In [0, 1]; zeros when there is no pose.
    """
    counts = np.zeros(int(n_elements), np.int64)
    for ids in element_ids:
        counts[np.unique(np.asarray(ids, np.int64))] += 1
    return counts / len(element_ids) if len(element_ids) else counts.astype(float)


def grouped_mean_quantile(ids: np.ndarray, values: np.ndarray, n_groups: int, q: float = 95.0
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean and ``q``-th percentile (linear interpolation, as ``numpy.percentile``) of
    ``values`` per group.

    Parameters
    ----------
    ids : (N,) int
        Group of each value, in ``[0, n_groups)``.
    values : (N,) float
    n_groups : int
    q : float
        Percentile, 0..100.

    Returns
    -------
    mean, quantile : (n_groups,) float
        nan for an empty group.
    count : (n_groups,) int
    """
    ids = np.asarray(ids, np.int64).ravel()
    v = np.asarray(values, float).ravel()
    count = np.bincount(ids, minlength=n_groups)[:n_groups]
    total = np.bincount(ids, weights=v, minlength=n_groups)[:n_groups]
    mean = np.full(n_groups, np.nan)
    nz = count > 0
    mean[nz] = total[nz] / count[nz]
    quant = np.full(n_groups, np.nan)
    if len(v):
        order = np.lexsort((v, ids))
        sv = v[order]
        start = np.concatenate([[0], np.cumsum(count)[:-1]])
        g = np.flatnonzero(nz)
        pos = start[g] + (count[g] - 1) * (q / 100.0)
        lo = np.floor(pos).astype(np.int64)
        hi = np.minimum(lo + 1, start[g] + count[g] - 1)
        quant[g] = sv[lo] + (sv[hi] - sv[lo]) * (pos - lo)
    return mean, quant, count


# --------------------------------------------------------------------------- rates


def binomial_upper(k: int, n: int, confidence: float = 0.95) -> float:
    """One-sided upper confidence bound of a rate seen ``k`` times in ``n`` trials
    (Clopper-Pearson); 1.0 when ``n`` is 0."""
    if n <= 0:
        return 1.0
    if k >= n:
        return 1.0
    from scipy.special import betaincinv  # the Beta(k + 1, n - k) quantile (scipy.stats takes seconds to import)

    return float(betaincinv(k + 1, n - k, confidence))


def majority_share(labels: Sequence[str]) -> tuple[str | None, float]:
    """The most frequent label and the share of the labels equal to it (repeatability of a
    verdict over repeated captures); ``(None, nan)`` without labels."""
    if not len(labels):
        return None, math.nan
    values, counts = np.unique(np.asarray(labels, dtype=object).astype(str), return_counts=True)
    i = int(np.argmax(counts))
    return str(values[i]), float(counts[i] / len(labels))
