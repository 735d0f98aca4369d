"""ScanRecognizer on simulated laser scans: the objects in view are found with the right labels, the tank
remains are rejected, the pose is right, and bad input raises."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.cloud import PointCloud
from semslam.errors import InputError, RecognitionError
from semslam.pipeline import ClusterOutcome, PipelineConfig, ScanRecognizer
from semslam.recognition.plausibility import (
    cluster_extent_m,
    scan_angular_extent,
    size_plausible,
    touches_scan_border,
)


@pytest.fixture(scope="module")
def db(builtin_db_fresh):
    return builtin_db_fresh


@pytest.fixture(scope="module")
def mission():
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset

    return simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1)), seed=4)


def test_finds_the_objects_in_view_with_the_right_labels(db, mission):
    from semslam.simulation.truth import cluster_truth

    rec = ScanRecognizer(db, PipelineConfig(estimate_pose=False))
    n_true = n_whole = n_border = 0
    for record in mission.scans[::3]:  # ~11 scans, every object
        cloud = mission.load_scan(record.scan_id)
        result = rec.recognize(cloud, seed=record.scan_id)
        assert len(result.clusters) == result.segmentation.n_clusters
        for c in result.clusters:
            assert isinstance(c, ClusterOutcome)
            truth = cluster_truth(mission, cloud, result.segmentation.input_indices(c.cluster_index))
            if truth.label == "background":
                assert c.detection is None and c.label == "unknown", c.reason  # tank remains, never an object
            elif c.touches_border:
                n_border += 1
                assert c.detection is None and "border" in c.reason
            else:
                n_whole += 1
                assert c.label == truth.label, (record.scan_id, c.reason)  # no confusion between fittings
                n_true += c.detection is not None
        assert all(d.label != "unknown" and d.extras["touches_border"] is False for d in result.detections)
    assert n_whole >= 8 and n_true / n_whole >= 0.8  # recall of whole objects (measured: 100 %)
    assert result.timings_ms["total"] >= result.timings_ms["segmentation"] > 0


def test_pose_of_a_detection_is_close_to_the_truth(db, mission):
    from semslam.simulation.truth import pose_error, true_T_scanner_object

    rec = ScanRecognizer(db)
    record = mission.scans[17]  # the ball valve, whole, in the middle of the footprint
    cloud = mission.load_scan(record.scan_id)
    result = rec.recognize(cloud, seed=1, stamp_s=record.end_stamp_s, scan_id=record.scan_id)
    assert [d.label for d in result.detections] == ["ball_valve"]
    det = result.detections[0]
    assert det.scan_id == record.scan_id and det.covariance_6x6.shape == (6, 6)
    oi = next(i for i, o in enumerate(mission.objects) if o.label == "ball_valve")
    err = pose_error(det, true_T_scanner_object(mission, oi, 0.5 * (record.start_stamp_s + record.end_stamp_s)),
                     db.class_info("ball_valve").symmetry)
    assert err.translation_error_m < 0.03 and err.rotation_error_rad < np.radians(15)


def test_border_policy_flag_keeps_cut_objects_and_marks_them(db, mission):
    cloud = mission.load_scan(mission.scans[0].scan_id)
    rec = ScanRecognizer(db, PipelineConfig(estimate_pose=False, border="flag", border_margin_rad=np.radians(30)))
    result = rec.recognize(cloud, seed=0)
    # a 30-degree margin puts every cluster on the border: flagged, not rejected for it
    assert all(c.touches_border for c in result.clusters)
    assert not any("scan border (partial" in c.reason for c in result.clusters)
    assert all(d.extras["touches_border"] and not d.reliable for d in result.detections)


def test_a_pose_fitted_to_a_border_cut_cluster_reports_its_orientation_unknown(db, mission):
    """The same ball valve, whole in the footprint, posed once as a whole cluster and once as if cut by the border:
    the cut one's rotation variances grow by pi^2/3 (the orientation of a part may be any that fits it), its
    position covariance and pose stay the same, and it is unreliable."""
    record = mission.scans[17]  # the ball valve, whole, in the middle of the footprint
    cloud = mission.load_scan(record.scan_id)
    whole = ScanRecognizer(db, PipelineConfig(border="flag")).recognize(cloud, seed=1).detections
    cut = ScanRecognizer(db, PipelineConfig(border="flag", border_margin_rad=np.radians(30))).recognize(
        cloud, seed=1).detections
    assert [d.label for d in whole] == [d.label for d in cut] == ["ball_valve"]
    w, c = whole[0], cut[0]
    assert not w.extras["touches_border"] and "orientation_unknown_border" not in w.extras
    assert c.extras["touches_border"] and c.extras["orientation_unknown_border"] and not c.reliable
    np.testing.assert_allclose(c.T_sensor_object.matrix, w.T_sensor_object.matrix)
    np.testing.assert_allclose(c.covariance_6x6[:3, :3], w.covariance_6x6[:3, :3])
    np.testing.assert_allclose(np.diag(c.covariance_6x6)[3:] - np.diag(w.covariance_6x6)[3:], np.pi**2 / 3)
    off = ScanRecognizer(db, PipelineConfig(border="flag", border_margin_rad=np.radians(30),
                                            border_rotation_variance_rad2=0.0)).recognize(cloud, seed=1).detections
    np.testing.assert_allclose(off[0].covariance_6x6, w.covariance_6x6)


def test_plausibility_helpers_against_analytic_cases():
    rng = np.random.default_rng(0)
    box = rng.uniform([-0.05, -0.02, -0.01], [0.05, 0.02, 0.01], size=(2000, 3))
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    ext = cluster_extent_m(box @ R.T + 1.0)  # rotation and translation invariant
    np.testing.assert_allclose(ext, [0.1, 0.04, 0.02], atol=0.003)
    assert size_plausible(ext, [0.02, 0.1, 0.04]) and not size_plausible(ext, [0.05, 0.03, 0.02], slack_m=0.0)
    # a flat scan seen from the origin: z = 1 m, x, y in [-0.5, 0.5]
    g = np.stack(np.meshgrid(np.linspace(-0.5, 0.5, 101), np.linspace(-0.5, 0.5, 101)), -1).reshape(-1, 2)
    scan = np.column_stack([g, np.ones(len(g))])
    ext_scan = scan_angular_extent(scan)
    np.testing.assert_allclose(ext_scan[:2], [-np.arctan(0.5), np.arctan(0.5)])
    assert touches_scan_border(scan[np.abs(scan[:, 0] - 0.5) < 0.02], ext_scan)
    assert not touches_scan_border(scan[np.hypot(scan[:, 0], scan[:, 1]) < 0.1], ext_scan)


def test_bad_input_raises(db):
    with pytest.raises(RecognitionError, match="'db'"):
        ScanRecognizer("db.npz")
    with pytest.raises(InputError, match="'config'"):
        ScanRecognizer(db, {"descriptor": "esf"})
    with pytest.raises(InputError, match="'border'"):
        PipelineConfig(border="cut")
    with pytest.raises(InputError, match="'reject_margin'"):
        PipelineConfig(reject_margin=-1.0)
    with pytest.raises(InputError, match="'size_tolerance'"):
        PipelineConfig(size_tolerance=0.0)
    with pytest.raises(InputError, match="'scan'"):
        ScanRecognizer(db).recognize(np.zeros((10, 3)))
    with pytest.raises(InputError, match="point_stamps_s"):
        ScanRecognizer(db).recognize(PointCloud(np.zeros((10, 3))), point_stamps_s=np.zeros(3))
