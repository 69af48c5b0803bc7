"""Characteristics of one inspection: definitions, their check against the reference's
features, and their measurement from the BCPS points with a standard uncertainty.

A :class:`Characteristic` is what a drawing's balloon says: ``id`` (the balloon number),
``kind``, the feature(s) it applies to, the limits as deviations from the nominal (mm, or
degrees for an angle), an optional nominal (default: the CAD's) and a criticality.

:func:`measure` takes the BCPS points in the reference frame and their relative weights (the
bcps stage's per-point confidence, :func:`inspector.kernels.bcps.confidence`):

1. each point belongs to the feature that owns its nearest reference triangle, when it lies
   within ``band_mm`` of it (:meth:`inspector.reference.Reference.distance` ``.closest``);
2. each feature a characteristic needs is fitted (:mod:`inspector.kernels.fits`, the CAD
   nominal as the start), with a robust trim (points beyond 3.5 robust standard deviations
   of the fit are left out, twice: an edge point of the neighbouring face, a defect);
3. the characteristic's value follows from the fit(s), its standard uncertainty ``u`` by
   propagation of the fits' covariances, ``U = 2 u`` (k = 2). Form characteristics
   (flatness, roundness, cylindricity) are minimum-zone widths; their ``u`` is the points'
   residual standard deviation (the zone of N noisy points is wider than the form by a few
   ``s``: the value is an upper bound of the form).

Verdicts: ``ok`` when ``lower <= deviation <= upper``, ``nok`` otherwise, and
``not_measurable`` with the reason -- never a value -- when the feature has too few points,
when its fit is ill-posed (a short arc, a plane seen along one line: :attr:`Fit.problem`),
or when ``U`` exceeds ``max_u_fraction`` of the tolerance width (the measurement cannot
decide).

Positions are in the reference frame as placed by the alignment (the part's best-fit frame):
``position`` is the diameter of the smallest zone around the nominal axis (or centre) that
holds the measured one, i.e. twice the largest distance between them (ISO 1101).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from inspector.characteristics.edges import EdgeSnap, PlaneEdge, replica_planes, snap_to_edges
from inspector.errors import RecipeError
from inspector.kernels import fits
from inspector.kernels.features import Feature

__all__ = [
    "CRITICALITY",
    "KINDS",
    "Characteristic",
    "CharacteristicResult",
    "assign_points",
    "measure",
    "unit_of",
]

#: Characteristic kinds and the feature kinds each accepts (per feature position).
KINDS: dict[str, tuple[str, ...]] = {
    "diameter": ("cylinder", "sphere"),
    "radius": ("cylinder", "sphere", "torus"),  # a torus's: its tube's (a fillet's radius)
    "distance": ("plane", "cylinder", "cone", "sphere"),
    "angle": ("plane", "cylinder", "cone"),
    "position": ("cylinder", "cone", "sphere", "torus"),  # a torus's: its centre's, as a sphere's
    "flatness": ("plane",),
    "roundness": ("cylinder", "cone"),
    "cylindricity": ("cylinder",),
}
#: How many features each kind takes.
ARITY = {"diameter": 1, "radius": 1, "distance": 2, "angle": 2, "position": 1, "flatness": 1, "roundness": 1,
         "cylindricity": 1}
#: Form characteristics: nominal 0, the value is a zone width.
FORM = ("flatness", "roundness", "cylindricity", "position")
CRITICALITY = ("minor", "major", "critical", "key")
#: Two planes or axes closer than this to parallel (degrees) have a distance.
PARALLEL_DEG = 1.0
#: Points a fit needs beyond its parameter count.
MIN_POINTS = {"plane": 10, "cylinder": 20, "cone": 24, "sphere": 16, "torus": 28}


def unit_of(kind: str) -> str:
    """``deg`` for an angle, ``mm`` for every other kind."""
    return "deg" if kind == "angle" else "mm"


@dataclass(frozen=True)
class Characteristic:
    """One characteristic of the drawing.

    Attributes
    ----------
    id : str
        The balloon number (unique in a recipe).
    kind : str
        One of :data:`KINDS`.
    features : tuple of str
        Feature ids (``F01`` ...), one or two (distance, angle).
    lower, upper : float
        Limits of the deviation from the nominal, mm (degrees for an angle); form and
        position: limits of the value (lower usually 0).
    nominal : float or None
        The nominal value; None: from the CAD (0 for form and position).
    criticality : str
        One of :data:`CRITICALITY`.
    description : str
        Free text (the DFQ's K2002; default: kind and features).
    """

    id: str
    kind: str
    features: tuple[str, ...]
    lower: float
    upper: float
    nominal: float | None = None
    criticality: str = "major"
    description: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "features", tuple(str(f) for f in self.features))
        where = f"characteristic {self.id!r}"
        if not str(self.id).strip():
            raise RecipeError("characteristic: empty id")
        if self.kind not in KINDS:
            raise RecipeError(f"{where}: unknown kind {self.kind!r} (expected {', '.join(KINDS)})")
        if self.criticality not in CRITICALITY:
            raise RecipeError(f"{where}: unknown criticality {self.criticality!r} (expected {', '.join(CRITICALITY)})")
        n = ARITY[self.kind]
        if len(self.features) != n:
            raise RecipeError(f"{where}: a {self.kind} names {n} feature{'s' if n > 1 else ''}, got "
                              f"{len(self.features) or 'none'}")
        for name, v in (("lower", self.lower), ("upper", self.upper)) + ((("nominal", self.nominal),) if self.nominal is not None else ()):
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                raise RecipeError(f"{where}: {name} must be a finite number, got {v!r}")
        if self.lower > self.upper:
            raise RecipeError(f"{where}: lower {self.lower} is above upper {self.upper}")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "characteristics") -> Characteristic:
        """From a recipe's ``[[characteristics]]`` table (``feature`` or ``features``: an id or a
        list); one-line :class:`RecipeError` naming ``where`` on a bad key."""
        allowed = {"id", "kind", "feature", "features", "lower", "upper", "nominal", "criticality", "description"}
        extra = sorted(set(d) - allowed)
        if extra:
            raise RecipeError(f"{where}: unknown key {extra[0]!r} (expected {', '.join(sorted(allowed))})")
        for key in ("id", "kind", "lower", "upper"):
            if key not in d:
                raise RecipeError(f"{where}: missing key {key!r}")
        feats = d.get("features", d.get("feature", ()))
        if isinstance(feats, str):
            feats = (feats,)
        if not isinstance(feats, (list, tuple)) or not all(isinstance(f, str) for f in feats):
            raise RecipeError(f"{where}: feature(s) must be an id or a list of ids, got {feats!r}")
        try:
            return cls(str(d["id"]), str(d["kind"]), tuple(feats), d["lower"], d["upper"], d.get("nominal"),
                       str(d.get("criticality", "major")), str(d.get("description", "")))
        except RecipeError as e:
            raise RecipeError(f"{where}: {e}") from None

    @property
    def unit(self) -> str:
        return unit_of(self.kind)

    @property
    def label(self) -> str:
        """The description, or ``kind F01[-F02]``."""
        return self.description or f"{self.kind} {'-'.join(self.features)}"

    def validate(self, features: Sequence[Feature] | Mapping[str, Feature]) -> None:
        """Raise :class:`RecipeError` (one line) unless the characteristic applies to ``features``:
        every id exists, each feature is of a kind the characteristic accepts, two planes or axes
        whose distance is asked are parallel, an angle is between features with directions."""
        by_id = _by_id(features)
        where = f"characteristic {self.id!r}"
        got = []
        for fid in self.features:
            if fid not in by_id:
                known = sorted(by_id)
                span = f"{known[0]}..{known[-1]}" if known else "none"
                raise RecipeError(f"{where}: feature {fid!r} does not exist in the reference (features {span}; "
                                  "`inspector features REFERENCE` lists them)")
            f = by_id[fid]
            if f.kind not in KINDS[self.kind]:
                raise RecipeError(f"{where}: a {self.kind} of a {f.kind} ({fid}) is not defined (a {self.kind} applies "
                                  f"to: {', '.join(KINDS[self.kind])})")
            got.append(f)
        if self.kind == "distance":
            a, b = got
            if a.id == b.id:
                raise RecipeError(f"{where}: a distance between {a.id} and itself")
            da, db = a.direction, b.direction
            if da is not None and db is not None:
                ang = math.degrees(math.acos(min(1.0, abs(float(da @ db)))))
                planes = (a.kind == "plane") + (b.kind == "plane")
                if planes == 1:  # an axis and a plane: the axis must lie along the plane
                    ang = abs(90.0 - ang)
                    if ang > PARALLEL_DEG:
                        raise RecipeError(f"{where}: a distance between the plane and the axis of {a.id} and {b.id}, "
                                          f"which is not parallel to it ({ang:.1f} deg off)")
                elif ang > PARALLEL_DEG:
                    what = "planes" if planes == 2 else "axes"
                    raise RecipeError(f"{where}: a distance between non-parallel {what} {a.id} and {b.id} "
                                      f"({ang:.1f} deg apart; at most {PARALLEL_DEG:g})")
        if self.kind == "angle" and got[0].id == got[1].id:
            raise RecipeError(f"{where}: an angle between {got[0].id} and itself")

    def nominal_value(self, features: Sequence[Feature] | Mapping[str, Feature]) -> float:
        """The nominal: given, else from the CAD features (0 for form and position)."""
        if self.nominal is not None:
            return float(self.nominal)
        if self.kind in FORM:
            return 0.0
        by_id = _by_id(features)
        geo = [_nominal_geometry(by_id[f]) for f in self.features]
        if self.kind == "diameter":
            return 2.0 * float(geo[0]["radius"])
        if self.kind == "radius":
            return float(geo[0]["minor_radius" if geo[0]["kind"] == "torus" else "radius"])
        if self.kind == "distance":
            return fits.geometric_distance(geo[0], geo[1])
        if self.kind == "angle":
            return _angle(geo[0], geo[1])
        raise AssertionError(self.kind)  # pragma: no cover


@dataclass(frozen=True)
class CharacteristicResult:
    """One measured characteristic (``result.json`` ``characteristics``).

    ``measured``, ``deviation``, ``u`` and ``U`` are None when not measurable.
    """

    id: str
    kind: str
    features: tuple[str, ...]
    nominal: float
    measured: float | None
    deviation: float | None
    lower: float
    upper: float
    u: float | None
    U: float | None
    points: int
    verdict: str
    reason: str = ""

    def to_json(self) -> dict[str, Any]:
        def num(v: float | None) -> float | None:
            return None if v is None or not math.isfinite(v) else float(v)

        return {"id": self.id, "kind": self.kind, "features": list(self.features), "nominal": float(self.nominal),
                "measured": num(self.measured), "deviation": num(self.deviation), "lower": float(self.lower),
                "upper": float(self.upper), "u": num(self.u), "U": num(self.U), "points": int(self.points),
                "verdict": self.verdict, "reason": self.reason}

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> CharacteristicResult:
        return cls(str(d["id"]), str(d["kind"]), tuple(d["features"]), float(d["nominal"]), d.get("measured"),
                   d.get("deviation"), float(d["lower"]), float(d["upper"]), d.get("u"), d.get("U"), int(d.get("points", 0)),
                   str(d["verdict"]), str(d.get("reason", "")))


def _by_id(features: Sequence[Feature] | Mapping[str, Feature]) -> Mapping[str, Feature]:
    return features if isinstance(features, Mapping) else {f.id: f for f in features}


def _nominal_geometry(f: Feature) -> dict[str, Any]:
    g: dict[str, Any] = {"kind": f.kind}
    for k, v in f.nominal.items():
        g[k] = np.asarray(v, float) if isinstance(v, (tuple, list)) else v
    if f.kind == "cone":
        g["point"] = g["apex"]
    return g


def _angle(ga: dict[str, Any], gb: dict[str, Any]) -> float:
    c = abs(float(fits.direction_of(ga) @ fits.direction_of(gb)))
    ang = math.degrees(math.acos(min(1.0, c)))
    return 90.0 - ang if (ga["kind"] == "plane") != (gb["kind"] == "plane") else ang


# --------------------------------------------------------------------------- measurement


def assign_points(points_ref: np.ndarray, features: Sequence[Feature], reference: Any, band_mm: float) -> np.ndarray:
    """Index of the feature each point belongs to, -1 for none.

    Parameters
    ----------
    points_ref : (N, 3) float
        Reference frame, mm.
    features : sequence of Feature
    reference : Reference
        Anything with ``vertices``, ``faces`` and ``distance.closest(points, parallel=False) -> (closest
        (N, 3), triangle (N,))``.
    band_mm : float
        Farthest a point may be from its nearest reference triangle, mm.

    Returns
    -------
    (N,) int
        Position in ``features``, or -1 (beyond the band, or on a triangle of no feature).
    """
    return _assigned(points_ref, features, reference, band_mm)[0]


def _assigned(points_ref: np.ndarray, features: Sequence[Feature], reference: Any,
              band_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`assign_points`, and each point's nearest reference triangle (N,) (-1: none)."""
    P = np.asarray(points_ref, float).reshape(-1, 3)
    out = np.full(len(P), -1, np.int64)
    if len(P) == 0 or not len(features):
        return out, out.copy()
    # Every point is asked: the compiled closest-point query costs about 0.2 us a point, less
    # than a numpy pre-selection by the features' boxes did (measured: 3 ms against 13 ms for
    # 15000 points and 11 features). On one thread: see meshdist.closest_query_serial.
    q, tid = reference.distance.closest(P, parallel=False)
    got = _owner(tid, features, len(reference.faces))
    d = P - q
    got[~(np.einsum("ij,ij->i", d, d) <= band_mm * band_mm)] = -1  # NaN (no closest point): not <=
    return got, np.asarray(tid, np.int64)


