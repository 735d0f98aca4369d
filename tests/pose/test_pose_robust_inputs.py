"""The pose search on clusters a depth camera can produce: a point at the sensor origin (invalid depth kept)."""

from __future__ import annotations

import numpy as np

from semslam.cloud import PointCloud
from semslam.pose import estimate_object_pose
from semslam.pose.search import RangeImage


def test_range_image_ignores_points_at_or_behind_the_sensor():
    """Catches: NaN pixel coordinates (a point at the viewpoint) crashing the image ("negative dimensions")."""
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(200, 3)) * 0.02 + [0.0, 0.0, 0.4]
    clean = RangeImage.build(pts, np.zeros(3), cell_m=0.008)
    dirty = RangeImage.build(np.vstack([np.zeros((3, 3)), pts, [[0.0, 0.0, -0.3]]]), np.zeros(3), cell_m=0.008)
    assert np.isfinite(dirty.range_min).sum() == np.isfinite(clean.range_min).sum() > 0
    assert np.array_equal(dirty.range_min, clean.range_min)


def test_pose_of_a_cluster_holding_the_sensor_origin_does_not_crash():
    rng = np.random.default_rng(1)
    box = rng.uniform(-1, 1, (3000, 3)) * [0.05, 0.03, 0.02]
    box[:, 2] = -0.02  # the face towards a sensor on -z
    model = PointCloud(box, viewpoint_xyz_m=[0.0, 0.0, -0.4], frame_id="object")
    cluster = np.vstack([box[::3] + [0.0, 0.0, 0.4], np.zeros((2, 3))])
    pose = estimate_object_pose(cluster, model)
    assert np.isfinite(pose.covariance_6x6).all()
    assert np.linalg.norm(pose.T_scanner_object.translation_m - [0.0, 0.0, 0.4]) < 0.03
