"""The procedural catalogue of pipework parts (semslam.simulation.catalogue)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from semslam.simulation import ObjectModel
from semslam.simulation.catalogue import CATALOGUE_LABELS, catalogue_objects


@pytest.fixture(scope="module")
def parts() -> dict[str, ObjectModel]:
    return catalogue_objects()


def test_at_least_ten_classes_with_the_similar_pairs(parts):
    assert len(parts) >= 10
    assert list(parts) == list(CATALOGUE_LABELS)
    for pair in (("flange", "blind_flange"), ("elbow_45", "elbow_90"), ("equal_tee", "cross")):
        assert set(pair) <= set(parts)


def test_meshes_watertight_positive_volume_plausible_size(parts):
    for label, m in parts.items():
        assert m.label == label
        assert m.mesh.is_watertight and m.mesh.is_winding_consistent, label
        assert m.mesh.volume > 1e-5, label  # > 10 cm^3
        assert np.isfinite(m.mesh.vertices).all()
        assert np.allclose(m.mesh.bounds.mean(axis=0), 0.0, atol=1e-9), label  # canonical: bbox centred
        assert 0.09 <= m.size_xyz_m.max() <= 0.30, (label, m.size_xyz_m)  # DN50-DN100 parts: 10-30 cm
        assert m.size_xyz_m.min() >= 0.02, (label, m.size_xyz_m)
        assert m.resting_poses and m.resting_probabilities[0] > 0


def _xor_fraction(mesh: trimesh.Trimesh, axis, angle: float) -> float:
    """Volume of the mesh outside its rotated copy, as a fraction of its volume (0 for a symmetry)."""
    T = trimesh.transformations.rotation_matrix(angle, axis)
    diff = trimesh.boolean.difference([mesh, mesh.copy().apply_transform(T)], engine="manifold")
    return 0.0 if diff.is_empty else float(diff.volume) / float(mesh.volume)


def test_declared_symmetries_hold(parts):
    kinds = {m.symmetry.kind for m in parts.values()}
    assert kinds == {"none", "discrete", "continuous"}
    for label, m in parts.items():
        s = m.symmetry
        if s.kind == "none":
            continue
        angles = [2 * np.pi / s.order] if s.kind == "discrete" else [np.radians(37.0), np.radians(121.0)]
        for a in angles:
            assert _xor_fraction(m.mesh, s.axis_object, a) < 0.02, (label, s)
    # the asymmetric ones really are not symmetric about any canonical axis (half turn)
    for label in ("ball_valve", "butterfly_valve"):
        for axis in np.eye(3):
            assert _xor_fraction(parts[label].mesh, axis, np.pi) > 0.05, (label, axis)


def test_database_views_classify_themselves_leave_one_out(parts):
    """Smoke check: 8 Kinect survey views per class, chi-square nearest neighbour leave-one-out.
    Measured (seed 0): ESF 99.0 %, VFH 96.2 %, ESF+VFH 98.1 % of 104 views; floors set a little below."""
    from semslam.recognition import build_database
    from semslam.evaluation.classifier import leave_one_out
    from semslam.simulation.cad_models import models_view_clouds
    from semslam.simulation.kinect import SURVEY_KINECT

    views, classes = models_view_clouds(parts, seed=0, config=SURVEY_KINECT)
    db = build_database(views, classes, seed=0)
    assert db.n_views == 8 * len(parts)
    assert leave_one_out(db, descriptor="esf", classifier="chi2").accuracy >= 0.95
    assert leave_one_out(db, descriptor="esf+vfh", classifier="chi2").accuracy >= 0.95