def _owner(tid: np.ndarray, features: Sequence[Feature], faces: int) -> np.ndarray:
    """The position in ``features`` of the feature owning each triangle ``tid`` (-1: none)."""
    owner = np.full(faces, -1, np.int64)
    for k, f in enumerate(features):
        owner[f.faces] = k
    return np.where(tid >= 0, owner[np.clip(tid, 0, None)], -1)


def _robust_fit(f: Feature, P: np.ndarray, w: np.ndarray) -> tuple[fits.Fit, np.ndarray]:
    """The feature's primitive fitted to ``P`` with the CAD nominal as start; points beyond 3.5
    robust standard deviations are left out (twice). Returns the fit and the kept mask."""
    keep = np.ones(len(P), bool)
    fit = _fit_kind(f, P, w)
    for _ in range(2):
        if not fit.params or not np.isfinite(fit.s):
            break
        r = fit.residuals
        mad = 1.4826 * float(np.median(np.abs(r - np.median(r))))
        cut = max(3.5 * mad, 1e-4)
        new = np.abs(r) <= cut
        if new.all():
            break
        idx = np.flatnonzero(keep)
        keep[idx[~new]] = False
        # Re-fit from the fit just made: the trim moves it by microns, so it settles in a
        # step or two instead of the dozen from the CAD nominal.
        fit = _fit_kind(f, P[keep], w[keep], start=fit.params)
    return fit, keep


