"""The aligned CAD reference: its mesh and signed distances to it."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

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
        import open3d as o3d

        p = np.asarray(points, float).reshape(-1, 3)
        if pose is not None:
            R, t = pose[:3, :3], pose[:3, 3]
            p = (p - t) @ R  # world -> reference frame
        if len(p) == 0:
            return np.zeros(0)
        d = self._scene.compute_signed_distance(o3d.core.Tensor(p.astype(np.float32)), nsamples=1)
        return d.numpy().astype(float)

    def surface_normals(self, points: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """Outward unit normals (world frame) of the reference surface at the points'
        closest points; (N, 3) world mm -> (N, 3)."""
        import open3d as o3d

        p = self.to_reference_frame(points, pose)
        ans = self._scene.compute_closest_points(o3d.core.Tensor(p.astype(np.float32)))
        n = ans["primitive_normals"].numpy().astype(float)
        return n @ pose[:3, :3].T

    def to_reference_frame(self, points: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> reference frame, using ``pose`` (reference -> world)."""
        return (np.asarray(points, float) - pose[:3, 3]) @ pose[:3, :3]
