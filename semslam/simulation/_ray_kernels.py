"""Ray casting on triangle meshes with Embree (embreex): first hits and occlusion tests, vectorised.

Embree works in float32; coordinates are shifted by the mesh's bounding-box centre so that float32
keeps ~1e-6 m resolution over a 16 m tank.

For the laser scanner the scene is also split (:meth:`RayCaster.split`): the few *large* faces (the
tank) are intersected exhaustively in float64 by numba kernels, and the many small faces (the objects)
are grouped into bounding spheres so that only the rays that can reach one go to Embree (a scan of the
tank sends a few per cent of its rays to Embree instead of all of them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from embreex import rtcore_scene as rtcs
from embreex.mesh_construction import TriangleMesh
from numba import njit

#: Tolerance (m) of the inside-the-triangle test of large faces: closes cracks along shared edges.
EDGE_TOL_M = 1e-7
#: Margin (m) added to the bounding spheres of small faces (covers Embree's float32 rounding).
SPHERE_MARGIN_M = 1e-4


@dataclass(frozen=True, eq=False)
class SplitScene:
    """A scene split for ray culling (all arrays world frame, float64, metres).

    Attributes
    ----------
    large_ids : ndarray (L,) int64
        Scene face index of each large face.
    large_verts : ndarray (L, 3, 3)
        Vertices of each large face.
    large_v0, large_normal : ndarray (L, 3)
        First vertex and unit normal of each large face.
    large_edge_normal : ndarray (L, 3, 3)
        Unit in-plane normals of the three edges, pointing into the triangle.
    large_edge_offset : ndarray (L, 3)
        ``edge_normal . edge_start``: a point p is inside when ``edge_normal . p >= offset - EDGE_TOL_M``.
    sphere_centre, sphere_radius : ndarray (G, 3), (G,)
        Bounding spheres of the groups of small faces (radius inf: no culling).
    small_scene : EmbreeScene or None
        The small faces only (shifted by :attr:`RayCaster.offset`); None when there are none.
    small_ids : ndarray (S,) int64
        Scene face index of each primitive of ``small_scene``.
    """

    large_ids: np.ndarray
    large_verts: np.ndarray
    large_v0: np.ndarray
    large_normal: np.ndarray
    large_edge_normal: np.ndarray
    large_edge_offset: np.ndarray
    sphere_centre: np.ndarray
    sphere_radius: np.ndarray
    small_scene: object
    small_ids: np.ndarray

    def first_small_hit_ids(self, o32_shifted: np.ndarray, d32: np.ndarray, tfar32: np.ndarray) -> np.ndarray:
        """Scene face index of the first small face hit before ``tfar32`` (-1 if none)."""
        if self.small_scene is None or len(o32_shifted) == 0:
            return np.full(len(o32_shifted), -1, dtype=np.int64)
        prim = np.asarray(self.small_scene.run(o32_shifted, d32, dists=tfar32), dtype=np.int64)
        return np.where(prim >= 0, self.small_ids[np.maximum(prim, 0)], -1)

    def small_unobstructed(self, o32_shifted: np.ndarray, d32: np.ndarray, tfar32: np.ndarray) -> np.ndarray:
        """True where no small face lies on ``origin + t direction``, ``0 < t < tfar32``."""
        if self.small_scene is None or len(o32_shifted) == 0:
            return np.ones(len(o32_shifted), dtype=bool)
        return np.asarray(self.small_scene.run(o32_shifted, d32, dists=tfar32, query="OCCLUDED")) < 0


class RayCaster:
    """An Embree scene of one mesh (concatenate several with :func:`trimesh.util.concatenate`)."""

    def __init__(self, mesh: trimesh.Trimesh):
        self.mesh = mesh
        self._offset = mesh.bounds.mean(axis=0)
        self._scene = rtcs.EmbreeScene()
        TriangleMesh(self._scene, (mesh.vertices[mesh.faces] - self._offset).astype(np.float32))
        self.face_normals = np.asarray(mesh.face_normals, dtype=float)
        self.v0 = self._v0 = np.asarray(mesh.vertices[mesh.faces[:, 0]], dtype=float)
        self._split: dict[tuple, SplitScene] = {}

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

    def unobstructed(self, origins: np.ndarray, directions: np.ndarray, dist_m: np.ndarray) -> np.ndarray:
        """True where nothing lies on the segment ``origin + t * direction``, ``0 < t < dist_m``."""
        o = np.ascontiguousarray(origins - self._offset, dtype=np.float32)
        if len(o) == 0:
            return np.zeros(0, dtype=bool)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        occ = self._scene.run(o, d, dists=np.ascontiguousarray(dist_m, dtype=np.float32), query="OCCLUDED")
        return np.asarray(occ) < 0

    def split(self, group_size_m: float = 0.5, max_large_faces: int = 256) -> SplitScene:
        """The scene split for culling (built once per caster and parameters, then cached).

        A face is *large* when a vertex lies more than ``group_size_m`` from its centroid; the other
        faces are grouped by the ``group_size_m`` cell of their centroid, one bounding sphere per group.
        With more than ``max_large_faces`` large faces nothing is split (every ray goes to Embree).
        """
        key = (float(group_size_m), int(max_large_faces))
        if key not in self._split:
            self._split[key] = _build_split(self.mesh, self._offset, self.face_normals, *key)
        return self._split[key]


def _build_split(mesh: trimesh.Trimesh, offset: np.ndarray, normals: np.ndarray, group_size_m: float,
                 max_large_faces: int) -> SplitScene:
    tris = np.asarray(mesh.vertices, dtype=float)[mesh.faces]  # (F, 3, 3)
    centroid = tris.mean(axis=1)
    extent = np.linalg.norm(tris - centroid[:, None], axis=2).max(axis=1)
    valid = np.linalg.norm(normals, axis=1) > 0.5  # zero-area faces are never hit
    large = (extent > group_size_m) & valid
    split = large.sum() <= max_large_faces
    if not split:  # too many large faces: everything goes to Embree
        large[:] = False
    large_ids = np.flatnonzero(large)
    small_ids = np.flatnonzero(valid & ~large)
    t, n = tris[large_ids], normals[large_ids]
    edge_n = np.empty((len(large_ids), 3, 3))
    edge_c = np.empty((len(large_ids), 3))
    for e in range(3):
        a, b, c = t[:, e], t[:, (e + 1) % 3], t[:, (e + 2) % 3]
        en = np.cross(n, b - a)
        en *= np.sign(np.sum(en * (c - a), axis=1))[:, None]  # towards the opposite vertex
        en /= np.linalg.norm(en, axis=1)[:, None]
        edge_n[:, e] = en
        edge_c[:, e] = np.sum(en * a, axis=1)
    if split:
        centres, radii = _group_spheres(tris[small_ids], centroid[small_ids], group_size_m)
    else:  # one infinite sphere: no ray is culled
        centres, radii = np.zeros((1, 3)), np.array([np.inf])
    scene = None
    if len(small_ids):
        scene = rtcs.EmbreeScene()
        TriangleMesh(scene, (tris[small_ids] - offset).astype(np.float32))
    return SplitScene(
        large_ids,
        np.ascontiguousarray(t),
        np.ascontiguousarray(t[:, 0]),
        np.ascontiguousarray(n),
        edge_n,
        edge_c,
        centres,
        radii,
        scene,
        small_ids,
    )


def _group_spheres(tris: np.ndarray, centroid: np.ndarray, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Bounding spheres (centre = bounding-box centre, radius + margin) of faces grouped by centroid cell."""
    if len(tris) == 0:
        return np.zeros((0, 3)), np.zeros(0)
    _, group = np.unique(np.floor(centroid / cell_m).astype(np.int64), axis=0, return_inverse=True)
    group = group.ravel()
    n_groups = group.max() + 1
    lo = np.full((n_groups, 3), np.inf)
    hi = np.full((n_groups, 3), -np.inf)
    verts = tris.reshape(-1, 3)
    g3 = np.repeat(group, 3)
    np.minimum.at(lo, g3, verts)
    np.maximum.at(hi, g3, verts)
    centres = (lo + hi) / 2
    r = np.zeros(n_groups)
    np.maximum.at(r, g3, np.linalg.norm(verts - centres[g3], axis=1))
    return centres, r + SPHERE_MARGIN_M


@njit(cache=True, nogil=True, error_model="numpy")
def inside_large(f, px, py, pz, edge_n, edge_c):
    """True if the point (on face ``f``'s plane) lies inside large face ``f`` (with EDGE_TOL_M)."""
    for e in range(3):
        if edge_n[f, e, 0] * px + edge_n[f, e, 1] * py + edge_n[f, e, 2] * pz < edge_c[f, e] - EDGE_TOL_M:
            return False
    return True


def unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row-normalised vectors and their norms."""
    n = np.linalg.norm(v, axis=-1)
    return v / np.where(n > 0, n, 1.0)[..., None], n