def _fit_kind(f: Feature, P: np.ndarray, w: np.ndarray, start: Mapping[str, Any] | None = None) -> fits.Fit:
    """The feature's primitive fitted to ``P``; the start is ``start`` (an earlier fit's
    params) when given, else the CAD nominal."""
    nm: Mapping[str, Any] = f.nominal
    if start and f.kind == "cylinder":
        nm = {"direction": start["direction"], "point": start["point"], "radius": start["radius"]}
    elif start and f.kind == "cone":
        nm = {"axis": start["axis"], "apex": start["apex"], "half_angle_deg": start["half_angle_deg"]}
    elif start and f.kind == "torus":
        nm = {k: start[k] for k in ("centre", "axis", "major_radius", "minor_radius")}
    m = MIN_POINTS[f.kind]
    if f.kind == "plane":
        return _oriented(fits.fit_plane(P, w, min_points=m), np.asarray(nm["normal"]))  # outward, as the CAD's
    if f.kind == "cylinder":
        return fits.fit_cylinder(P, w, axis=np.asarray(nm["direction"]), point=np.asarray(nm["point"]),
                                 radius=float(nm["radius"]), min_points=m)
    if f.kind == "cone":
        return fits.fit_cone(P, w, axis=np.asarray(nm["axis"]), apex=np.asarray(nm["apex"]),
                             half_angle_deg=float(nm["half_angle_deg"]), min_points=m)
    if f.kind == "sphere":
        return fits.fit_sphere(P, w, min_points=m)
    if f.kind == "torus":
        return fits.fit_torus(P, w, axis=np.asarray(nm["axis"]), centre=np.asarray(nm["centre"]),
                              major_radius=float(nm["major_radius"]), minor_radius=float(nm["minor_radius"]), min_points=m)
    raise ValueError(f"{f.id}: cannot fit a {f.kind}")


