"""Per-scan up direction from the vehicle's attitude (``detect_dataset(up_from_attitude=True)``,
``ScanRecognizer.recognize(up_scanner=...)``): a vehicle rolls and pitches, so one ``PipelineConfig.up_scanner``
cannot keep objects upright on a real dive."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import semslam.pipeline.hypothesis as helpers
from semslam.cli.main import main
from semslam.dataset import AttitudeLog, Dataset, DepthLog, DvlLog, ScanRecord, VehicleDescription
from semslam.errors import InputError
from semslam.geometry import RigidTransform
from semslam.io import read_point_cloud
from semslam.pipeline import PipelineConfig, ScanRecognizer
from semslam.pipeline.dataset_detection import detect_dataset
from semslam.pipeline.dataset_detection import MAX_ATTITUDE_GAP_S, up_in_scanner
from semslam.recognition import load_database

SUBSET = Path(__file__).parents[1] / "data" / "real_valves"


def _dataset(rpy_rad: np.ndarray, stamps: np.ndarray, R_vehicle_scanner: np.ndarray, scans=(), clouds=None) -> Dataset:
    vehicle = VehicleDescription()
    mount = RigidTransform.from_rotation_translation(R_vehicle_scanner, [0.6, 0.0, 0.3])
    vehicle = dataclasses.replace(vehicle, scanner=dataclasses.replace(vehicle.scanner, T_vehicle_scanner=mount))
    return Dataset(vehicle, DvlLog([], np.zeros((0, 3)), []), AttitudeLog(stamps, rpy_rad), DepthLog([], []),
                   scans=list(scans), scan_clouds=clouds)


def test_up_in_scanner_against_scipy():
    """World up (NED -z) seen from a scanner pitched 60 degrees down on a vehicle rolled 10 and pitched -5 degrees
    with any heading: scipy's rotation composition is the oracle; roll and pitch are interpolated between
    samples; no sample near the stamp: None."""
    R_vs = Rotation.from_euler("y", -60, degrees=True).as_matrix()
    t = np.array([0.0, 1.0])
    rpy = np.radians([[8.0, -4.0, 170.0], [12.0, -6.0, -170.0]])  # yaw wraps: it must not matter
    ds = _dataset(rpy, t, R_vs)
    R_wv = Rotation.from_euler("ZYX", [123.0, -5.0, 10.0], degrees=True).as_matrix()  # the midpoint, any yaw
    expected = (R_wv @ R_vs).T @ [0.0, 0.0, -1.0]
    np.testing.assert_allclose(up_in_scanner(ds, 0.5), expected, atol=1e-12)
    level = _dataset(np.zeros((2, 3)), t, np.eye(3))
    np.testing.assert_allclose(up_in_scanner(level, 0.3), [0.0, 0.0, -1.0], atol=1e-15)
    assert up_in_scanner(ds, 1.0 + MAX_ATTITUDE_GAP_S + 0.01) is None
    assert up_in_scanner(_dataset(np.zeros((0, 3)), np.zeros(0), np.eye(3)), 0.0) is None


def test_detect_mission_gives_each_scan_its_own_up(monkeypatch):
    """Each scan is recognised with the up of the attitude at its middle; without the option, with none."""
    t = np.arange(0.0, 10.0, 0.1)
    rpy = np.column_stack([np.radians(5.0) * np.sin(t), np.radians(-3.0) * np.cos(t), np.zeros_like(t)])
    scans = [ScanRecord(k, 2.0 * k, 2.0 * k + 0.4, f"scan_{k}.pcd") for k in range(3)]
    cloud = read_point_cloud(SUBSET / "ball_valve" / "pitch000_yaw000_30cm_1.pcd")
    ds = _dataset(rpy, t, np.eye(3), scans, {k: cloud for k in range(3)})
    seen = []
    rec = ScanRecognizer.__new__(ScanRecognizer)
    rec.recognize = lambda c, **kw: seen.append(kw["up_scanner"]) or _EMPTY
    detect_dataset(ds, rec, up_from_attitude=True)
    for k, up in enumerate(seen):
        np.testing.assert_allclose(up, up_in_scanner(ds, 2.0 * k + 0.2), atol=1e-12)
    assert len({tuple(np.round(u, 6)) for u in seen}) == 3  # they differ: the vehicle rocks
    seen.clear()
    detect_dataset(ds, rec)
    assert seen == [None, None, None]


class _Empty:
    detections: list = []
    clusters: list = []
    timings_ms: dict = {}


_EMPTY = _Empty()


@pytest.fixture(scope="module")
def fused_db(tmp_path_factory):
    """A fused database of the committed real views but the yaw +30 setting, with up (the classes record theirs)."""
    tmp = tmp_path_factory.mktemp("fused")
    for f in SUBSET.glob("*/*.pcd"):
        if "yaw030" not in f.name:
            (tmp / "views" / f.parent.name).mkdir(parents=True, exist_ok=True)
            shutil.copy(f, tmp / "views" / f.parent.name / f.name)
    db = tmp / "db.npz"
    assert main(["db", "build", str(tmp / "views"), "--fuse", "--up", "0,-1,0", "--voxel", "auto",
                 "--normal-radius", "auto", "--out", str(db)]) == 0
    return load_database(db)


def test_recognize_uses_the_scans_own_up(fused_db, monkeypatch):
    """``recognize(up_scanner=u)`` poses upright about ``u`` (overriding the configuration's), and a bad ``u`` is a
    clear error."""
    captured = []
    real = helpers.estimate_object_pose

    def spy(*a, **kw):
        captured.append(kw.get("up_scanner"))
        return real(*a, **kw)

    monkeypatch.setattr(helpers, "estimate_object_pose", spy)
    from semslam.segmentation import SegmentationConfig

    cfg = PipelineConfig(segmentation=SegmentationConfig(max_planes=0, voxel_leaf_m="auto", cluster_tolerance_m="auto"),
                         border="keep", reject_margin=3.0, up_scanner=(1.0, 0.0, 0.0))
    rec = ScanRecognizer(fused_db, cfg)
    scan = read_point_cloud(SUBSET / "globe_valve" / "pitch000_yaw030_30cm_1.pcd")
    res = rec.recognize(scan, up_scanner=(0.0, -2.0, 0.0))
    assert res.detections and all(d.extras["pose_upright"] for d in res.detections)
    assert captured and all(np.allclose(u, [0.0, -1.0, 0.0]) for u in captured)
    captured.clear()
    rec.recognize(scan)  # back to the configuration's up
    assert captured and all(np.allclose(u, [1.0, 0.0, 0.0]) for u in captured)
    for bad in ((0.0, 0.0, 0.0), (1.0, np.nan, 0.0), (1.0, 2.0)):
        with pytest.raises(InputError, match="up_scanner"):
            rec.recognize(scan, up_scanner=bad)


def test_model_databases_record_the_resting_up_of_untied_classes(tmp_path):
    """A database built from models records each class's up in its object frame from its most probable resting pose
    (``R_rest_object^T (0, 0, 1)``), except classes that rest on either of two faces; the pipeline then poses them
    upright when the scan's up is given."""
    from semslam.simulation.cad_models import _tied_rests, resting_up_objects, with_resting_up
    from semslam.simulation.model_views import tied_up_objects
    from semslam.simulation.catalogue import catalogue_objects

    models = catalogue_objects()
    ups = resting_up_objects(models)
    assert set(ups) == {k for k, m in models.items() if _tied_rests(m) == [0]} and "flange" in ups
    for label, up in ups.items():
        R = np.asarray(models[label].resting_poses[0])[:3, :3]
        np.testing.assert_allclose(R @ up, [0.0, 0.0, 1.0], atol=1e-12)  # up, seen in the rest frame (z up)
    out = tmp_path / "db.npz"
    assert main(["db", "build", "--builtin", "--n-views", "2", "--model-views", "2", "--esf-samples", "2000",
                 "--out", str(out)]) == 0
    db = load_database(out)
    from semslam.simulation.objects import builtin_objects

    expected = resting_up_objects(builtin_objects())
    assert db.params["up_object"] == expected and expected  # saved and read back
    tied = tied_up_objects(builtin_objects())
    assert db.params["up_object_tied"] == tied and set(tied) | set(expected) == set(db.classes)
    for label in db.classes:
        assert db.up_object(label) == expected.get(label)
        # one up, or both ways up of a part that rests on either face, each up in its rest's frame
        assert db.up_objects(label) == ([expected[label]] if label in expected else tied[label])
    for label, pair in tied.items():
        for r, up in zip(_tied_rests(builtin_objects()[label]), pair):
            R = np.asarray(builtin_objects()[label].resting_poses[r])[:3, :3]
            np.testing.assert_allclose(R @ up, [0.0, 0.0, 1.0], atol=1e-12)
    empty = with_resting_up(db, {})
    assert empty.params["up_object"] == expected  # nothing to add: unchanged
