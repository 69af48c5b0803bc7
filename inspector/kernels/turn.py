"""The turn about an axis of near-symmetry, judged on the silhouettes: pure kernels over rays.

The features that fix a near-symmetric part's turn about its axis (a keyway, a flat, bolt
holes) are a fraction of a millimetre deep in the silhouettes. Points selected against a
pose cannot judge it: each ray's point may lie anywhere on its hull segment (3.5 mm median
on a keyed shaft), so the selection follows the reference it is selected against. The
contour rays themselves can: for the sized reference at the part's pose every contour ray
grazes it (keyed shaft at 0.98, 16 cameras: 1st-99th percentile of the residuals -5 to
+6 um), and at a wrong turn the rays past the keyway miss it or cut into it.

:class:`TurnJudge` holds the rays (:class:`Rays`, one per camera: origin, directions and
the depth range each can meet the part in) and the reference placed by a pose under a size
model, and gives the silhouette loss of every turn of the reference about its axis.
:func:`judge_turns` scans the turns, searches the lowest basins and says how firmly the
silhouettes choose (a :class:`~inspector.model.PoseConfidence`); :func:`polish_turn`
refines a turn. The tuning is :class:`TurnOptions`.

Conventions: mm and degrees; ``pose`` is reference -> world (4, 4); the axis (unit) and its
centre are in the reference frame.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from inspector.kernels.axis import AMBIGUOUS_POINTS, AxisScan, TurnZone, pose_confidence
from inspector.kernels.bcps import Rays, ray_min_distance
from inspector.kernels.prior import SizePrior
from inspector.kernels.rigid import turns_about_axis
from inspector.kernels.robust import tukey_loss
from inspector.model import PoseConfidence

__all__ = ["TurnJudge", "TurnOptions", "basins", "judge_turns", "polish_turn", "search_turn", "silhouette_scan",
           "turn", "turned"]


@dataclass(frozen=True)
class TurnOptions:
    """How the silhouettes judge the turn about an axis of near-symmetry (tuning, not recipe
    parameters: the values every acceptance figure was measured with).

    Attributes
    ----------
    cutoff_mm : float
        Tukey cutoff of the contour rays' residuals, mm (a keyway is 0.1-0.5 mm deep).
    step_deg : float
        The scan's step about the axis, about, degrees (its cutoff is as wide as the
        outermost point moves in a step).
    stride : int
        The judge uses every n-th contour ray (the scan and the basin search).
    fine_stride : int
        The final polish uses every n-th contour ray.
    coarse : (float, int)
        Sampling along the rays while searching: step, mm, and refinement levels
        (:func:`~inspector.kernels.bcps.ray_min_distance`).
    fine : (float, int)
        Sampling along the rays in the final polish: step, mm, and refinement levels.
    local_deg : float
        The basin search's step, degrees.
    basins : int
        How many of the scan's lowest minima are searched.
    resettle_deg : float
        A turn beyond this (degrees) is settled again by the points before the
        silhouettes judge again about it.
    polish_deg : float
        Half-width of the final polish about the judged turn, degrees.
    xatol_deg : float
        Every Brent search's tolerance, degrees.
    """

    cutoff_mm: float = 0.1
    step_deg: float = 5.0
    stride: int = 9
    fine_stride: int = 3
    coarse: tuple[float, int] = (0.5, 2)
    fine: tuple[float, int] = (0.25, 3)
    local_deg: float = 1.0
    basins: int = 2
    resettle_deg: float = 3.0
    polish_deg: float = 1.5
    xatol_deg: float = 0.02


def turn(axis: np.ndarray, centre: np.ndarray, angle_deg: float) -> np.ndarray:
    """(4, 4) turn of the reference frame by ``angle_deg`` about the line (axis (3,), centre (3,))."""
    return turns_about_axis(np.asarray(axis, float), np.asarray(centre, float), np.array([angle_deg]))[0]


def turned(pose: np.ndarray, prior: SizePrior, axis: np.ndarray, centre: np.ndarray, angle_deg: float) -> np.ndarray:
    """The rigid pose (4, 4) that places the reference as ``pose`` (4, 4) does, turned by
    ``angle_deg`` about its own axis *before* the size model: ``placement(result) =
    placement(pose) @ turn``. (Turning after it would also turn the model's shift and tilt,
    fitted at ``pose``: 0.03-0.05 mm at the ends of a 40 mm shaft after a half turn.)"""
    S = np.linalg.inv(pose) @ prior.placement(pose)
    return pose @ S @ turn(axis, centre, angle_deg) @ np.linalg.inv(S)


def _crosses(zone: TurnZone, origin: np.ndarray, dirs: np.ndarray, t0: np.ndarray, t1: np.ndarray,
             inv: np.ndarray) -> np.ndarray:
    """(M,) bool: rays with a point (every 0.5 mm of their range) in the zone's variable
    cells; ``inv`` (4, 4) maps the world into the zone's (the nominal reference's) frame."""
    if not len(dirs):
        return np.zeros(0, bool)
    top = np.where(t0 <= t1, t1, t0)
    n = int(np.ceil(float(np.max(top - t0)) / 0.5)) + 1
    tt = np.minimum(t0[:, None] + 0.5 * np.arange(n)[None, :], top[:, None])
    X = (origin + tt[..., None] * dirs[:, None, :]).reshape(-1, 3)
    Y = X @ inv[:3, :3].T + inv[:3, 3]
    return np.asarray(zone.hits(Y).reshape(tt.shape).any(axis=1))


class TurnJudge:
    """The silhouette loss of the reference turned about its axis, under one placement.

    The loss of a turn is the mean Tukey loss (0..1) at ``options.cutoff_mm`` of the
    silhouette residuals (:func:`~inspector.kernels.bcps.ray_min_distance`) of every
    ``stride``-th contour ray against the reference placed by ``pose`` under ``prior`` and
    turned about its own axis (:func:`turned`), about the residuals' median at the judged
    turn.

    Only the rays through the reference's :class:`~inspector.kernels.axis.TurnZone` are
    evaluated at each turn; the others add the same loss at every turn (evaluated once).

    Parameters
    ----------
    rays : sequence of Rays
        Every camera's contour rays (cameras without a contour left out).
    distance : callable
        ``(N, 3) -> (N,)`` signed distance to the nominal reference in its own frame, mm
        (NaN far from it is fine: ``MeshDistance.near``).
    zone : TurnZone
        The reference's turn zone about ``axis``.
    pose : (4, 4) float
        The judged pose, reference -> world.
    prior : SizePrior
        The part's size model at ``pose``.
    axis, centre : (3,) float
        The axis of near-symmetry (unit) and a point on it, reference frame, mm.
    stride : int
        Every n-th ray of each camera is used.
    fine : bool
        Sample along the rays at ``options.fine`` (else ``options.coarse``).
    options : TurnOptions
    """

    def __init__(self, rays: Sequence[Rays], distance: Callable[[np.ndarray], np.ndarray], zone: TurnZone,
                 pose: np.ndarray, prior: SizePrior, axis: np.ndarray, centre: np.ndarray, *, stride: int, fine: bool,
                 options: TurnOptions) -> None:
        self.pose, self.prior, self.axis, self.centre = pose, prior, np.asarray(axis, float), np.asarray(centre, float)
        self.options = options
        self._distance, self._fine = distance, fine
        self._place = prior.placement(pose)
        inv = np.linalg.inv(self._place)
        self._rays: list[Rays] = []
        rest: list[Rays] = []
        n = 0
        for origin, dirs, r0, r1 in rays:
            sub = slice(None, None, stride)
            d, a, b = dirs[sub], r0[sub], r1[sub]
            ok = a <= b
            n += int(ok.sum())
            act = ok & _crosses(zone, origin, d, a, b, inv)
            self._rays.append(Rays(origin, d[act], a[act], b[act]))
            rest.append(Rays(origin, d[ok & ~act], a[ok & ~act], b[ok & ~act]))
        #: Rays judged (within their range), all cameras.
        self.n = n
        # The median and the turn-independent part, from the rays left out.
        r_act = self._at_pose = self._residuals(np.eye(4))
        r_rest = np.concatenate([self._min_distance(inv, ray) for ray in rest]) if rest else np.zeros(0)
        r_all = np.concatenate([r_act, r_rest])
        r_all = r_all[np.isfinite(r_all)]
        #: Median residual at the judged turn, mm (the size left over: the loss is about it).
        self.median = float(np.median(r_all)) if len(r_all) else 0.0
        self._rest = r_rest[np.isfinite(r_rest)] - self.median

    def _min_distance(self, inv: np.ndarray, ray: Rays) -> np.ndarray:
        """(M,) smallest signed distance, mm, along each of ``ray``'s rays to the reference
        that ``inv`` (4, 4, world -> its frame) places, under the prior's scale."""
        index, scale = self._distance, self.prior.scale

        def sd(X: np.ndarray) -> np.ndarray:
            return scale * index(X @ inv[:3, :3].T + inv[:3, 3])

        step, levels = self.options.fine if self._fine else self.options.coarse
        return ray_min_distance(ray.origin, ray.dirs, ray.t0, ray.t1, sd, step_mm=step, levels=levels)

    def _residuals(self, turn_T: np.ndarray) -> np.ndarray:
        """Residuals, mm, of the rays through the zone against the reference turned by ``turn_T`` (4, 4)."""
        inv = np.linalg.inv(self._place @ turn_T)
        res = [self._min_distance(inv, ray) for ray in self._rays]
        return np.concatenate(res) if res else np.zeros(0)

    def loss(self, angle_deg: float, cutoff_mm: float | None = None) -> float:
        """Mean loss (0..1) of the rays at the turn ``angle_deg`` about the axis, Tukey cutoff
        ``cutoff_mm`` (default ``options.cutoff_mm``)."""
        cutoff = self.options.cutoff_mm if cutoff_mm is None else cutoff_mm
        r = self._at_pose if angle_deg == 0.0 else self._residuals(turn(self.axis, self.centre, angle_deg))
        r = r[np.isfinite(r)] - self.median
        return float(np.sum(tukey_loss(r, cutoff)) + np.sum(tukey_loss(self._rest, cutoff))) / max(self.n, 1)

    def turned(self, angle_deg: float) -> np.ndarray:
        """The judged pose turned by ``angle_deg`` (:func:`turned`), (4, 4)."""
        return turned(self.pose, self.prior, self.axis, self.centre, angle_deg)