def measure(characteristics: Sequence[Characteristic], features: Sequence[Feature], points_ref: np.ndarray,
            weights: np.ndarray | None, reference: Any, *, band_mm: float = 0.5, max_u_fraction: float = 0.5,
            slice_mm: float | None = None, u_surface_mm: float = 0.0,
            groups: np.ndarray | None = None, origins: np.ndarray | None = None,
            edges: Sequence[PlaneEdge] = ()) -> list[CharacteristicResult]:
    """Measure characteristics from one inspection's points.

    Parameters
    ----------
    characteristics : sequence of Characteristic
        Validated against ``features`` (:meth:`Characteristic.validate`; raises RecipeError).
    features : sequence of Feature
        The reference's features (:func:`inspector.kernels.features.find_features`).
    points_ref : (N, 3) float
        BCPS points in the reference frame (``Reference.to_reference_frame(points, pose)``), mm.
    weights : (N,) float or None
        Relative weights in [0, 1] (the bcps per-point confidence); None: all 1.
    reference : Reference
        The reference mesh the features were found on (its closest-point query).
    band_mm : float
        A point farther than this from the reference belongs to no feature, mm.
    max_u_fraction : float
        ``U`` above this fraction of the tolerance width (``upper - lower``): not measurable.
    slice_mm : float, optional
        Roundness: thickness of the cross-sections along the axis (default: a fifth of the
        feature's length, at least 0.5 mm).
    u_surface_mm : float
        Standard uncertainty of an offset of the whole part's surface common to all its
        points (the silhouettes' edge placement), mm; added in quadrature to each size
        characteristic's ``u`` times its sensitivity (:func:`offset_sensitivity`: 2 for a
        diameter or a thickness, 0 for a step, an axis distance, an angle or a form).
    groups : (N,) int, optional
        The source of each point (the camera whose contour gave it): each feature's fit
        covariance is scaled by the points' design effect over these groups
        (:func:`inspector.kernels.fits.grouped`), so points that err together are not
        counted as independent. None: every point independent.
    origins : (N, 3) float, optional
        The centre of the camera whose contour ray gave each point (reference frame, mm):
        with ``edges``, the points near a sharp edge between two planes are moved along their
        rays onto the edge the rays show, and belong to both planes
        (:func:`inspector.characteristics.edges.snap_to_edges`).
    edges : sequence of PlaneEdge
        The reference's convex edges between planes
        (:func:`inspector.characteristics.edges.plane_edges`).

    Returns
    -------
    list of CharacteristicResult
        In the order of ``characteristics``.
    """
    by_id = {f.id: f for f in features}
    for c in characteristics:
        c.validate(by_id)
    P = np.asarray(points_ref, float).reshape(-1, 3)
    w = np.ones(len(P)) if weights is None else np.asarray(weights, float).ravel()
    if w.shape != (len(P),):
        raise ValueError(f"weights must be ({len(P)},), got {w.shape}")
    w = np.clip(np.nan_to_num(w, nan=0.0), 0.0, None)
    g = None if groups is None else np.asarray(groups).ravel()
    if g is not None and g.shape != (len(P),):
        raise ValueError(f"groups must be ({len(P)},), got {g.shape}")
    needed = sorted({fid for c in characteristics for fid in c.features})
    used = [by_id[fid] for fid in needed]
    owner, tid = _assigned(P, used, reference, band_mm)
    snapped: tuple[np.ndarray, EdgeSnap] | None = None
    if origins is not None and len(edges):
        nearest = _owner(tid, features, len(reference.faces))  # the edges' feature positions index `features`
        P, w, g, owner, snapped = _snapped(P, w, g, owner, np.asarray(origins, float).reshape(-1, 3), edges, used,
                                           band_mm, nearest)
    jack: dict[str, dict[Any, Any]] = {}  # each plane's leave-one-camera-out planes, made once
    fitted: dict[str, tuple[fits.Fit, np.ndarray]] = {}
    groups_of: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # each fitted feature's points' groups and weights
    # Each feature's points as one slice of a stable sort by owner (in their original order):
    # a boolean mask over all the points per feature costs ten times more.
    owner = np.where(w > 0, owner, -1)
    order = np.argsort(owner, kind="stable")
    cuts = np.searchsorted(owner[order], np.arange(len(used) + 1))
    for k, f in enumerate(used):
        sel = order[cuts[k]:cuts[k + 1]]
        Pf, wf = P[sel], w[sel]
        fit, keep = _robust_fit(f, Pf, wf)
        if g is not None and fit.params:
            gk, wk = g[sel][keep], wf[keep]
            fit = fits.grouped(fit, gk, wk)
            groups_of[f.id] = (gk, wk)
            if snapped is not None and f.kind == "plane":
                # Its edges' points move when an edge is fitted without a camera.
                rows, snap = snapped
                jack[f.id] = replica_planes(Pf[keep], wk, gk, rows[sel[keep]], snap, fit.params["normal"],
                                            min_points=MIN_POINTS["plane"])
        fitted[f.id] = (fit, Pf[keep])
    out = []
    for c in characteristics:
        out.append(_one(c, by_id, fitted, max_u_fraction, slice_mm, u_surface_mm, groups_of, jack))
    return out


