"""ScanRecognizer.warm_up (prepares the pose models and loads the kernels on a database view) changes no
result: the same detections, poses and covariances as a recognizer that was not warmed up."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.pipeline import PipelineConfig, ScanRecognizer


@pytest.fixture(scope="module")
def db(builtin_db_fresh):
    return builtin_db_fresh


def test_warm_up_changes_no_result(db):
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset

    mission = simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1)), seed=4)
    warm = ScanRecognizer(db, PipelineConfig())
    warm.warm_up()
    assert set(warm._pose_models) == set(db.classes)  # every class prepared
    cold = ScanRecognizer(db, PipelineConfig())
    n_det = 0
    for record in mission.scans[::6]:
        cloud = mission.load_scan(record.scan_id)
        a = warm.recognize(cloud, seed=record.scan_id)
        b = cold.recognize(cloud, seed=record.scan_id)
        assert [d.label for d in a.detections] == [d.label for d in b.detections]
        for da, dbb in zip(a.detections, b.detections):
            np.testing.assert_array_equal(da.T_sensor_object.matrix, dbb.T_sensor_object.matrix)
            np.testing.assert_array_equal(da.covariance_6x6, dbb.covariance_6x6)
        n_det += len(a.detections)
    assert n_det > 0


def test_warm_up_without_pose_prepares_models_only(db):
    rec = ScanRecognizer(db, PipelineConfig(estimate_pose=False))
    rec.warm_up()
    assert set(rec._pose_models) == set(db.classes)