def silhouette_scan(judge: TurnJudge, scan: AxisScan) -> AxisScan:
    """``scan``'s turns about the axis, about every ``step_deg``, judged on the
    silhouettes at a cutoff as wide as the outermost point moves between two of them (at 0.1
    mm a flat's basin is +-0.6 degree wide on a Ø20 shaft, and a grid would step over it):
    an :class:`~inspector.kernels.axis.AxisScan` whose cost is :meth:`TurnJudge.loss`
    (``inf`` for a turn that leaves the visual hull, the pose's own for a symmetry of the
    reference) and whose ``n_points`` are the contour points it stands for."""
    o = judge.options
    k = max(1, int(round(len(scan.angles_deg) * o.step_deg / 360.0)))
    idx = np.arange(0, len(scan.angles_deg), k)
    turns = scan.angles_deg[idx]
    wide = max(o.cutoff_mm, scan.radius_mm * np.radians(360.0 / len(scan.angles_deg) * k))
    cost = np.full(len(idx), np.inf)
    for j, i in enumerate(idx):
        if j == 0 or (scan.inside_hull[i] and not scan.symmetric[i]):
            cost[j] = judge.loss(float(turns[j]), wide)
    cost[np.asarray(scan.symmetric)[idx]] = cost[0]
    return dataclasses.replace(scan, angles_deg=turns, cost=cost, moved=scan.moved[idx],
                               poke=None if scan.poke is None else scan.poke[idx], cutoff_mm=wide,
                               n_points=judge.n * o.stride)


