"""Outward face normals for meshes written by others (`semslam.simulation.mesh_orientation`): oracles are a box
(every outward normal points away from its centre), an open grid (one consistent side) and the shared valve-panel
base, a closed plate whose file winds half of its faces against their neighbours."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from tests._support.shared import require_shared
from semslam.simulation.mesh_orientation import orient_outward


def _outward(mesh: trimesh.Trimesh) -> np.ndarray:
    return np.einsum("ij,ij->i", mesh.face_normals, mesh.triangles_center - mesh.vertices.mean(axis=0)) > 0


def test_a_box_with_faces_wound_the_wrong_way_is_turned_outward():
    box = trimesh.creation.box((0.1, 0.2, 0.3))
    assert _outward(box).all()
    faces = box.faces.copy()
    faces[[0, 3, 7, 8, 11]] = faces[[0, 3, 7, 8, 11]][:, ::-1]
    fixed, n = orient_outward(trimesh.Trimesh(box.vertices, faces, process=False))
    assert n == 5 and _outward(fixed).all() and fixed.is_winding_consistent
    inside_out, n = orient_outward(trimesh.Trimesh(box.vertices, box.faces[:, ::-1], process=False))
    assert n == 12 and _outward(inside_out).all()
    same, n = orient_outward(box)
    assert n == 0 and np.array_equal(same.faces, box.faces)


def test_an_open_surface_is_wound_consistently_on_its_first_faces_side():
    x, y = np.meshgrid(np.arange(5.0), np.arange(5.0), indexing="ij")
    v = np.c_[x.ravel(), y.ravel(), np.zeros(25)]
    f = np.array([[5 * i + j, 5 * (i + 1) + j, 5 * i + j + 1] for i in range(4) for j in range(4)] +
                 [[5 * (i + 1) + j, 5 * (i + 1) + j + 1, 5 * i + j + 1] for i in range(4) for j in range(4)])
    up = trimesh.Trimesh(v, f, process=False).face_normals[:, 2]
    assert (np.abs(up) > 0.99).all() and len(set(np.sign(up))) == 1
    g = f.copy()
    g[[3, 10, 20]] = g[[3, 10, 20]][:, ::-1]
    fixed, n = orient_outward(trimesh.Trimesh(v, g, process=False))
    assert n == 3 and np.allclose(fixed.face_normals[:, 2], fixed.face_normals[0, 2])


def test_the_shared_valve_panel_base_is_closed_and_outward_once_oriented(shared_dir):
    path = require_shared(shared_dir / "data" / "models" / "tac_valve_base.obj", "shared real models")
    mesh = trimesh.load(path, force="mesh", process=False)
    mesh.merge_vertices()
    assert not mesh.is_winding_consistent  # as written
    fixed, n = orient_outward(mesh)
    assert n > 0 and fixed.is_winding_consistent and fixed.is_watertight and fixed.volume > 0
    # every face's normal points out of the plate (its bores included): a ray started a hair outside along the
    # normal crosses the surface an even number of times; as written, some crossed it an odd number
    assert (_crossings(fixed) % 2 == 0).all()
    assert (_crossings(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)) % 2 == 1).any()


def _crossings(mesh: trimesh.Trimesh) -> np.ndarray:
    origins = mesh.triangles_center + 1e-6 * mesh.face_normals
    _, rays = mesh.ray.intersects_id(origins, mesh.face_normals, multiple_hits=True)
    return np.bincount(rays, minlength=len(mesh.faces))


@pytest.mark.parametrize("name", ["blind_flange_4in_cl150.stl", "slipon_flange_6in_cl300.stl",
                                  "wetmate_receptacle.stl"])
def test_well_wound_shared_models_are_left_as_written(shared_dir, name):
    path = require_shared(shared_dir / "data" / "models" / name, "shared real models")
    mesh = trimesh.load(path, force="mesh", process=False)
    mesh.merge_vertices()
    fixed, n = orient_outward(mesh)
    assert n == 0 and np.array_equal(fixed.faces, mesh.faces)