def _snapped(P: np.ndarray, w: np.ndarray, g: np.ndarray | None, owner: np.ndarray, origins: np.ndarray,
             edges: Sequence[PlaneEdge], used: Sequence[Feature], band_mm: float,
             nearest: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray,
                                      tuple[np.ndarray, EdgeSnap] | None]:
    """The points near the used planes' edges moved onto them; each such point given to its
    edge's first used plane, and a copy of it to the second (a point on an edge lies on both);
    the edges' other points left out (:attr:`~inspector.characteristics.edges.EdgeSnap.dropped`).
    A moved point's weight is 1: its place no longer depends on its segment's length.

    Returns the points, weights, groups and owners, and, when groups are known, each point's
    position among the moved ones (-1: not moved) with the snap."""
    pos = {f.id: k for k, f in enumerate(used)}
    mine = [e for e in edges if e.a in pos or e.b in pos]
    if not mine:
        return P, w, g, owner, None
    snap = snap_to_edges(P, origins, mine, band_mm, groups=g, nearest=nearest)
    if not len(snap.index):
        return P, w, g, owner, None
    P, w, owner = P.copy(), w.copy(), owner.copy()
    owner[snap.dropped] = -1  # on an edge, represented by its moved points
    P[snap.index] = snap.points
    w[snap.index] = 1.0
    # Each point's edge's two planes' positions among the used features (-1: not used).
    ka, kb = (np.array([pos.get(pair[i], -1) for pair in snap.pairs], np.int64)[snap.edge] for i in (0, 1))
    owner[snap.index] = np.where(ka >= 0, ka, kb)
    both = (ka >= 0) & (kb >= 0)
    twin = snap.index[both]
    P = np.concatenate([P, P[twin]])
    w = np.concatenate([w, w[twin]])
    owner = np.concatenate([owner, kb[both]])
    if g is None:
        return P, w, g, owner, None
    g = np.concatenate([g, g[twin]])
    rows = np.full(len(P), -1, np.int64)
    rows[snap.index] = np.arange(len(snap.index))
    rows[len(P) - len(twin):] = np.flatnonzero(both)
    return P, w, g, owner, (rows, snap)


