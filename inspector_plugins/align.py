"""Stage ``align.global_icp``: pose of the reference from any orientation, robust ICP.

The BCPS stage finishes the alignment on the selected points (select, re-align, select).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from inspector import hookimpl
from inspector.errors import StageError
from inspector.kernels.registration import align_reference
from inspector.params import param
from inspector.pipeline import InspectionContext
from inspector.registry import StageRegistry, StageSpec


@dataclass(frozen=True)
class AlignParams:
    voxel_mm: float = param(1.0, "down-sampling of the global search, mm", min=0.05, max=100.0)
    inlier_mm: float = param(2.0, "distance under which a point counts as matched, mm (a part off by more is a wrong part)", min=0.01, max=100.0)
    min_fitness: float = param(0.3, "fraction of matched points under which alignment has failed (wrong reference?)", min=0.0, max=1.0)
    seed: int = param(0, "random seed of the global search (results are deterministic)", min=0, max=2**31 - 1)


def run_align(ctx: InspectionContext, p: AlignParams) -> InspectionContext:
    recon = ctx.need("reconstruction", "align")
    ref = ctx.need("reference", "align")
    a = align_reference(
        recon.points, recon.normals, ref.vertices, ref.faces, voxel_mm=p.voxel_mm, inlier_mm=p.inlier_mm, seed=p.seed,
        index=ref.distance,
    )
    if a.fitness < p.min_fitness:
        raise StageError(
            f"the reference does not match the reconstruction (fitness {a.fitness:.2f} < {p.min_fitness:.2f}): "
            f"{_size_hint(ref.vertices, recon.points)}"
        )
    return ctx.evolve(alignment=a)


#: Size ratios (reference / part) that betray a unit mistake, and what it then likely is.
_UNIT_RATIOS = ((1e-3, "a mesh in metres?"), (1e3, "a mesh in micrometres?"), (1 / 25.4, "a mesh in inches?"))


def _size_hint(ref_vertices: np.ndarray, points: np.ndarray) -> str:
    """Why a reference may not match: its size against the reconstruction's (bounding-box
    diagonals, mm), and the likely unit mistake when their ratio is one."""
    size = float(np.linalg.norm(np.ptp(ref_vertices, axis=0)))
    part = float(np.linalg.norm(np.ptp(points, axis=0)))
    ratio = max(size, 1e-12) / max(part, 1e-12)
    # A hull's bulges make the part look up to ~1.5x its size; the units are 25x apart.
    unit = next((why for r, why in _UNIT_RATIOS if abs(np.log(ratio / r)) < np.log(2.0)), "wrong reference or part?")
    return f"the reference is {size:.3g} mm across, the part {part:.3g} mm: {unit}"


@hookimpl
def inspector_register_stages(registry: StageRegistry) -> None:
    registry.add(
        StageSpec(
            name="align.global_icp",
            run=run_align,
            params=AlignParams,
            requires=("carve",),
            doc="Global registration from any orientation, then robust point-to-plane ICP",
        )
    )
