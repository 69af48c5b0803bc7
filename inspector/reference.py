"""The aligned CAD reference: its mesh and signed distances to it.

Distances and closest points come from :class:`~inspector.kernels.meshdist.MeshDistance`
(exact, float64, built once per reference on first use); Open3D's raycasting scene answers
only the queries outside the index's band.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from inspector.kernels.axis import TurnZone

__all__ = ["Reference"]


@dataclass(frozen=True, eq=False)
class Reference:
    """A watertight reference mesh in its own frame (mm).

    Attributes
    ----------
    name : str
        Where it came from (file path or ``builtin:NAME``).
    vertices : (V, 3) float
    faces : (F, 3) int
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray

    @classmethod
    def load(cls, spec: str) -> Reference:
        """Load ``builtin:NAME`` or an STL/PLY/OBJ file; raises ReferenceMeshError."""
        from inspector.parts import load_reference

        # Keep the CAD coordinates: poses and regions are expressed in them.
        mesh = load_reference(spec, recentre=False)
        return cls(str(spec), np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64))

    @classmethod
    def from_mesh(cls, name: str, mesh: Any) -> Reference:
        return cls(name, np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64))

    @cached_property
    def _scene(self) -> Any:
        import open3d as o3d

        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(
            o3d.core.Tensor(self.vertices.astype(np.float32)),
            o3d.core.Tensor(self.faces.astype(np.uint32)),
        )
        return scene

    @cached_property
    def distance(self) -> Any:
        """Exact signed distance in the reference frame (:class:`~inspector.kernels.meshdist.MeshDistance`,
        built on first use; Open3D answers the rare queries outside its band)."""
        from inspector.kernels.meshdist import MeshDistance

        return MeshDistance(self.vertices, self.faces, fallback=self._open3d_signed_distance,
                            fallback_closest=self._open3d_closest)

    def _open3d_closest(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        import open3d as o3d

        ans = self._scene.compute_closest_points(o3d.core.Tensor(np.asarray(p, np.float32)))
        return ans["points"].numpy().astype(float), ans["primitive_ids"].numpy().astype(np.int64)

    def _open3d_signed_distance(self, p: np.ndarray) -> np.ndarray:
        import open3d as o3d

        d = self._scene.compute_signed_distance(o3d.core.Tensor(np.asarray(p, np.float32)), nsamples=1)
        return d.numpy().astype(float)

    def signed_distance(self, points: np.ndarray, pose: np.ndarray | None = None) -> np.ndarray:
        """Signed distance of world points to the reference placed by ``pose``.

        Parameters
        ----------
        points : (N, 3) float
            World mm.
        pose : (4, 4) float, optional
            Reference -> world transform (identity when None).

        Returns
        -------
        (N,) float
            mm, negative inside the reference (CONTRACT sign).
        """
        p = np.asarray(points, float).reshape(-1, 3)
        if pose is not None:
            R, t = pose[:3, :3], pose[:3, 3]
            p = (p - t) @ R  # world -> reference frame
        if len(p) == 0:
            return np.zeros(0)
        return self.distance(p)

    def surface_normals(self, points: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """Outward unit normals (world frame) of the reference surface at the points'
        closest points; (N, 3) world mm -> (N, 3)."""
        p = self.to_reference_frame(points, pose)
        _, tid = self.distance.closest(p)
        return self.distance.pn[tid, 0] @ pose[:3, :3].T  # the triangles' unit normals

    def to_reference_frame(self, points: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> reference frame, using ``pose`` (reference -> world)."""
        return (np.asarray(points, float) - pose[:3, 3]) @ pose[:3, :3]

    @cached_property
    def _turn_zones(self) -> dict[tuple[bytes, bytes], TurnZone]:
        return {}

    def turn_zone(self, axis: np.ndarray, centre: np.ndarray) -> TurnZone:
        """Where a turn about (``axis``, ``centre``) can change the distance to the reference
        (:func:`~inspector.kernels.axis.turn_zone`).

        Parameters
        ----------
        axis, centre : (3,) float
            Unit axis and a point on it, reference frame, mm.

        Returns
        -------
        TurnZone
            Built on first use for that axis (40-85 ms) and kept with the reference: it
            depends on the reference alone, so every part of a batch shares it.
        """
        # lazy: kernels.axis loads open3d (kernels.rigid), which `import inspector.recipe`
        # must not (tests/core/test_manager.py::test_import_inspector_is_light)
        from inspector.kernels.axis import turn_zone

        key = (np.asarray(axis, float).tobytes(), np.asarray(centre, float).tobytes())
        zones = self._turn_zones
        if key not in zones:
            zones[key] = turn_zone(self.distance.near, self.vertices, axis, centre)
        return zones[key]