#: Plane characteristics whose u the camera jackknife checks (:func:`_jackknife_u`).
JACKKNIFE_KINDS = ("distance", "angle")
#: Fewer cameras than this seeing a jackknifed characteristic's planes: not measurable.
MIN_JACKKNIFE_CAMERAS = 3


def _jackknife_u(c: Characteristic, fitted: Mapping[str, tuple[fits.Fit, np.ndarray]],
                 groups_of: Mapping[str, tuple[np.ndarray, np.ndarray]],
                 cache: dict[str, dict[Any, Any]] | None = None) -> tuple[float, int] | None:
    """The delete-one-camera jackknife standard uncertainty of a distance or angle between
    planes, and the number of cameras it left out; None when the characteristic is of another
    kind or the groups are unknown.

    A plane's points lie along the edges its silhouettes show (never inside the face): when
    a few cameras show an edge, its points' offset and the plane's tilt rest on those cameras,
    and one camera's contour placed a little off tilts the plane -- an error no residual shows,
    because the fit passes through every edge it is given. Computing the value again without
    each camera in turn shows it (Quenouille-Tukey jackknife over the cameras, the units that
    err together: ``u^2 = (G - 1) / G * sum (v_g - mean v)^2``). The plane refits are closed
    form (:func:`inspector.kernels.fits.plane_jackknife`); cylinders and cones (iterative
    fits) keep their design-effect u (:func:`inspector.kernels.fits.grouped`).
    """
    if c.kind not in JACKKNIFE_KINDS or not all(fid in groups_of and fitted[fid][0].kind == "plane" for fid in c.features):
        return None
    full = [fitted[fid][0].perturbed(np.zeros(len(fitted[fid][0].names))) for fid in c.features]
    cache = {} if cache is None else cache
    for fid in c.features:
        if fid not in cache:
            cache[fid] = fits.plane_jackknife(fitted[fid][1], groups_of[fid][1], groups_of[fid][0],
                                              fitted[fid][0].params["normal"], min_points=MIN_POINTS["plane"])
    without = [cache[fid] for fid in c.features]
    value = fits.geometric_distance if c.kind == "distance" else fits.geometric_angle
    values = []
    for cam in sorted(set().union(*without)):
        geos = [w[cam] if cam in w else g for w, g in zip(without, full)]  # a camera a plane did not see: as fitted
        known = [geo for geo in geos if geo is not None]
        if len(known) == len(geos):
            values.append(value(*known))
    G = len(values)
    if G < MIN_JACKKNIFE_CAMERAS:
        return float("inf"), G
    v = np.asarray(values)
    return float(np.sqrt((G - 1) / G * float(((v - v.mean()) ** 2).sum()))), G


def _oriented(fit: fits.Fit, normal: np.ndarray) -> fits.Fit:
    """A plane ``fit`` with its normal turned to the side of ``normal`` (3,) (its residuals and
    perturbed geometry with it)."""
    if not fit.params or float(fit.params["normal"] @ normal) >= 0:
        return fit
    geometry = fit.perturbed  # its geometry at the local parameters given

    def flipped(d: np.ndarray) -> dict[str, Any]:
        g = geometry(d)
        return {**g, "normal": -g["normal"]}

    return fits.Fit(fit.kind, {**fit.params, "normal": -fit.params["normal"]}, -fit.residuals, fit.names, fit.cov,
                    fit.s, fit.n, fit.u, fit.amplification, fit.problem, flipped, fit.design_effect)


