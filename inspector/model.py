"""Data model: cameras, rigs, captures, and the results that flow between stages.

Everything here is a frozen dataclass: stages never mutate what they receive, they
return new values (see :mod:`inspector.runner`). Arrays are numpy, units are mm.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from inspector.kernels import camera as camk
from inspector.kernels.deviation import deviation_stats
from inspector.kernels.prior import SizePrior

__all__ = [
    "Camera",
    "Rig",
    "Truth",
    "Capture",
    "Silhouette",
    "Reconstruction",
    "Alignment",
    "BcpsPoints",
    "Defect",
    "DeviationStats",
    "RegionSummary",
    "EvaluationSummary",
    "SUMMARY_FIELDS",
    "Evaluation",
    "InspectionResult",
]


def _frozen(a: Any, shape: tuple[int, ...] | None = None) -> np.ndarray:
    arr = np.array(a, dtype=float)
    if shape is not None and arr.shape != shape:
        raise ValueError(f"expected shape {shape}, got {arr.shape}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Camera:
    """One calibrated camera (OpenCV pinhole model, mm).

    Attributes
    ----------
    name : str
    width, height : int
        Image size in pixels.
    K : (3, 3) float
    dist : (5,) float
        ``[k1, k2, p1, p2, k3]``.
    R : (3, 3) float
        World -> camera rotation.
    t : (3,) float
        World -> camera translation, mm.
    """

    name: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "K", _frozen(self.K, (3, 3)))
        d = np.zeros(5)
        given = np.ravel(np.asarray(self.dist, float)) if self.dist is not None else np.zeros(0)
        d[: min(5, given.size)] = given[:5]  # OpenCV order; missing terms are zero
        object.__setattr__(self, "dist", _frozen(d, (5,)))
        object.__setattr__(self, "R", _frozen(self.R, (3, 3)))
        object.__setattr__(self, "t", _frozen(np.ravel(self.t), (3,)))

    @property
    def centre(self) -> np.ndarray:
        """Optical centre in world mm, (3,)."""
        return camk.camera_centre(self.R, self.t)

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.dist))

    def project(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (N, 3) -> pixels (N, 2) and depths (N,)."""
        return camk.project(X, self.K, self.dist, self.R, self.t)

    def rays(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (N, 2) -> optical centre (3,) and unit world directions (N, 3)."""
        return camk.pixel_rays(uv, self.K, self.dist, self.R, self.t)

    def footprint_mm(self, point: np.ndarray | None = None) -> float:
        """Size of one pixel, in mm, at ``point`` (default: the world origin)."""
        p = np.zeros(3) if point is None else np.asarray(point, float)
        z = float((self.R @ p + self.t)[2])
        return z / float(np.sqrt(self.K[0, 0] * self.K[1, 1]))

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "width": int(self.width),
            "height": int(self.height),
            "K": self.K.tolist(),
            "dist": self.dist.tolist(),
            "R": self.R.tolist(),
            "t": self.t.tolist(),
        }


@dataclass(frozen=True, eq=False)
class Rig:
    """The cameras of one rig, in a fixed order."""

    cameras: tuple[Camera, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "cameras", tuple(self.cameras))

    def __len__(self) -> int:
        return len(self.cameras)

    def __iter__(self):
        return iter(self.cameras)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.cameras)

    def camera(self, name: str) -> Camera:
        for c in self.cameras:
            if c.name == name:
                return c
        raise KeyError(name)

    def footprint_mm(self) -> float:
        """Median pixel footprint at the rig centre, mm."""
        return float(np.median([c.footprint_mm() for c in self.cameras]))

    def to_json(self) -> dict[str, Any]:
        return {"units": "mm", "cameras": [c.to_json() for c in self.cameras]}


@dataclass(frozen=True, eq=False)
class Truth:
    """Ground truth of a simulated capture (``truth/`` in a capture folder).

    Attributes
    ----------
    mesh_path : Path or None
        ``truth/part.ply``: the true surface in world mm.
    info : mapping
        ``truth/truth.json``: true pose, scale, defects.
    vertices, faces : arrays or None
        The true surface when held in memory (simulated captures not written to disk).
    """

    mesh_path: Path | None
    info: Mapping[str, Any] = field(default_factory=dict)
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None

    def mesh_arrays(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(V, 3) vertices and (F, 3) faces of the true surface, or None when unknown."""
        if self.vertices is not None and self.faces is not None:
            return self.vertices, self.faces
        if self.mesh_path is not None and Path(self.mesh_path).is_file():
            import trimesh

            m: Any = trimesh.load(self.mesh_path, force="mesh", process=False)
            return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
        return None


@dataclass(frozen=True, eq=False)
class Capture:
    """One trigger of the rig.

    Attributes
    ----------
    name : str
        Capture identifier (the folder name for replayed captures).
    rig : Rig
    images : Mapping[str, np.ndarray]
        Camera name -> image (H, W) or (H, W, C), uint8 or uint16.
    backgrounds : Mapping[str, np.ndarray]
        Camera name -> image of the empty rig (may be empty).
    polarity : str
        ``"dark-object"`` or ``"bright-object"``.
    metadata : Mapping[str, Any]
        Extra keys of ``capture.json``.
    source : Path | None
        Folder the capture was read from.
    truth : Truth | None
    """

    name: str
    rig: Rig
    images: Mapping[str, np.ndarray]
    backgrounds: Mapping[str, np.ndarray] = field(default_factory=dict)
    polarity: str = "dark-object"
    metadata: Mapping[str, Any] = field(default_factory=dict)
    source: Path | None = None
    truth: Truth | None = None


@dataclass(frozen=True, eq=False)
class Silhouette:
    """Segmentation of one camera image.

    Attributes
    ----------
    camera : str
    mask : (H, W) bool
        True on the object.
    soft : (H, W) float32
        Object coverage in [0, 1] estimated from the grey levels; its 0.5 level is the
        sub-pixel contour.
    contour : (M, 2) float
        Sub-pixel contour points ``(u, v)`` spaced about one pixel apart, excluding
        points on the image border.
    touches_border : bool
        The silhouette reaches the image border: outside the image is unknown, not empty.
    edge_px : float
        Uncertainty of the sub-pixel contour beyond image noise, px: 0 for anti-aliased
        images, a few tenths for hard-edged ones (their pixel staircase, smoothed).
    support : (y0, y1, x0, x1) int or None
        Rows ``y0:y1`` and columns ``x0:x1`` that hold the object with a margin: outside
        them the mask is False and the coverage below 0.5 (0 where it was not computed),
        so kernels look for the object there only. None: anywhere in the image.
    """

    camera: str
    mask: np.ndarray
    soft: np.ndarray
    contour: np.ndarray
    touches_border: bool = False
    edge_px: float = 0.0
    support: tuple[int, int, int, int] | None = None


@dataclass(frozen=True, eq=False)
class Reconstruction:
    """Visual hull of the silhouettes.

    Attributes
    ----------
    points : (N, 3) float
        Surface points, world mm.
    normals : (N, 3) float
        Outward unit normals.
    vertices, faces : (V, 3) float, (F, 3) int
        Display mesh.
    voxel_mm : float
    """

    points: np.ndarray
    normals: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    voxel_mm: float


@dataclass(frozen=True, eq=False)
class Alignment:
    """Pose of the reference in the rig frame.

    Attributes
    ----------
    pose : (4, 4) float
        Reference -> world transform.
    fitness : float
        Fraction of reconstruction points within the inlier distance.
    rmse_mm : float
    method : str
    """

    pose: np.ndarray
    fitness: float
    rmse_mm: float
    method: str = ""
    confidence: PoseConfidence | None = None


@dataclass(frozen=True)
class PoseConfidence:
    """How firmly the data fix the pose's turn about the reference's axis of near-symmetry.

    Attributes
    ----------
    axis : (3,) tuple of float or None
        Unit axis of near-symmetry, reference frame (None: the reference has none, e.g. a
        box; nothing below is then measured).
    symmetry_deg : tuple of float
        Turns about the axis that map the reference onto itself (its own symmetries, which
        are not ambiguities), degrees.
    hull_range_deg : tuple of float
        The turns, degrees (negative and positive), about the pose within which the
        reference stays inside the part's visual hull: how far the silhouettes alone
        allow the pose to turn.
    runner_up_deg : float or None
        The best other turn (neither near the pose nor near a symmetry, and inside the
        hull), degrees; None when no other turn competes (every other one leaves the hull
        or is near a symmetry, or the silhouettes show a single basin).
    margin : float or None
        How much worse the data fit at ``runner_up_deg`` than at the pose: the mean Tukey
        loss at ``cutoff_mm`` (0: every residual zero; 1: every one beyond the cutoff) at the
        runner-up minus at the pose. The built-in ``bcps`` stages judge the silhouettes: the
        residuals are the contour rays' smallest distances to the reference, each turn at
        its own best (:func:`inspector.kernels.bcps.ray_min_distance`).
    margin_points : int or None
        ``margin`` times the number of contour points (or points): about how many pin the turn.
    cutoff_mm : float
        The loss's cutoff, mm.
    ambiguous : bool
        Whether the runner-up fits about as well (``margin_points`` below a few dozen):
        the features that key the part do not decide its turn in these images.
    """

    axis: tuple[float, float, float] | None = None
    symmetry_deg: tuple[float, ...] = ()
    hull_range_deg: tuple[float, float] = (0.0, 0.0)
    runner_up_deg: float | None = None
    margin: float | None = None
    margin_points: int | None = None
    cutoff_mm: float = 0.0
    ambiguous: bool = False

    def to_json(self) -> dict[str, Any]:
        return {
            "axis": None if self.axis is None else [float(v) for v in self.axis],
            "symmetry_deg": [float(v) for v in self.symmetry_deg],
            "hull_range_deg": [float(v) for v in self.hull_range_deg],
            "runner_up_deg": self.runner_up_deg,
            "margin": self.margin,
            "margin_points": self.margin_points,
            "cutoff_mm": float(self.cutoff_mm),
            "ambiguous": bool(self.ambiguous),
        }


@dataclass(frozen=True, eq=False)
class BcpsPoints:
    """Best-case coherent points, one per contour point per camera.

    Attributes
    ----------
    points : (N, 3) float
        World mm.
    deviation : (N,) float
        Signed distance to the aligned reference, mm (negative inside).
    camera : (N,) int
        Index of the camera in the rig.
    pixel : (N, 2) float
        Contour point ``(u, v)`` the ray went through.
    segment_mm : (N,) float
        Length of the candidate segment on that ray, mm (NaN in a selection that only
        fed the pose search, which does not measure it).
    method : str
        ``"ray"`` or ``"surface"``.
    size : SizePrior or None
        The part's best-fit size model the selection was made against
        (:mod:`inspector.kernels.prior`); None: the nominal reference.
    """

    points: np.ndarray
    deviation: np.ndarray
    camera: np.ndarray
    pixel: np.ndarray
    segment_mm: np.ndarray
    method: str
    size: SizePrior | None = None


@dataclass(frozen=True)
class Defect:
    """A cluster of points outside tolerance."""

    kind: str  # "missing" or "excess"
    position: tuple[float, float, float]
    extent: tuple[float, float, float]
    n_points: int
    worst_mm: float
    region: str

    def to_json(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "position": list(self.position),
            "extent": list(self.extent),
            "n_points": self.n_points,
            "worst_mm": self.worst_mm,
            "region": self.region,
        }


@dataclass(frozen=True)
class DeviationStats:
    """Summary of signed deviations, mm (negative: missing material)."""

    mean: float
    std: float
    min: float
    max: float
    p01: float
    p99: float
    mean_abs: float

    @classmethod
    def of(cls, deviation: np.ndarray) -> DeviationStats | None:
        """The summary of ``deviation`` (N,), None when there is none."""
        d = deviation_stats(np.asarray(deviation, float))
        return cls(**d) if d else None

    def to_json(self) -> dict[str, float]:
        return {"mean": self.mean, "std": self.std, "min": self.min, "max": self.max, "p01": self.p01,
                "p99": self.p99, "mean_abs": self.mean_abs}


@dataclass(frozen=True)
class RegionSummary:
    """One tolerance region of a part: its band, and the BCPS points that fell in it.

    ``name`` is ``"default"`` for the points of no named region.
    """

    name: str
    lower_mm: float
    upper_mm: float
    n_points: int
    out_of_tolerance_points: int
    deviation_mm: DeviationStats | None


@dataclass(frozen=True, eq=False)
class EvaluationSummary:
    """The evaluate stage's contract: what ``result.json``, the history and the CSV export
    read, whichever evaluate variant ran.

    An evaluate stage declares ``StageSpec(summary=EvaluationSummary)`` (or a dataclass with
    at least the fields of :data:`SUMMARY_FIELDS`: a subclass, to add its own), checked when
    the plugin registers, and sets ``Evaluation(summary=...)``, checked by the runner.

    Attributes
    ----------
    n_points : int
        Points evaluated (BCPS points).
    deviation_mm : DeviationStats or None
        Their signed deviations; None without points.
    tolerance_mm : (float, float)
        The default band, ``(lower, upper)``.
    within_tolerance : float
        Share of the points within their band, 0..1.
    out_of_tolerance_points : int
    regions : tuple of RegionSummary
        Optional: per region, ``"default"`` first (the CSV export's ``regions.csv``).
    point_region : (N,) int or None
        Optional: per BCPS point, its index in ``regions``.
    """

    n_points: int
    deviation_mm: DeviationStats | None
    tolerance_mm: tuple[float, float]
    within_tolerance: float
    out_of_tolerance_points: int
    regions: tuple[RegionSummary, ...] = ()
    point_region: np.ndarray | None = None

    def to_json(self) -> dict[str, Any]:
        """The ``stats`` keys of ``result.json`` this summary fills (as before it existed)."""
        return {
            "n_points": int(self.n_points),
            "deviation_mm": self.deviation_mm.to_json() if self.deviation_mm is not None else {},
            "within_tolerance": float(self.within_tolerance),
            "out_of_tolerance_points": int(self.out_of_tolerance_points),
            "tolerance_mm": {"lower": float(self.tolerance_mm[0]), "upper": float(self.tolerance_mm[1])},
        }


#: The fields an evaluate stage must fill (those of :class:`EvaluationSummary` without default).
SUMMARY_FIELDS = ("n_points", "deviation_mm", "tolerance_mm", "within_tolerance", "out_of_tolerance_points")


@dataclass(frozen=True, eq=False)
class Evaluation:
    """Tolerance verdict of one part.

    ``summary`` is the typed contract (:class:`EvaluationSummary`); ``stats`` holds whatever
    else the variant reports (written to ``result.json`` ``stats``, after the summary's keys).
    """

    verdict: str  # "pass" | "fail" | "error" (with ``error``: e.g. defects a turned pose would explain)
    stats: Mapping[str, Any]
    defects: tuple[Defect, ...]
    out_of_tolerance: np.ndarray  # (N,) bool, per BCPS point
    summary: EvaluationSummary | None = None
    error: str | None = None


@dataclass(frozen=True, eq=False)
class InspectionResult:
    """Everything one inspection produced; what the outputs write."""

    capture: str
    recipe: str
    verdict: str  # "pass" | "fail" | "error"
    error: str | None
    timings_s: Mapping[str, float]
    pose: np.ndarray | None = None
    stats: Mapping[str, Any] = field(default_factory=dict)
    defects: tuple[Defect, ...] = ()
    reconstruction: Reconstruction | None = None
    bcps: BcpsPoints | None = None
    rig: Rig | None = None
    #: capture.json's keys but polarity (part_id, timestamp, extras); {} when unknown.
    metadata: Mapping[str, Any] = field(default_factory=dict)
    #: The recipe file (absolute) and the SHA-256 of its bytes, when it came from a file.
    recipe_path: str | None = None
    recipe_sha256: str | None = None
    #: The evaluate stage's summary (None: no evaluate stage, or an error).
    summary: EvaluationSummary | None = None
    #: What stages put in ``context.extras``, JSON-safe (``result.json`` ``extras``).
    extras: Mapping[str, Any] = field(default_factory=dict)
