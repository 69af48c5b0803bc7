"""Stage ``carve.hull``: coarse-to-fine visual hull of the silhouettes."""

from __future__ import annotations

from dataclasses import dataclass

from inspector import hookimpl
from inspector.errors import StageError
from inspector.params import param
from inspector.pipeline import InspectionContext
from inspector.registry import StageRegistry, StageSpec


@dataclass(frozen=True)
class CarveParams:
    voxel_mm: float = param(0.5, "finest voxel edge, mm (only cells near the surface are refined)", min=0.1, max=10.0)
    coarse_mm: float = param(0.0, "edge of the starting cells, mm (0: chosen from the bounds)", min=0.0, max=1000.0)
    mesh: bool = param(False, "also make the hull's display mesh (reconstruction_mesh.ply): the inspection itself never reads it, "
                             "and it is a third of this stage's time")
    mesh_voxel_mm: float = param(0.0, "grid of the display mesh, mm (0: max(voxel, 0.5 mm))", min=0.0, max=100.0)


def run_carve(ctx: InspectionContext, p: CarveParams) -> InspectionContext:
    from inspector.kernels.carving import carve

    sils = ctx.need("silhouettes", "carve")
    cams = ctx.capture.rig.cameras
    recon = carve(
        cams,
        [s.mask for s in sils],
        voxel_mm=p.voxel_mm,
        open_border=[s.touches_border for s in sils],
        coarse_mm=p.coarse_mm or None,
        mesh_voxel_mm=p.mesh_voxel_mm or None,
        mesh=p.mesh,
        supports=[s.support for s in sils],
    )
    if len(recon.points) == 0:
        raise StageError("the silhouettes have no common volume (check the calibration in rig.json)")
    return ctx.evolve(reconstruction=recon)


@hookimpl
def inspector_register_stages(registry: StageRegistry) -> None:
    registry.add(
        StageSpec(
            name="carve.hull",
            run=run_carve,
            params=CarveParams,
            requires=("segment",),
            doc="Visual hull, coarse-to-fine: surface points with normals (and, with mesh, a display mesh)",
        )
    )