def _one(c: Characteristic, by_id: Mapping[str, Feature], fitted: Mapping[str, tuple[fits.Fit, np.ndarray]],
         max_u_fraction: float, slice_mm: float | None, u_surface_mm: float = 0.0,
         groups_of: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
         jack: dict[str, dict[Any, Any]] | None = None) -> CharacteristicResult:
    nominal = c.nominal_value(by_id)
    fs = [fitted[fid][0] for fid in c.features]
    npts = int(sum(ft.n for ft in fs))

    def fail(reason: str) -> CharacteristicResult:
        return CharacteristicResult(c.id, c.kind, c.features, nominal, None, None, c.lower, c.upper, None, None, npts,
                                    "not_measurable", reason)

    for fid, ft in zip(c.features, fs):
        if ft.problem is not None:
            return fail(f"{fid}: {ft.problem}")
    try:
        value, u = _value(c, by_id, fitted, slice_mm)
    except _NotMeasurable as e:
        return fail(str(e))
    except fits.FitError as e:
        return fail(f"{'-'.join(c.features)}: {e}")
    if not math.isfinite(value) or not math.isfinite(u):
        return fail(f"{'-'.join(c.features)}: the fit gives no finite value")
    by_camera = _jackknife_u(c, fitted, groups_of or {}, jack)
    if by_camera is not None:
        if not math.isfinite(by_camera[0]):
            return fail(f"{'-'.join(c.features)}: seen by {by_camera[1]} camera(s); at least {MIN_JACKKNIFE_CAMERAS} "
                        "are needed to know how much it rests on one camera's contour")
        u = max(u, by_camera[0])
    if u_surface_mm > 0:
        u = math.hypot(u, abs(offset_sensitivity(c, by_id, fitted)) * u_surface_mm)
    U = 2.0 * u
    width = c.upper - c.lower
    if width > 0 and U > max_u_fraction * width:
        return fail(f"U = {U:.4g} {c.unit} exceeds {max_u_fraction:g} of the tolerance width {width:.4g} {c.unit}: "
                    "the measurement cannot decide")
    dev = value - nominal
    verdict = "ok" if c.lower <= dev <= c.upper else "nok"
    return CharacteristicResult(c.id, c.kind, c.features, nominal, value, dev, c.lower, c.upper, u, U, npts, verdict)


def _offset(geo: dict[str, Any], f: Feature, delta: float) -> dict[str, Any]:
    """A fitted primitive's surface moved by ``delta`` mm along its outward normal (the part
    grown by ``delta`` there): a plane along its (outward) normal, a boss's or a convex
    sphere's radius up, a bore's down; a cone's apex along its axis; a torus's tube radius up
    when convex (a rounded edge), down when concave (a groove). Axes do not move."""
    g = dict(geo)
    sign = 1.0 if f.nominal.get("convex", True) else -1.0
    if g["kind"] == "plane":
        g["point"] = np.asarray(g["point"], float) + delta * fits.direction_of(g)
    elif g["kind"] in ("cylinder", "sphere"):
        g["radius"] = float(g["radius"]) + sign * delta
    elif g["kind"] == "torus":
        g["minor_radius"] = float(g["minor_radius"]) + sign * delta
    elif g["kind"] == "cone":
        alpha = math.radians(float(g["half_angle_deg"]))
        g["apex"] = np.asarray(g["apex"], float) - sign * delta / math.sin(alpha) * fits.direction_of(g)
        if "radius" in g:
            g["radius"] = float(g["radius"]) + sign * delta / math.cos(alpha)
    return g


def offset_sensitivity(c: Characteristic, by_id: Mapping[str, Feature],
                       fitted: Mapping[str, tuple[fits.Fit, np.ndarray]]) -> float:
    """How much the characteristic's value moves per mm of a surface offset common to all its
    features (d value / d delta, mm/mm or deg/mm).

    The silhouettes place every edge of a part with the same small bias (the segmentation's
    threshold against the edge profile, the calibration's scale: a fraction of a pixel), so
    a part looks grown or shrunk by a common ``delta`` -- one systematic error shared by all
    its points, which no number of points averages away. A diameter moves by ``2 delta``
    (a bore's by ``-2 delta``), a radius by ``delta`` (a bore's, a groove's or an inner
    fillet's by ``-delta``), a thickness between faces facing away by ``2 delta``, a step
    between faces facing the same way by 0, a distance between axes, an angle, a position
    or a form by 0."""
    if c.kind in ("diameter", "radius"):
        f = by_id[c.features[0]]
        k = 2.0 if c.kind == "diameter" else 1.0
        return k * (1.0 if f.nominal.get("convex", True) else -1.0)
    if c.kind != "distance":
        return 0.0
    fa, fb = (by_id[fid] for fid in c.features)
    ga, gb = (fitted[fid][0].perturbed(np.zeros(len(fitted[fid][0].names))) for fid in c.features)
    h = 1e-3
    hi = fits.geometric_distance(_offset(ga, fa, h), _offset(gb, fb, h))
    lo = fits.geometric_distance(_offset(ga, fa, -h), _offset(gb, fb, -h))
    return (hi - lo) / (2 * h)