def basins(sil: AxisScan, step_deg: float) -> list[float]:
    """The turns (degrees, -180..180) of the scan's lowest local minima, the pose's own
    turn (0) whenever it is one, none within 1.5 ``step_deg`` of another symmetry of the
    reference; ``[0.0]`` when none is left."""
    a = (sil.angles_deg + 180.0) % 360.0 - 180.0
    sym = a[sil.symmetric & (np.abs(a) > 1e-9)]
    gap = np.abs((a[:, None] - sym[None, :] + 180.0) % 360.0 - 180.0)
    near = np.asarray((gap <= 1.5 * step_deg).any(axis=1)) if len(sym) else np.zeros(len(a), bool)
    out = [float(a[i]) for i in sil.minima(len(a)) if np.isfinite(sil.cost[i]) and not near[i]]
    return out or [0.0]


def polish_turn(judge: TurnJudge, around: float, half_deg: float) -> tuple[float, float]:
    """The turn (degrees) within ``around +- half_deg`` whose silhouettes fit best at
    ``cutoff_mm``, and its loss: a bounded Brent search to ``xatol_deg``."""
    best = minimize_scalar(judge.loss, bounds=(around - half_deg, around + half_deg), method="bounded",
                           options={"xatol": judge.options.xatol_deg})
    return float(best.x), float(best.fun)


