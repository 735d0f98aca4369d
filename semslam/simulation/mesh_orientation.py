"""Outward face normals for meshes written by others.

A model's face normals orient the model points of the pose's visibility term (a point is expected in a scan only
where its normal faces the sensor), so a face wound the wrong way makes the scan contradict the true pose. Files
from CAD exports are not always consistent: the shared valve-panel base (``tac_valve_base.obj``, a closed plate of
192 faces) has a third of its adjacent face pairs wound against each other. :func:`orient_outward` winds every face
consistently with its neighbours across shared edges, then turns each closed part whose signed volume is negative
inside out; an open part keeps the orientation of its first face (nothing tells its outside).
"""

from __future__ import annotations

from collections import deque

import numpy as np
import trimesh


def orient_outward(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, int]:
    """``mesh`` with consistent winding and closed parts outward, and the number of faces turned."""
    faces = np.asarray(mesh.faces, dtype=np.int64)
    n = len(faces)
    if n == 0:
        return mesh, 0
    pairs = np.asarray(mesh.face_adjacency, dtype=np.int64).reshape(-1, 2)
    edges = np.asarray(mesh.face_adjacency_edges, dtype=np.int64).reshape(-1, 2)
    # does a face run along its shared edge from a to b? Two consistently wound neighbours run it opposite ways
    same = _runs_forward(faces[pairs[:, 0]], edges) == _runs_forward(faces[pairs[:, 1]], edges)
    neighbours: list[list[tuple[int, bool]]] = [[] for _ in range(n)]
    for (f1, f2), s in zip(pairs.tolist(), same.tolist()):
        neighbours[f1].append((f2, s))
        neighbours[f2].append((f1, s))
    flip = np.zeros(n, dtype=bool)
    component = np.full(n, -1, dtype=np.int64)
    n_comp = 0
    for seed in range(n):  # breadth first over each connected part: a neighbour wound alike is turned
        if component[seed] >= 0:
            continue
        component[seed] = n_comp
        queue = deque([seed])
        while queue:
            f = queue.popleft()
            for g, s in neighbours[f]:
                if component[g] < 0:
                    component[g] = n_comp
                    flip[g] = flip[f] ^ s
                    queue.append(g)
        n_comp += 1
    wound = np.where(flip[:, None], faces[:, ::-1], faces)
    # a closed part (every edge shared by two of its faces: 3/2 adjacent pairs a face) with a negative volume is
    # inside out
    v = np.asarray(mesh.vertices, dtype=float)
    tri = v[wound]
    signed = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    volume = np.bincount(component, weights=signed, minlength=n_comp)
    n_faces = np.bincount(component, minlength=n_comp)
    n_pairs = np.bincount(component[pairs[:, 0]], minlength=n_comp) if len(pairs) else np.zeros(n_comp, np.int64)
    inside_out = (2 * n_pairs == 3 * n_faces) & (volume < 0)
    flip ^= inside_out[component]
    out = np.where(flip[:, None], faces[:, ::-1], faces)
    return trimesh.Trimesh(v, out, process=False), int(flip.sum())


def _runs_forward(faces: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """For each face (k, 3) and edge (k, 2) ``(a, b)`` of it: does the face's vertex order go from a to b?"""
    a, b = edges[:, 0], edges[:, 1]
    nxt = np.roll(faces, -1, axis=1)
    return ((faces == a[:, None]) & (nxt == b[:, None])).any(axis=1)
