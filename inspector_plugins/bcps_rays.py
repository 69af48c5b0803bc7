"""The rays and inside maps of the ``bcps`` stages, built once an inspection.

The stage adapter (:mod:`inspector_plugins.bcps`) runs several selections an inspection
(the pose search's, then the final one) on the same contour rays and silhouettes; this
module builds what they share on first use and keeps it for that inspection.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from inspector.errors import StageError
from inspector.kernels import bcps as bk
from inspector.kernels.extent import bounds_of
from inspector.kernels.silhouette import inside_map, inside_region
from inspector.kernels.threads import map_threads
from inspector.pipeline import InspectionContext

__all__ = ["ContourRays"]


class ContourRays:
    """Every camera's rays through its sub-pixel contour points, and the silhouettes' inside
    maps the ray method needs: built on first use, kept for one inspection."""

    def __init__(self, ctx: InspectionContext, compiled: bool) -> None:
        self.ctx, self.compiled = ctx, compiled
        self._views: tuple[list[bk.View], object | None] | None = None
        self._rays: dict[int, bk.Rays] = {}
        self._coarse: tuple[tuple[object, ...], list[bk.CoarseHull]] | None = None
        self._bounds: dict[float, np.ndarray] = {}

    def bounds(self, margin_mm: float) -> np.ndarray:
        """The reconstruction's box grown by ``margin_mm``: (2, 3) ``[min, max]``, mm."""
        if margin_mm not in self._bounds:
            pts = self.ctx.need("reconstruction", "bcps").points
            if len(pts) == 0:
                raise StageError("the reconstruction is empty")
            lo, hi = bounds_of(pts)
            self._bounds[margin_mm] = np.stack([lo - margin_mm, hi + margin_mm])
        return self._bounds[margin_mm]

    def views(self) -> tuple[list[bk.View], object | None]:
        """The silhouettes as :class:`~inspector.kernels.bcps.View` and, compiled, their stack."""
        if self._views is None:
            sils = self.ctx.need("silhouettes", "bcps")
            # OpenCV and numpy release the GIL: cameras in parallel. The compiled kernels pack each
            # map's region around the silhouette (16 x 5 MP: 320 MB of float32 never written).
            maps = map_threads(lambda s: inside_region(s.soft, support=s.support) if self.compiled else inside_map(s.soft), sils)
            views = [bk.View(cam, m, s.touches_border) for cam, m, s in zip(self.ctx.capture.rig.cameras, maps, sils)]
            stack = None
            if self.compiled:
                from inspector.kernels.hull_jit import stack_views

                stack = stack_views(views)
            self._views = (views, stack)
        return self._views

    def camera(self, i: int) -> bk.Rays:
        """Camera ``i``'s rays (:class:`~inspector.kernels.bcps.Rays`) and the depth range
        each can meet the reconstruction in."""
        if not self._rays:  # all cameras on the first ask, in parallel (the work releases the GIL)
            self._rays = dict(enumerate(map_threads(self._build, range(len(self.ctx.capture.rig.cameras)))))
        return self._rays[i]

    def _build(self, i: int) -> bk.Rays:
        cam, contour = self.ctx.capture.rig.cameras[i], self.ctx.need("silhouettes", "bcps")[i].contour
        recon = self.ctx.need("reconstruction", "bcps")
        origin, dirs = cam.rays(contour)
        # Only where the ray passes near the reconstruction (the hull is conservative). A pose
        # update can move a grazing ray's optimum far along it: every pass searches it all.
        t0, t1 = bk.ray_ranges(cam, contour, origin, dirs, recon.points, max(1.0, 2.0 * recon.voxel_mm),
                               compiled=self.compiled)
        return bk.Rays(origin, dirs, t0, t1)

    def all(self) -> list[bk.Rays]:
        """The rays of every camera with a contour, in camera order."""
        return [self.camera(i) for i, s in enumerate(self.ctx.need("silhouettes", "bcps")) if len(s.contour)]

    def coarse(self, cams: Sequence[int], bounds: np.ndarray, step_mm: float, accept_px: float) -> list[bk.CoarseHull] | None:
        """Cameras ``cams``' rays' coarse samples hull-tested (:func:`~inspector.kernels.bcps.coarse_hull`):
        once an inspection for these parameters, which every selection's search then reads
        (the hull does not move with the pose). None without the compiled kernels."""
        views, stack = self.views()
        if stack is None:
            return None
        key = (tuple(cams), np.asarray(bounds, np.float64).tobytes(), float(step_mm), float(accept_px))
        if self._coarse is None or self._coarse[0] != key:
            tables = bk.coarse_hull([(i, self.camera(i)) for i in cams], views, bounds, stack, step_mm=step_mm,
                                    accept_px=accept_px)
            self._coarse = (key, tables)
        return self._coarse[1]
