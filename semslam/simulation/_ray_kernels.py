"""Ray casting on triangle meshes with Embree (embreex): first hits and occlusion tests, vectorised.

Embree works in float32; coordinates are shifted by the mesh's bounding-box centre so that float32
keeps ~1e-6 m resolution over a 16 m tank.
"""

from __future__ import annotations

import numpy as np
import trimesh
from embreex import rtcore_scene as rtcs
from embreex.mesh_construction import TriangleMesh


class RayCaster:
    """An Embree scene of one mesh (concatenate several with :func:`trimesh.util.concatenate`)."""

    def __init__(self, mesh: trimesh.Trimesh):
        self.mesh = mesh
        self._offset = mesh.bounds.mean(axis=0)
        self._scene = rtcs.EmbreeScene()
        TriangleMesh(self._scene, (mesh.vertices[mesh.faces] - self._offset).astype(np.float32))
        self.face_normals = np.asarray(mesh.face_normals, dtype=float)
        self.v0 = self._v0 = np.asarray(mesh.vertices[mesh.faces[:, 0]], dtype=float)

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distance along each unit ``direction`` to the first surface (inf if none) and the hit
        triangle index (-1 if none). ``origins``, ``directions``: (N, 3)."""
        o = np.ascontiguousarray(origins - self._offset, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        if len(o) == 0:
            return np.zeros(0), np.zeros(0, dtype=np.int64)
        tri = np.asarray(self._scene.run(o, d), dtype=np.int64)  # primitive ids only (fastest query)
        hit = tri >= 0
        dist = np.full(len(tri), np.inf)
        # exact float64 distance to the hit triangle's plane
        n = self.face_normals[tri[hit]]
        v0 = self._v0[tri[hit]]
        dist[hit] = np.sum((v0 - origins[hit]) * n, axis=1) / np.sum(directions[hit] * n, axis=1)
        return dist, tri

    @property
    def offset(self) -> np.ndarray:
        """Shift subtracted from world coordinates before Embree (float32 precision)."""
        return self._offset

    def first_hit_ids_raw(self, o32_shifted: np.ndarray, d32: np.ndarray) -> np.ndarray:
        """Hit triangle ids (-1 = none) for rays already shifted by :attr:`offset`, float32."""
        if len(o32_shifted) == 0:
            return np.zeros(0, dtype=np.int64)
        return np.asarray(self._scene.run(o32_shifted, d32), dtype=np.int64)

    def unobstructed_raw(self, o32_shifted: np.ndarray, d32: np.ndarray, dist_m: np.ndarray) -> np.ndarray:
        """:meth:`unobstructed` for rays already shifted by :attr:`offset`, float32."""
        if len(o32_shifted) == 0:
            return np.zeros(0, dtype=bool)
        occ = self._scene.run(o32_shifted, d32, dists=np.ascontiguousarray(dist_m, dtype=np.float32), query="OCCLUDED")
        return np.asarray(occ) < 0

    def unobstructed(self, origins: np.ndarray, directions: np.ndarray, dist_m: np.ndarray) -> np.ndarray:
        """True where nothing lies on the segment ``origin + t * direction``, ``0 < t < dist_m``."""
        o = np.ascontiguousarray(origins - self._offset, dtype=np.float32)
        if len(o) == 0:
            return np.zeros(0, dtype=bool)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        occ = self._scene.run(o, d, dists=np.ascontiguousarray(dist_m, dtype=np.float32), query="OCCLUDED")
        return np.asarray(occ) < 0


def unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row-normalised vectors and their norms."""
    n = np.linalg.norm(v, axis=-1)
    return v / np.where(n > 0, n, 1.0)[..., None], n
