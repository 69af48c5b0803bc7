"""The pose search: select, settle, scan, judge the turn, polish; a pure kernel around a selection.

The global alignment's fit on the bulgy visual hull is a start, not a pose: the paper's way
round is to select the best-case points, re-align the reference on them and select again.
:func:`search_pose` does that for any selection rule, given as a callable (:class:`Select`:
a pose in, :class:`~inspector.model.BcpsPoints` out), and returns the final alignment and
selection:

1. **settle** — a sparse selection, a robust re-fit on it (on the points moved by their
   median deviation along the normals: a size error is not a misalignment), a new
   selection, until the pose stops turning (:meth:`_Search.settle`). The first fit also
   scans every turn about the reference's axis of near-symmetry, if it has one
   (:func:`~inspector.kernels.registration.refine_on_points` ``axis_scan``);
2. **scan and judge the turn** — where the reference has such an axis, the turn about it is
   judged on the contour rays themselves (:mod:`~inspector.kernels.turn`), and a turn
   beyond ``resettle_deg`` is settled again by the points and judged again
   (:meth:`_Search.judge_turn`);
3. **size** — with a size prior, the part's best-fit scale, refitted against the sized
   reference while it still turns the pose (:meth:`_Search.fit_size`);
4. **polish** — the silhouettes' final say on the turn, on finer rays
   (:meth:`_Search.polish`), and the final selection.

The refined :class:`~inspector.model.Alignment` is written here and only here: its pose,
its fit figures, its method (``<global>+bcps-refine`` and ``+size`` with a size model) and
its :class:`~inspector.model.PoseConfidence`; a stage passes it on unchanged.

The tuning (14 numbers measured on the acceptance parts) is :class:`PoseOptions`.
Conventions: mm and degrees; ``pose`` is reference -> world (4, 4).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np

from inspector.kernels.axis import AxisScan, TurnZone, pose_confidence, scan_about_axis
from inspector.kernels.bcps import Rays
from inspector.kernels.prior import SizePrior, fit_size_prior
from inspector.kernels.registration import refine_on_points
from inspector.kernels.rigid import axis_turn_deg, rotation_deg
from inspector.kernels.turn import TurnJudge, TurnOptions, judge_turns, polish_turn
from inspector.model import Alignment, BcpsPoints, PoseConfidence

__all__ = ["PoseOptions", "PoseReference", "Select", "search_pose"]


@dataclass(frozen=True)
class PoseOptions:
    """Tuning of the pose search (not recipe parameters: the values every acceptance figure
    was measured with).

    Attributes
    ----------
    size_range : float
        Largest size error (relative) the search must tolerate: the nominal reference may
        poke out of a part this much small by this fraction of its radius (the hull depth
        that counts when a turn is judged against the visual hull).
    reselect_deg : float
        A re-fit that turns the pose by more than this (degrees) is followed by a new
        selection and re-fit ...
    attempts : int
        ... at most this many times in all (also bounds the size re-fits).
    turn : TurnOptions
        How the silhouettes judge the turn about an axis of near-symmetry.
    """

    size_range: float = 0.035
    reselect_deg: float = 0.05
    attempts: int = 4
    turn: TurnOptions = field(default_factory=TurnOptions)


class Select(Protocol):
    """A selection rule: the best-case points for the reference placed at ``pose`` (4, 4).

    ``sparse``: a selection that only feeds a fit (fewer rays, coarser sampling: the fit
    averages thousands of points); ``prior``: rank the candidates against the reference
    under this size model (deviations stay against the nominal one).
    """

    def __call__(self, pose: np.ndarray, *, sparse: bool = False, prior: SizePrior | None = None) -> BcpsPoints: ...


class PoseReference(Protocol):
    """What the search reads of the reference (:class:`inspector.reference.Reference` is one)."""

    @property
    def vertices(self) -> np.ndarray: ...

    @property
    def faces(self) -> np.ndarray: ...

    @property
    def distance(self) -> Any: ...

    def signed_distance(self, points: np.ndarray, pose: np.ndarray | None = None) -> np.ndarray: ...

    def surface_normals(self, points: np.ndarray, pose: np.ndarray) -> np.ndarray: ...

    def to_reference_frame(self, points: np.ndarray, pose: np.ndarray) -> np.ndarray: ...

    def turn_zone(self, axis: np.ndarray, centre: np.ndarray) -> TurnZone: ...


class _Turn(NamedTuple):
    """Where the turn judgement left the search."""

    refined: Alignment  # the fit, turned as the silhouettes chose
    sel: BcpsPoints  # the last sparse selection
    axis: np.ndarray | None  # the judged axis (None: none, or every turn is a symmetry)
    scan: AxisScan | None  # the last scan of the points about the axis
    judged: np.ndarray | None  # the placement the silhouettes judged (4, 4), or None
    confidence: PoseConfidence


def search_pose(select: Select, reference: PoseReference, alignment: Alignment, hull_points: np.ndarray,
                hull_voxel_mm: float, rays: Callable[[], Sequence[Rays]], *, robust_mm: float, start_mm: float,
                sized: bool, options: PoseOptions | None = None) -> tuple[Alignment, BcpsPoints]:
    """Refine ``alignment`` on the points ``select`` picks, and the selection with it.

    Parameters
    ----------
    select : Select
        The selection rule.
    reference : PoseReference
        The nominal reference.
    alignment : Alignment
        The global alignment (its pose is the start).
    hull_points : (H, 3) float
        Surface points of the part's visual hull, world, mm (the part lies inside it).
    hull_voxel_mm : float
        The hull's voxel, mm.
    rays : callable
        ``() -> sequence of Rays``: every camera's contour rays (asked for only when a turn
        is judged).
    robust_mm, start_mm : float
        Final and initial robust scale of the re-fits, mm.
    sized : bool
        Fit the part's size model (:mod:`~inspector.kernels.prior`) and make the final
        selection against it.
    options : PoseOptions, optional

    Returns
    -------
    alignment : Alignment
        The refined pose, its fit figures, method and confidence.
    bcps : BcpsPoints
        The final selection (with its size model when ``sized``).
    """
    search = _Search(select, reference, hull_points, hull_voxel_mm, rays, robust_mm=robust_mm, start_mm=start_mm,
                     sized=sized, options=options if options is not None else PoseOptions())
    return search.run(alignment)


class _Search:
    """One pose search's inputs and its steps (see the module's description)."""

    def __init__(self, select: Select, reference: PoseReference, hull_points: np.ndarray, hull_voxel_mm: float,
                 rays: Callable[[], Sequence[Rays]], *, robust_mm: float, start_mm: float, sized: bool,
                 options: PoseOptions) -> None:
        self.select, self.ref, self.hull_points, self.rays = select, reference, hull_points, rays
        self.robust_mm, self.start_mm, self.sized, self.o = robust_mm, start_mm, sized, options
        # The part lies inside its hull up to the voxel size; the nominal reference pokes out
        # of a part up to 3 % small by 3 % of its radius.
        self.hull_mm = max(2.0 * hull_voxel_mm, options.size_range * float(np.ptp(reference.vertices, axis=0).max()) / 2.0)

    def run(self, alignment: Alignment) -> tuple[Alignment, BcpsPoints]:
        """The four steps from the global ``alignment``: the refined alignment and selection."""
        # A size error shifts every deviation the same way: it is not a misalignment.
        # Fitting the points themselves would slide the reference until some faces are
        # flush (BCPS points sit on edges, each close to two faces) and report the
        # others twice too far. So the fit is on the points moved by the median
        # deviation along the reference normals: a uniformly small part comes out
        # centred and uniformly small. The robust scale starts wide (start_mm): on a
        # nearly symmetric part (a shaft with a flat) the few points that fix the
        # rotation about its axis are off by tenths of a millimetre, beyond the final
        # scale, until the fit has used them.
        # The first fit also scans every turn about the reference's axis of
        # near-symmetry, if it has one, and starts from the best few: the global
        # alignment's fit on the bulgy hull can end anywhere about it (shaft with a flat:
        # ten degrees, 1.2 mm at the flat, a false reject; flange keyed by four bolt
        # holes: 6 degrees; a keyed shaft: 160 degrees), a local minimum a single fit
        # does not leave.
        refined, sel = self.settle(alignment.pose, self.select(alignment.pose, sparse=True), True)
        t = self.judge_turn(refined, sel)
        result = Alignment(t.refined.pose, t.refined.fitness, t.refined.rmse_mm, f"{alignment.method}+bcps-refine")
        if not self.sized:
            result = dataclasses.replace(result, pose=self.polish(result.pose, SizePrior(), t), confidence=t.confidence)
            return result, self.select(result.pose)
        prior = self.fit_size(t.sel, result.pose, t.axis)
        result = dataclasses.replace(result, pose=self.polish(result.pose, prior, t))
        bcps = dataclasses.replace(self.select(result.pose, prior=prior), size=prior)
        if not prior.is_identity:
            result = dataclasses.replace(result, pose=prior.rigid(result.pose), method=f"{result.method}+size")
        return dataclasses.replace(result, confidence=t.confidence), bcps

    def settle(self, pose: np.ndarray, sel: BcpsPoints, scan: bool) -> tuple[Alignment, BcpsPoints]:
        """Re-fit on ``sel`` and select again until the pose settles: the last fit and the
        selection it stands on. ``scan``: the first fit scans the turns about the axis."""
        ref = self.ref
        for attempt in range(self.o.attempts):
            last = pose
            for i in range(2):
                offset = float(np.median(ref.signed_distance(sel.points, pose)))
                target = sel.points - offset * ref.surface_normals(sel.points, pose)
                refined = refine_on_points(
                    target, ref.vertices, ref.faces, pose, robust_mm=self.robust_mm, index=ref.distance,
                    start_mm=self.start_mm, axis_scan=(scan and i == 0 and attempt == 0),
                    hull_points=self.hull_points, hull_mm=self.hull_mm,
                )
                pose = refined.pose
                if abs(offset) < 0.5 * self.robust_mm:
                    break
            # The selection follows the pose it is made against (a ray through a bolt
            # hole picks its point deepest in the reference's material when the
            # reference's hole is elsewhere), so one re-fit moves only part of the way:
            # select again and re-fit until the pose settles (flange keyed by four
            # holes, 6 degrees off after the global alignment: 2.1, 1.6, 0.55, 0.17
            # degrees after each re-fit).
            if attempt == self.o.attempts - 1 or rotation_deg(last, pose) < self.o.reselect_deg:
                break
            sel = self.select(pose, sparse=True)
        return refined, sel

    def scan_at(self, pose: np.ndarray, sel: BcpsPoints) -> AxisScan | None:
        """The points' scan about the reference's axis at ``pose`` (None: no axis)."""
        ref = self.ref
        return scan_about_axis(sel.points, ref.vertices, ref.faces, pose, cutoff_mm=self.start_mm,
                               index=ref.distance, hull_points=self.hull_points, hull_mm=self.hull_mm)

    def judge(self, pose: np.ndarray, prior: SizePrior, axis: np.ndarray, centre: np.ndarray, fine: bool) -> TurnJudge:
        """The silhouettes' judge of the turns about ``axis`` at ``pose`` under ``prior``."""
        o = self.o.turn
        return TurnJudge(self.rays(), self.ref.distance.near, self.ref.turn_zone(axis, centre), pose, prior, axis, centre,
                         stride=o.fine_stride if fine else o.stride, fine=fine, options=o)

    def judge_turn(self, refined: Alignment, sel: BcpsPoints) -> _Turn:
        """The turn about the axis of near-symmetry, judged on the silhouettes."""
        scan = self.scan_at(refined.pose, sel)
        # The axis whose turn the silhouettes judge (None: no axis, or one every turn about
        # which is a symmetry).
        axis = scan.axis if scan is not None and scan.distinct().any() else None
        if scan is None or axis is None:
            # No turn to judge (a torus: every turn is a symmetry): its axis and symmetries.
            return _Turn(refined, sel, None, scan, None, pose_confidence(scan))
        # The turn is fixed by features a fraction of a millimetre deep in the silhouettes
        # (a keyway: 0.1-0.5 mm in one or two views), which the points selected against a
        # pose cannot judge (they follow it). So the turns are judged on the contour rays
        # themselves, against the reference under the part's size (a 2 % small shaft is
        # 0.2 mm in everywhere, which would drown the keyway): every 6 degrees the hull
        # allows, then the two lowest basins each to its best turn. Keyed shaft, 16
        # cameras, 0.98: the points alone left it 120 degrees off; now 0.01.
        prior = self.size_prior(sel, refined.pose, axis=axis) if self.sized else SizePrior()
        judge = self.judge(refined.pose, prior, axis, scan.centre, False)
        angle, confidence = judge_turns(judge, scan)
        if abs(angle) > self.o.turn.resettle_deg:
            # Another turn: the points settle the other five degrees of freedom there
            # (and move the turn again: a keyed shaft on 8 cameras, up to 6.5 degrees),
            # and the silhouettes judge again about it, under a size model fitted there.
            start = judge.turned(angle)
            refined, sel = self.settle(start, self.select(start, sparse=True), False)
            prior = self.size_prior(sel, refined.pose, axis=axis) if self.sized else SizePrior()
            rescan = self.scan_at(refined.pose, sel)
            assert rescan is not None  # the reference's axis is its own: a scan about it exists
            scan = rescan
            judge = self.judge(refined.pose, prior, axis, scan.centre, False)
            angle, confidence = judge_turns(judge, scan)
        refined = dataclasses.replace(refined, pose=judge.turned(angle))
        return _Turn(refined, sel, axis, scan, prior.placement(refined.pose), confidence)

    def size_prior(self, sel: BcpsPoints, pose: np.ndarray, start: np.ndarray | None = None,
                   axis: np.ndarray | None = None) -> SizePrior:
        """The part's best-fit size model, from a selection (:mod:`~inspector.kernels.prior`).

        ``axis`` (3,), reference frame: an axis of near-symmetry whose turn the silhouettes
        decide; the fit's rotation loses its component about it (the points pin that turn so
        weakly that the fit wanders: a keyed shaft at 0.98 on 8 cameras, 5 degrees).
        """
        V = self.ref.vertices
        prior = fit_size_prior(self.ref.to_reference_frame(sel.points, pose), self.ref.distance,
                               centre=0.5 * (V.min(axis=0) + V.max(axis=0)), robust_mm=self.robust_mm,
                               start_mm=self.start_mm, start=start)
        if axis is None or prior.is_identity:
            return prior
        w = np.asarray(prior.rotation, float)
        a = np.asarray(axis, float)
        q = w - (w @ a) * a
        return dataclasses.replace(prior, rotation=(float(q[0]), float(q[1]), float(q[2])))

    def fit_size(self, sel: BcpsPoints, pose: np.ndarray, axis: np.ndarray | None) -> SizePrior:
        """The size model at ``pose``, from ``sel`` and re-fitted against itself."""
        prior = self.size_prior(sel, pose, axis=axis)
        if prior.is_identity:
            return prior
        # The first selection was made against the nominal reference, whose deepest
        # points over the faces that moved more bias the scale towards 1 (hex nut at
        # 0.98: 0.9833). One more sparse selection against the fitted prior, and a
        # re-fit from it, remove most of that bias.
        # Repeated while the fit still turns the pose: the keying features of a scaled
        # part sit off the nominal at any turn, so the rigid re-fit above can end a
        # degree off (flange at 0.98: 1.09 degrees; 0.25 after one re-fit against the
        # prior).
        for _ in range(self.o.attempts - 1):
            refit = self.size_prior(self.select(pose, sparse=True, prior=prior), pose, prior.rigid(), axis=axis)
            if refit.is_identity:
                break
            step = rotation_deg(prior.rigid(pose), refit.rigid(pose))
            prior = refit
            if step < self.o.reselect_deg:
                break
        return prior

    def polish(self, pose: np.ndarray, prior: SizePrior, t: _Turn) -> np.ndarray:
        """The final turn (4, 4 pose), the silhouettes', when they decide it."""
        # The size fit keeps the turn (its rotation loses its component about the axis),
        # but its shift and tilt and the selections it stands on change the silhouettes'
        # best turn by tenths of a degree: the final turn is theirs, on the fine loss of
        # every third ray, about the turn judged before.
        if t.judged is None or t.axis is None or t.scan is None or t.confidence.ambiguous:
            return pose
        since = axis_turn_deg(t.judged, prior.placement(pose), t.axis)
        fine = self.judge(pose, prior, t.axis, t.scan.centre, True)
        return fine.turned(polish_turn(fine, -since, self.o.turn.polish_deg)[0])
