"""Stage ``align.global_icp``: pose of the reference from any orientation, robust ICP.

The BCPS stage finishes the alignment on the selected points (select, re-align, select).
"""

from __future__ import annotations

from dataclasses import dataclass

from inspector import hookimpl
from inspector.errors import StageError
from inspector.params import param
from inspector.pipeline import InspectionContext
from inspector.registry import StageRegistry, StageSpec


@dataclass(frozen=True)
class AlignParams:
    voxel_mm: float = param(1.0, "down-sampling of the global search, mm", min=0.05)
    inlier_mm: float = param(2.0, "distance under which a point counts as matched, mm (a part off by more is a wrong part)", min=0.01)
    min_fitness: float = param(0.3, "fraction of matched points under which alignment has failed (wrong reference?)", min=0.0, max=1.0)
    seed: int = param(0, "random seed of the global search (results are deterministic)")


def run_align(ctx: InspectionContext, p: AlignParams) -> InspectionContext:
    from inspector.kernels.registration import align_reference

    recon = ctx.need("reconstruction", "align")
    ref = ctx.need("reference", "align")
    a = align_reference(
        recon.points, recon.normals, ref.vertices, ref.faces, voxel_mm=p.voxel_mm, inlier_mm=p.inlier_mm, seed=p.seed,
        index=ref.distance,
    )
    if a.fitness < p.min_fitness:
        raise StageError(
            f"align: the reference does not match the reconstruction (fitness {a.fitness:.2f} < {p.min_fitness:.2f}): wrong reference or part?"
        )
    return ctx.evolve(alignment=a)


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