def search_turn(judge: TurnJudge, start: float, half_deg: float, radius_mm: float) -> tuple[float, float]:
    """The best turn (degrees) within ``half_deg`` of ``start``, and its loss at
    ``cutoff_mm``: every ``local_deg`` there (at the cutoff of that step at the outermost
    radius ``radius_mm``), then a Brent search about the best of those."""
    o = judge.options
    cutoff = max(o.cutoff_mm, radius_mm * np.radians(o.local_deg))
    grid = start + np.arange(-half_deg, half_deg + 1e-9, o.local_deg)
    b = float(grid[int(np.argmin([judge.loss(float(a), cutoff) for a in grid]))])
    return polish_turn(judge, b, o.local_deg)


def judge_turns(judge: TurnJudge, scan: AxisScan) -> tuple[float, PoseConfidence]:
    """The turn (degrees) the silhouettes choose about the judged pose, and how firmly.

    The scan (:func:`silhouette_scan`) names the basins; each of the ``basins`` lowest is
    searched to its best turn (:func:`search_turn`), and the lowest wins. The confidence
    (:func:`~inspector.kernels.axis.pose_confidence` of the scan for the axis, the
    symmetries and the hull range) takes its runner-up and margin from the other searched
    basins, each at its own best turn: a basin narrower than the scan's step is not judged
    by a turn beside it.
    """
    o = judge.options
    sil = silhouette_scan(judge, scan)
    found = [search_turn(judge, b, o.step_deg, scan.radius_mm) for b in basins(sil, o.step_deg)[:o.basins]]
    order = sorted(range(len(found)), key=lambda i: found[i][1])
    angle, loss = found[order[0]]
    conf = pose_confidence(sil)
    width = np.degrees(2.0 * o.cutoff_mm / scan.radius_mm) + o.local_deg
    others = [found[i] for i in order[1:] if abs((found[i][0] - angle + 180.0) % 360.0 - 180.0) > width]
    if others:
        runner, rloss = others[0]
        margin = rloss - loss
        points = int(round(margin * judge.n * o.stride))
        conf = dataclasses.replace(conf, runner_up_deg=float((runner - angle + 180.0) % 360.0 - 180.0), margin=margin,
                                   margin_points=points, cutoff_mm=o.cutoff_mm,
                                   ambiguous=points < AMBIGUOUS_POINTS)
    else:
        # One basin (the others are symmetries or leave the hull): no other turn competes.
        conf = dataclasses.replace(conf, runner_up_deg=None, margin=None, margin_points=None, ambiguous=False)
    return angle, conf
