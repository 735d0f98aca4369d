"""Pose and size of catalogue parts whose origin (bounding-box centre) is far from their surface: the butterfly
valve (a wafer ring with a lever along +x: L-shaped) was recognised in the catalogue benchmark but never fitted
(ICP fitness 0.19-0.68) and 3 of its 8 clusters failed the size test (issue #15, benchmarks/history/catalogue.md)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from semslam.recognition.plausibility import principal_extent
from semslam.pose.estimate import estimate_object_pose, prepare_pose_model
from semslam.pose.search import ViewCentroids
from semslam.simulation.cad_models import models_view_clouds
from semslam.simulation.catalogue import catalogue_objects
from semslam.simulation.kinect import POSE_MODEL_KINECT, SURVEY_KINECT


@pytest.fixture(scope="module")
def butterfly():
    models = {"butterfly_valve": catalogue_objects()["butterfly_valve"]}
    model_views, classes = models_view_clouds(models, seed=0, config=POSE_MODEL_KINECT, tied_rests=True)
    return models, model_views, classes


def test_view_centroids_of_a_sphere_and_a_plate():
    rng = np.random.default_rng(0)
    n = rng.normal(size=(4000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    vc = ViewCentroids.build(0.1 * n, n)
    strict, sheet = vc.lookup(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]))
    # the lit hemisphere's centroid is r/2 towards the viewer (the radius rule's guess, exact for a sphere); the
    # strict depth buffer drops grazing samples and lands nearer the viewer
    np.testing.assert_allclose(sheet, [[0, 0, 0.05], [0.05, 0, 0]], atol=0.006)
    assert 0.055 < strict[0, 2] < 0.07 and 0.055 < strict[1, 0] < 0.07
    g = np.arange(-0.1, 0.1001, 0.005)  # 5 mm samples (the pose models' visibility samples are 6 mm apart)
    plate = np.column_stack([np.repeat(g, len(g)), np.tile(g, len(g)), np.zeros(len(g) ** 2)])
    up = np.tile([0.0, 0.0, 1.0], (len(plate), 1))
    got = ViewCentroids.build(plate + [0.3, 0.0, 0.0], up).lookup(np.array([[0.0, 0.0, 1.0]]))[:, 0]
    np.testing.assert_allclose(got, [[0.3, 0.0, 0.0]] * 2, atol=0.01)  # on the plate, not in front of it
    # two plates 5 cm apart: seen from above, the lower one is hidden (it was in the facing-only centroid)
    two = np.vstack([plate, plate - [0.0, 0.0, 0.05]])
    got = ViewCentroids.build(two, np.vstack([up, up])).lookup(np.array([[0.0, 0.0, 1.0]]))[:, 0]
    np.testing.assert_allclose(got[:, 2], [0.0, 0.0], atol=0.005)


def test_l_shaped_part_is_fitted_from_views_the_radius_start_missed(butterfly):
    """Before the fix the translation started ~10 cm from the truth for most orientations (the 3 cm translation
    steps never pulled it in): views at 60, 180 and 300 degrees gave fitness 0.39-0.68 and 43-178 degree
    rotation errors; now all fit (measured 0.98-0.99, 0.2 degrees)."""
    models, model_views, classes = butterfly
    model = prepare_pose_model([c for _, _, c in model_views])
    cfg = dataclasses.replace(SURVEY_KINECT, elevation_rad=float(np.radians(60.0)))
    queries, _ = models_view_clouds(models, seed=3, config=cfg, n_views=6)
    R = Rotation.from_euler("xyz", [20, -35, 110], degrees=True).as_matrix()
    t = np.array([0.1, -0.2, 1.4])
    for _, view_id, cloud in queries[1::2]:
        est = estimate_object_pose(cloud.points_xyz_m @ R.T + t, model, symmetry=classes["butterfly_valve"]["symmetry"],
                                   viewpoint_xyz_m=R @ cloud.viewpoint_xyz_m + t)
        R_err = est.T_scanner_object.rotation.T @ R
        angle = np.degrees(np.arccos(np.clip((np.trace(R_err) - 1) / 2, -1, 1)))
        assert est.fitness >= 0.95 and angle < 3.0, (view_id, est.fitness, angle)
        assert np.linalg.norm(est.T_scanner_object.translation_m - t) < 0.005, view_id


def test_size_limit_admits_the_whole_l_shaped_part(butterfly):
    """The size test measures clusters along their principal axes: the whole butterfly valve is 0.299 m that way
    against a 0.232 m box side, and the box-side limit (0.277 m) rejected it. ``size_reference="principal"``
    admits it; box-like classes keep their limit; the default (``"box"``) is the old rule."""
    from semslam.errors import InputError
    from semslam.pipeline import PipelineConfig, ScanRecognizer
    from semslam.recognition import build_database

    parts = catalogue_objects()
    models = {"butterfly_valve": parts["butterfly_valve"], "flange": parts["flange"]}
    views, classes = models_view_clouds(models, seed=0, config=SURVEY_KINECT, n_views=3)
    model_views, _ = models_view_clouds(models, seed=0, config=POSE_MODEL_KINECT, tied_rests=True)
    db = build_database(views, classes, seed=0, model_views=model_views)
    rec = ScanRecognizer(db, PipelineConfig(size_reference="principal"))
    mesh = parts["butterfly_valve"].mesh
    whole = principal_extent(np.ascontiguousarray(trimesh.sample.sample_surface(mesh, 20000, seed=0)[0]))[0]
    box_limit = 1.15 * float(np.max(parts["butterfly_valve"].size_xyz_m)) + 0.01
    assert whole > box_limit
    assert rec.class_size_limit_m("butterfly_valve") >= whole
    assert rec.class_size_limit_m("flange") == pytest.approx(1.15 * 0.2 + 0.01, abs=0.004)
    assert rec.max_plausible_extent_m() == max(rec.class_size_limit_m(c) for c in rec.db.classes)
    box = ScanRecognizer(db)  # the default: the bounding box's longest side
    assert box.class_size_limit_m("butterfly_valve") == pytest.approx(box_limit)
    with pytest.raises(InputError, match="size_reference"):
        PipelineConfig(size_reference="diagonal")
    assert PipelineConfig.from_dict(PipelineConfig(size_reference="principal").to_dict()).size_reference == "principal"
