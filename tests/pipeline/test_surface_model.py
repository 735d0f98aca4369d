"""The model the part and fragment tests look for a cluster's points on (``ScanRecognizer.surface_model``): the
class's pose-model views and its recognition views together, so a surface only the recognition views reach counts
as the object's (the unseen parts' hot-stab receptacle: the bottom of its 19 cm bore, seen by the survey's steep
looks, not by the pose-model views at 60 deg; its ~50-point clusters were left unknown beside the recognised
receptacle). Here a plate with a deep bore whose bottom only the recognition views hold."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.detection import Detection
from semslam.pipeline import PipelineConfig, ScanRecognizer
from semslam.pipeline.parts import PartsConfig, _part_fitness
from semslam.pose.estimate import prepare_pose_model
from semslam.pose.model import SurfacePoints, _nearest
from semslam.recognition.database import ViewDatabase
from semslam.symmetry import Symmetry

STEP = 0.004


def _plate() -> np.ndarray:
    """A 20 x 20 cm plate at z = 0 with a 7 cm hole at its centre (object frame, z down into the bore)."""
    x, y = np.meshgrid(np.arange(-0.1, 0.1, STEP), np.arange(-0.1, 0.1, STEP), indexing="ij")
    p = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    return p[np.hypot(p[:, 0], p[:, 1]) > 0.035]


def _bottom() -> np.ndarray:
    """The bore's bottom, 19 cm below the plate."""
    x, y = np.meshgrid(np.arange(-0.03, 0.03, STEP), np.arange(-0.03, 0.03, STEP), indexing="ij")
    p = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 0.19)])
    return p[np.hypot(p[:, 0], p[:, 1]) < 0.03]


def _database(with_model_views: bool = True) -> ViewDatabase:
    """Classes a, b, c of 4 views each (histograms in three blobs); class a's recognition views hold the plate and
    the bore's bottom, its pose-model views (when stored) the plate only."""
    rng = np.random.default_rng(0)
    centres = rng.gamma(2.0, size=(3, 640))
    esf = np.vstack([c + rng.gamma(0.3, size=(4, 640)) for c in centres]).astype(np.float32)
    labels = np.repeat(np.array(list("abc")), 4)
    a_view = np.vstack([_plate(), _bottom()])
    other = _plate() * 0.5
    views = [a_view if lab == "a" else other for lab in labels]
    offsets = np.concatenate([[0], np.cumsum([len(v) for v in views])]).astype(np.int64)
    infos = {c: {"symmetry": Symmetry(), "size_xyz_m": np.array([0.2, 0.2, 0.19])} for c in "abc"}
    model = {}
    if with_model_views:
        plates = [_plate(), _plate()]
        model = {"model_labels": np.array(["a", "a"]),
                 "model_point_offsets": np.array([0, len(plates[0]), 2 * len(plates[0])], np.int64),
                 "model_points_xyz_m": np.vstack(plates).astype(np.float32),
                 "model_viewpoints_xyz_m": np.array([[0.0, -0.5, -0.5], [0.0, 0.5, -0.5]])}
    return ViewDatabase(labels, np.array([f"v{i}" for i in range(len(labels))]), offsets,
                        np.vstack(views).astype(np.float32), np.tile([0.0, 0.0, -0.7], (len(labels), 1)), esf,
                        np.ones((len(labels), 308), np.float32), infos, **model)


def _at_identity(label: str) -> Detection:
    return Detection(label, 0.1, np.eye(4), np.eye(6) * 1e-4, fitness=1.0, reliable=True, extras={"view_index": 0})


@pytest.fixture(scope="module")
def recognizer():
    return ScanRecognizer(_database(), PipelineConfig(verify_min_fitness=0.95, parts=PartsConfig(fragments=True)))


def test_a_piece_only_the_recognition_views_show_lies_on_the_surface_model(recognizer):
    bottom, plate = _bottom(), _plate()
    assert _part_fitness(recognizer, _at_identity("a"), "a", 0, [bottom, plate]) == [1.0, 1.0]
    # the pose model alone (what the search aligns to) has no bottom: 19 cm from every point of it
    assert recognizer.pose_model("a", 0) is not recognizer.surface_model("a", 0)

    class PoseModelOnly:
        config = recognizer.config

        def surface_model(self, label, view_index):
            return SurfacePoints.of_pose_model(recognizer.pose_model(label, view_index))

    assert _part_fitness(PoseModelOnly(), _at_identity("a"), "a", 0, [bottom, plate]) == [0.0, 1.0]


def test_points_off_the_object_are_not_on_the_surface_model(recognizer):
    beside = _bottom() + [0.0, 0.0, 0.05]  # 5 cm below the bore's bottom: inside the part's solid
    assert _part_fitness(recognizer, _at_identity("a"), "a", 0, [beside]) == [0.0]


def test_without_pose_model_views_or_with_the_matched_view_the_surface_is_the_pose_models():
    for db, cfg, view in ((_database(with_model_views=False), PipelineConfig(), 0),
                          (_database(), PipelineConfig(pose_model="view"), 1)):
        rec = ScanRecognizer(db, cfg)
        surface, model = rec.surface_model("a", view), rec.pose_model("a", view)
        assert surface.points_xyz_m is model.icp_target.points_xyz_m and surface.grid is model.radius_grid
        assert rec.surface_model("a", view) is surface  # cached: its KD-tree, when built, is built once


def test_the_surface_points_give_the_pose_models_nearest_distances(recognizer):
    """The surface of the same views is the pose model's ICP target: the same distances as the pose model's own
    nearest-point query (``pose.model._nearest``), within the radius grid's bound and beyond it (the KD-tree)."""
    views = recognizer.db.pose_views("a") + [recognizer.db.view_cloud(int(i)) for i in recognizer.db.views_of("a")]
    model = prepare_pose_model(views, recognizer.config.pose)
    surface = SurfacePoints.of_views(views, recognizer.config.pose)
    q = np.random.default_rng(1).uniform(-0.12, 0.22, size=(500, 3))
    for bound in (0.006, 0.05):
        np.testing.assert_array_equal(surface.distances(q, bound), _nearest(model, q, bound)[0])