class _NotMeasurable(Exception):
    pass


def _value(c: Characteristic, by_id: Mapping[str, Feature], fitted: Mapping[str, tuple[fits.Fit, np.ndarray]],
           slice_mm: float | None) -> tuple[float, float]:
    kind = c.kind
    fit, pts = fitted[c.features[0]]
    if kind in ("diameter", "radius"):
        k = 2.0 if kind == "diameter" else 1.0
        name = "minor_radius" if fit.kind == "torus" else "radius"  # a torus's: its tube's
        i = fit.names.index(name)
        return k * float(fit.params[name]), k * float(np.sqrt(fit.cov[i, i]))
    if kind == "distance":
        return fits.distance_between(fit, fitted[c.features[1]][0])
    if kind == "angle":
        return fits.angle_between(fit, fitted[c.features[1]][0])
    if kind == "position":
        return _position(by_id[c.features[0]], fit)
    if kind == "flatness":
        return fits.flatness(pts, fit), fit.s
    if kind == "cylindricity":
        return fits.cylindricity(pts, fit), fit.s
    if kind == "roundness":
        return _roundness(by_id[c.features[0]], fit, pts, slice_mm)
    raise AssertionError(kind)  # pragma: no cover


def _position(f: Feature, fit: fits.Fit) -> tuple[float, float]:
    nm = _nominal_geometry(f)
    if f.kind in ("sphere", "torus"):
        c0 = nm["centre"]

        def zone(g: dict[str, Any]) -> float:
            return 2.0 * float(np.linalg.norm(np.asarray(g["centre"]) - c0))
    else:
        a0 = np.asarray(nm.get("direction", nm.get("axis")), float)
        ends: tuple[np.ndarray, ...]
        if f.kind == "cylinder":
            half = 0.5 * float(nm["length"]) * a0
            ends = (nm["point"] - half, nm["point"] + half)
        else:
            ends = (nm["apex"],)

        def zone(g: dict[str, Any]) -> float:
            p, a = np.asarray(g["point"], float), np.asarray(g.get("direction", g.get("axis")), float)
            worst = 0.0
            for e in ends:
                d = e - p
                worst = max(worst, float(np.linalg.norm(d - (d @ a) * a)))
            return 2.0 * worst

    return fits.propagate(zone, [fit])


def _roundness(f: Feature, fit: fits.Fit, pts: np.ndarray, slice_mm: float | None) -> tuple[float, float]:
    """The largest minimum-zone roundness over cross-sections along the fitted axis.

    A section counts when it holds at least 12 points all around the axis (no gap of more
    than 90 degrees between them: a short arc does not fix a centre). All sections are
    solved together (:func:`inspector.kernels.fits.roundness_sections`, one programme)."""
    a = np.asarray(fit.params.get("direction", fit.params.get("axis")), float)
    p = np.asarray(fit.params["point"], float)
    h = (pts - p) @ a
    length = float(np.ptp(h)) if len(h) else 0.0
    step = slice_mm if slice_mm is not None else max(0.5, length / 5.0)
    edges = np.arange(h.min(), h.max() + step, step) if len(h) else np.zeros(0)
    bu, bv = fits.orthonormal_basis(a)
    d = pts - p
    ang = np.arctan2(d @ bv, d @ bu)
    sections = []
    for lo in edges:
        sel = (h >= lo) & (h < lo + step)
        if sel.sum() < 12:
            continue
        t = np.sort(ang[sel])
        gap = max(float(np.max(np.diff(t))) if len(t) > 1 else 2 * math.pi, float(t[0] + 2 * math.pi - t[-1]))
        if gap > math.pi / 2:
            continue
        sections.append(pts[sel])
    if not sections:
        raise _NotMeasurable(f"{f.id}: no cross-section of {step:.3g} mm holds enough points around the axis for a roundness")
    return float(fits.roundness_sections(sections, a).max()), fit.s
