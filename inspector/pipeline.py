"""The inspection context that flows through the stages, and the tolerance specification.

Data flows one way: each stage receives the context, reads what earlier stages produced,
and returns a new context (``context.evolve(reconstruction=...)``) with its own output set.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from inspector.errors import StageError
from inspector.model import Alignment, BcpsPoints, Capture, Evaluation, Reconstruction, Silhouette
from inspector.reference import Reference

__all__ = ["Band", "Region", "Tolerance", "InspectionContext"]


@dataclass(frozen=True)
class Band:
    """Allowed signed deviation, mm: ``lower <= deviation <= upper``."""

    lower: float
    upper: float


@dataclass(frozen=True)
class Region:
    """A named region of the reference (axis-aligned box in the reference frame, mm)."""

    name: str
    box_min: tuple[float, float, float]
    box_max: tuple[float, float, float]
    band: Band

    def contains(self, points_ref: np.ndarray) -> np.ndarray:
        """(N, 3) reference-frame points -> (N,) bool."""
        lo = np.asarray(self.box_min)
        hi = np.asarray(self.box_max)
        return np.all((points_ref >= lo) & (points_ref <= hi), axis=1)


@dataclass(frozen=True)
class Tolerance:
    """Tolerance bands: a default band, and regions that override it (last one wins)."""

    default: Band = Band(-0.1, 0.1)
    regions: tuple[Region, ...] = ()


@dataclass(frozen=True, eq=False)
class InspectionContext:
    """Everything known about one inspection so far.

    Attributes
    ----------
    capture : Capture
    reference : Reference or None
    tolerance : Tolerance
    silhouettes : tuple of Silhouette, one per rig camera (after ``segment``)
    reconstruction : Reconstruction (after ``carve``)
    alignment : Alignment (after ``align``; ``bcps`` may refine it)
    bcps : BcpsPoints (after ``bcps``)
    evaluation : Evaluation (after ``evaluate``)
    extras : dict
        Free space for third-party stages (e.g. a classifier's label): kept, JSON-safe, in
        ``result.json`` ``extras``, the history and ``InspectionResult.extras``.
    settings : mapping
        Plugin name -> its validated recipe settings (``[plugins.NAME]``, see
        ``inspector_register_settings``); read-only.
    """

    capture: Capture
    reference: Reference | None
    tolerance: Tolerance = field(default_factory=Tolerance)
    silhouettes: tuple[Silhouette, ...] | None = None
    reconstruction: Reconstruction | None = None
    alignment: Alignment | None = None
    bcps: BcpsPoints | None = None
    evaluation: Evaluation | None = None
    extras: dict[str, Any] = field(default_factory=dict)
    settings: Mapping[str, Any] = field(default_factory=dict)

    def evolve(self, **changes: Any) -> InspectionContext:
        """A copy with ``changes`` applied."""
        return dataclasses.replace(self, **changes)

    def need(self, attr: str, stage: str) -> Any:
        """The value of ``attr``, or a StageError saying which earlier stage is missing."""
        value = getattr(self, attr)
        if value is None:
            raise StageError(f"stage {stage}: needs {attr}, which no earlier stage produced")
        return value
