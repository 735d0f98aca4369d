"""The data contract (semslam.dataset), the streaming SLAM session and detect_dataset, without and with the
simulator: a dataset built from plain numpy arrays runs through both; a simulated mission gives the same run
in memory, from its directory, and streamed in another interleaving."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from semslam.cloud import PointCloud
from semslam.dataset import (
    AttitudeLog,
    Dataset,
    DepthLog,
    DvlLog,
    ObjectTruth,
    ScanRecord,
    VehicleDescription,
    VehicleTruth,
    read_dataset,
    read_vehicle_toml,
    write_dataset,
    write_vehicle_toml,
)
from semslam.errors import DatasetError, SemslamError, SlamError
from semslam.geometry import RigidTransform
from semslam.slam import SlamConfig, SlamSession, initial_state_of
from semslam.run.dataset_loop import feed_message, merged_messages
from semslam.run import run_slam


def numpy_dive(seed: int = 0, duration_s: float = 60.0) -> Dataset:
    """A straight, level run at 0.2 m/s north with a constant heading: plain arrays, no simulator."""
    rng = np.random.default_rng(seed)
    ta = np.arange(0.0, duration_s + 1e-9, 0.05)
    td = np.arange(0.0, duration_s + 1e-9, 0.2)
    tz = np.arange(0.0, duration_s + 1e-9, 0.1)
    rpy = np.zeros((len(ta), 3)) + rng.normal(0, [0.0035, 0.0035, 0.0175], (len(ta), 3))
    v = np.tile([0.2, 0.0, 0.0], (len(td), 1)) + rng.normal(0, 0.002, (len(td), 3))
    z = 3.0 + rng.normal(0, 0.02, len(tz))
    tt = np.arange(0.0, duration_s + 1e-9, 0.5)
    truth = VehicleTruth(tt, np.column_stack([0.2 * tt, 0 * tt, 3.0 + 0 * tt]), np.zeros((len(tt), 3)),
                         np.tile([0.2, 0.0, 0.0], (len(tt), 1)))
    return Dataset(VehicleDescription.girona500(), DvlLog(td, v, np.ones(len(td), bool)), AttitudeLog(ta, rpy),
                   DepthLog(tz, z), truth)


def test_a_numpy_dataset_runs_through_slam_session_and_run_slam():
    """run_slam is the loop over the session: the same numbers; dead reckoning tracks the straight run."""
    ds = numpy_dive()
    a = run_slam(ds, mode="dr", config=SlamConfig())
    s = SlamSession(ds.vehicle, mode="dr", config=SlamConfig(), start=initial_state_of(ds))
    for t, kind, payload in merged_messages(ds, {}):
        if kind == "attitude":
            s.add_attitude(t, *payload)
        elif kind == "dvl":
            s.add_dvl(t, payload[0], valid=payload[1])
        else:
            s.add_depth(t, *payload)
    b = s.finish()
    np.testing.assert_array_equal(a.position_ned_m, b.position_ned_m)
    np.testing.assert_array_equal(a.position_cov_m2, b.position_cov_m2)
    assert a.metrics["ate_rmse_m"] < 0.1
    assert abs(a.position_ned_m[-1, 0] - 12.0) < 0.3 and a.stamps_s[-1] == pytest.approx(60.0)
    est = s.estimate()
    np.testing.assert_allclose(est.position_ned_m, b.position_ned_m[-1])


def _stream(session: SlamSession, ds: Dataset, dets: dict, attitude_lead_s: float) -> None:
    """Feed ``ds`` with the attitude ``attitude_lead_s`` ahead of the other sensors (another interleaving)."""
    msgs = list(merged_messages(ds, dets))
    key = [(t - (attitude_lead_s if kind == "attitude" else 0.0), i) for i, (t, kind, _) in enumerate(msgs)]
    for _, i in sorted(key):
        feed_message(session, *msgs[i])


@pytest.fixture(scope="module")
def sim_mission():
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset

    return simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1)), seed=3, with_scans=False)


def test_simulated_mission_same_run_in_memory_from_disk_and_streamed(sim_mission, tmp_path):
    """The dataset directory round-trips the run to 1e-9; streaming the messages with the attitude half a
    second ahead of the other sensors gives the very same run (the session waits for the attitude)."""
    from semslam.simulation.detections import simulate_detections
    from semslam.simulation.truth_slam import builtin_symmetries, truth_detection_config

    sym = builtin_symmetries()
    dets = simulate_detections(sim_mission, truth_detection_config(sim_mission), seed=1, symmetries=sym)
    cfg = SlamConfig()
    a = run_slam(sim_mission, dets, mode="pose", config=cfg, symmetries=sym)
    back = read_dataset(write_dataset(sim_mission, tmp_path / "m"))
    assert back.dvl.beam_range_m is not None and back.vehicle.to_dict() == sim_mission.vehicle.to_dict()
    b = run_slam(back, dets, mode="pose", config=cfg, symmetries=sym)
    np.testing.assert_allclose(b.position_ned_m, a.position_ned_m, atol=1e-9)
    np.testing.assert_allclose(b.smoothed_position_ned_m, a.smoothed_position_ned_m, atol=1e-9)
    s = SlamSession(sim_mission.vehicle, mode="pose", config=cfg, symmetries=sym, start=initial_state_of(sim_mission))
    _stream(s, sim_mission, dets, attitude_lead_s=0.5)
    c = s.finish()
    np.testing.assert_array_equal(c.position_ned_m, a.position_ned_m)
    assert [lm.label for lm in c.landmarks] == [lm.label for lm in a.landmarks]
    assert a.metrics["n_objects_mapped"] == 4 and a.metrics["ate_rmse_m"] < 0.1


def test_beam_ranges_tell_the_filter_where_the_bottom_slopes(sim_mission):
    """The simulated DVL's beams disagree with a flat bottom over the tank's slopes and agree over the flat
    floor; the filter's degraded-noise hypothesis follows them (a planted tolerance of 10 m makes every bottom
    flat, and the filter never takes the degraded hypothesis)."""
    from semslam.geometry import rotations_from_rpy
    from semslam.simulation.config import WorldConfig
    from semslam.simulation.sensors import dvl_beams_over_slope
    from semslam.slam.sensors import DvlModel

    m = sim_mission
    t = m.dvl.stamp_s
    rpy = np.array([np.interp(t, m.truth.stamp_s, np.unwrap(m.truth.rpy_rad[:, i])) for i in range(3)]).T
    slope = dvl_beams_over_slope(WorldConfig.from_dict(m.metadata["simulator"]["world"]),
                                 m.truth.interpolate_position(t), rpy, math.radians(30.0))
    model = DvlModel(m.vehicle)
    R = rotations_from_rpy(rpy)
    ok = np.isfinite(m.dvl.beam_range_m).all(axis=1)
    flat = [model.bottom_flat(r, R[i]) for i, r in enumerate(m.dvl.beam_range_m)]
    agree = np.mean([(not f) == s for f, s, k in zip(flat, slope, ok) if k])
    assert agree > 0.97 and slope[ok].any() and (~slope[ok]).any()
    assert all(f is None for f, k in zip(flat, ok) if not k)
    run = run_slam(m, {}, mode="dr")
    assert run.metrics["dvl_degraded"] > 0
    lax = replace(m, vehicle=m.vehicle.replace(dvl=replace(m.vehicle.dvl, flat_bottom_tolerance_m=10.0)))
    assert run_slam(lax, {}, mode="dr").metrics["dvl_degraded"] == 0


def test_session_rejects_messages_in_the_past_and_bad_values():
    ds = numpy_dive(duration_s=5.0)
    s = SlamSession(ds.vehicle, mode="pose", start_stamp_s=0.0)
    s.add_attitude(0.0, [0, 0, 0])
    s.add_attitude(1.0, [0, 0, 0])
    s.add_dvl(0.5, [0.2, 0, 0])  # covered by the attitude: processed now
    with pytest.raises(SlamError, match="dvl stamps must not decrease"):
        s.add_dvl(0.4, [0.2, 0, 0])
    with pytest.raises(SlamError, match="depth message stamped 0.2 arrived after the filter had processed up to 0.5"):
        s.add_depth(0.2, 3.0)
    with pytest.raises(SlamError, match="finite"):
        s.add_attitude(float("nan"), [0, 0, 0])
    with pytest.raises(SlamError, match="'velocity_mps'.*finite"):
        s.add_dvl(1.0, [np.nan, 0, 0])
    s.add_dvl(1.0, [np.nan, 0, 0], valid=False)  # a dropout
    with pytest.raises(SlamError, match="Detection"):
        s.add_detections(1.0, ["not a detection"])
    res = s.finish()
    assert res.metrics["dvl_dropouts"] == 1
    with pytest.raises(SlamError, match="finished"):
        s.add_attitude(2.0, [0, 0, 0])
    with pytest.raises(SlamError, match="attitude"):
        SlamSession(ds.vehicle, mode="dr").finish()
    with pytest.raises(SemslamError, match="'mode'"):
        SlamSession(ds.vehicle, mode="fast")


def test_logs_reject_nan_unsorted_and_bad_validity():
    with pytest.raises(DatasetError, match=r"'stamp_s' argument of DvlLog must hold finite stamps.*row 1"):
        DvlLog([0.0, np.nan], np.zeros((2, 3)), [1, 1])
    with pytest.raises(DatasetError, match=r"AttitudeLog must be sorted.*0.5 after 1.0 at row 2"):
        AttitudeLog([0.0, 1.0, 0.5], np.zeros((3, 3)))
    with pytest.raises(DatasetError, match="'valid'.*0/1.*2"):
        DvlLog([0.0, 1.0], np.zeros((2, 3)), [1, 2])
    with pytest.raises(DatasetError, match="finite on every valid row"):
        DvlLog([0.0], [[np.nan, 0, 0]], [True])
    with pytest.raises(DatasetError, match="at least 2 rows"):
        VehicleTruth([0.0], np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(DatasetError, match="beam ranges per row"):
        Dataset(VehicleDescription(), DvlLog([0.0], np.zeros((1, 3)), [True], [[1.0, 1.0]]),
                AttitudeLog([0.0], np.zeros((1, 3))), DepthLog([0.0], [1.0]))
    empty = Dataset(VehicleDescription(), DvlLog([], np.zeros((0, 3)), []), AttitudeLog([], np.zeros((0, 3))),
                    DepthLog([], []))
    with pytest.raises(SlamError, match="no attitude samples"):
        run_slam(empty, {}, mode="dr")


def test_vehicle_file_round_trip_and_errors(tmp_path):
    v = VehicleDescription.girona500().replace(
        scanner=replace(VehicleDescription().scanner, line_count=100,
                        T_vehicle_scanner=RigidTransform.from_xyz_rpy([0.6, 0, 0.3], [0, 0, math.pi / 2])))
    path = write_vehicle_toml(v, tmp_path / "vehicle.toml")
    assert read_vehicle_toml(path).to_dict() == v.to_dict()
    cases = {
        "typo": ("[dvl]\nnoise_abs_mp = 0.001\n", r"unknown key\(s\) \['dvl.noise_abs_mp'\]"),
        "degrees": ("[dvl]\nbeam_angle_rad = 30\n", r"'dvl.beam_angle_rad' must be in \[0, 1.2\] rad \(degrees"),
        "type": ("[depth]\nnoise_m = \"2 cm\"\n", r"'depth.noise_m' must be a number. Got '2 cm'"),
        "rotation": ("[scanner]\nmatrix = [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]\n", "extrinsic scanner.T_vehicle_scanner"),
        "both": ("[scanner]\nxyz_m = [0,0,0]\nmatrix = [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]\n", "either"),
        "toml": ("[dvl\n", "not valid TOML"),
        "section": ("dvl = 3\n", "'dvl' must be a table"),
        "version": ("format_version = 7\n", "'format_version' must be 1"),
    }
    for name, (text, msg) in cases.items():
        f = tmp_path / f"{name}.toml"
        f.write_text(text)
        with pytest.raises(DatasetError, match=msg) as exc:
            read_vehicle_toml(f)
        assert str(f) in str(exc.value), name
    with pytest.raises(DatasetError, match="does not exist"):
        read_vehicle_toml(tmp_path / "none.toml")


def test_mission_directory_of_format_1_is_refused_with_a_one_line_error(sim_mission, tmp_path):
    """Format 1 (semslam <= 0.1) is no longer read: a clear error naming the file and what to do, never a guess
    of the vehicle from old simulator settings; a format-2 directory without its vehicle file names the file."""
    d = write_dataset(sim_mission, tmp_path / "v1")
    meta = json.loads((d / "mission.json").read_text())
    meta["format_version"] = 1
    (d / "mission.json").write_text(json.dumps(meta))
    with pytest.raises(DatasetError, match=r"mission.json.*format_version 1.*no longer reads"):
        read_dataset(d)
    meta["format_version"] = 2
    (d / "mission.json").write_text(json.dumps(meta))
    (d / "vehicle.toml").unlink()
    with pytest.raises(DatasetError, match="vehicle.toml"):
        read_dataset(d)


def test_detect_mission_on_a_numpy_dataset_feeds_the_session():
    """Scans held in memory (a synthetic box on a floor, no simulator) through detect_dataset: the same
    detections as the recogniser scan by scan, stamped inside each scan, and accepted by the session."""
    from semslam.simulation.synthetic_views import partial_view, ring_viewpoints, synthetic_shape_views
    from semslam.pipeline import PipelineConfig, ScanRecognizer
    from semslam.pipeline.dataset_detection import detect_dataset, scan_seed
    from semslam.recognition import build_database

    views, classes = synthetic_shape_views(6, n_points=500, seed=2)
    db = build_database(views, classes, seed=0)
    rec = ScanRecognizer(db, PipelineConfig(estimate_pose=False), seed=0)
    ds0 = numpy_dive(duration_s=6.0)
    clouds, records = {}, []
    rng = np.random.default_rng(5)
    for k in range(3):
        vp = ring_viewpoints(6, phase_rad=0.2)[k]  # views the database has not seen; the scanner at the origin
        obj = partial_view("box", (0.10, 0.06, 0.03), vp, n_points=500, seed=k).points_xyz_m
        floor = np.column_stack([rng.uniform(-0.4, 0.4, 4000), rng.uniform(-0.4, 0.4, 4000), np.full(4000, -0.02)])
        pts = np.vstack([obj, floor]) - vp
        line = np.repeat(np.arange(10), len(pts) // 10 + 1)[:len(pts)].astype(np.int32)
        clouds[k] = PointCloud(pts, frame_id="scanner", fields={"line": line})
        records.append(ScanRecord(k, 1.0 + k, 1.3 + k, f"scans/{k}.pcd", len(pts)))
    vehicle = ds0.vehicle.replace(scanner=replace(ds0.vehicle.scanner, line_count=10))
    ds = replace(ds0, vehicle=vehicle, scans=records, scan_clouds=clouds)
    found = detect_dataset(ds, rec, seed=4, keep_unreliable=True)  # no pose estimated: every pose unreliable
    assert not detect_dataset(ds, rec, seed=4).detections_by_scan
    assert len(found.scans) == 3 and found.summary()["n_scans"] == 3
    for r in records:
        direct = rec.recognize(clouds[r.scan_id], seed=scan_seed(4, r.scan_id), stamp_s=r.end_stamp_s,
                               scan_id=r.scan_id, point_stamps_s=ds.point_stamps_s(r, clouds[r.scan_id]))
        assert [d.label for d in direct.detections] == [d.label for d in found.detections_by_scan.get(r.scan_id, [])]
        for d in found.detections_by_scan.get(r.scan_id, []):
            assert r.start_stamp_s <= d.stamp_s <= r.end_stamp_s
    labels = [d.label for v in found.detections_by_scan.values() for d in v]
    assert labels == ["box"] * 3
    res = run_slam(ds, found.detections_by_scan, mode="position")
    assert res.metrics["n_landmarks"] == 0  # detections without poses give no landmark, and break nothing


def test_objects_and_scans_validate():
    with pytest.raises(DatasetError, match="end_stamp_s"):
        ScanRecord(0, 2.0, 1.0, "x.pcd")
    ds = numpy_dive(duration_s=2.0)
    with pytest.raises(DatasetError, match="unique scan ids"):
        replace(ds, scans=[ScanRecord(0, 0.0, 0.1, "a"), ScanRecord(0, 0.2, 0.3, "b")])
    with pytest.raises(DatasetError, match="scan ids"):
        ds.load_scan(5)
    obj = ObjectTruth("v", "ball_valve", RigidTransform.identity())
    assert replace(ds, objects=[obj]).objects[0].in_database


def test_girona500_defaults_are_the_simulated_sensors_figures():
    """The documented defaults for a dataset without a vehicle file are the sensor figures the Monte Carlo of
    benchmarks/RESULTS.md validates (the simulator's specification): a change to either must be deliberate."""
    from semslam.dataset import vehicle_from_simulator_dict
    from semslam.simulation import SimulatorConfig

    sim = vehicle_from_simulator_dict(SimulatorConfig().to_dict(), RigidTransform.identity()).to_dict()
    default = VehicleDescription.girona500().to_dict()
    for section in ("dvl", "attitude", "depth"):
        assert sim[section] == default[section], section
    # the simulated triangulation scanner's camera is in its vehicle file (0.3 m along the scanner's x axis)
    assert sim["scanner"]["camera_xyz_m"] == [SimulatorConfig().scanner.baseline_m, 0.0, 0.0]


def test_mission_log_errors_name_the_file(sim_mission, tmp_path):
    d = write_dataset(sim_mission, tmp_path / "m")
    rows = (d / "ahrs.csv").read_text().splitlines()
    rows[3], rows[4] = rows[4], rows[3]  # two stamps out of order
    (d / "ahrs.csv").write_text("\n".join(rows) + "\n")
    with pytest.raises(DatasetError, match=r"ahrs.csv.*must be sorted.*row 3"):
        read_dataset(d)
    rows[3] = "nan" + rows[3][rows[3].index(","):]
    (d / "ahrs.csv").write_text("\n".join(rows) + "\n")
    with pytest.raises(DatasetError, match=r"ahrs.csv.*finite stamps"):
        read_dataset(d)


def test_far_future_and_early_messages_are_skipped_and_counted():
    """A detection stamped 10^9 s in the future used to make the filter predict for hours; a DVL sample before
    the start was dropped without a word. Now: skipped, counted in the metrics, the run unchanged."""
    import time as _time

    from semslam.detection import Detection

    ds = numpy_dive(duration_s=5.0)
    base = run_slam(ds, {}, mode="pose", config=SlamConfig())
    det = Detection("elbow", 0.1, RigidTransform.from_xyz_rpy([0, 0, 1.0], [0, 0, 0]), np.eye(6) * 1e-4,
                    stamp_s=1e9, scan_id=0)
    t = _time.perf_counter()
    res = run_slam(ds, {0: [det]}, mode="pose", config=SlamConfig())
    assert _time.perf_counter() - t < 30
    assert res.metrics["skipped_beyond_attitude"] == 1
    np.testing.assert_array_equal(res.position_ned_m, base.position_ned_m)
    s = SlamSession(ds.vehicle, mode="dr", start_stamp_s=1.0)
    s.add_dvl(0.5, [0.2, 0, 0])
    s.add_depth(0.6, 3.0)
    s.add_attitude(1.0, [0, 0, 0])
    s.add_attitude(2.0, [0, 0, 0])
    assert s.finish().metrics["skipped_before_start"] == 2


def test_detection_records_are_typed_strictly():
    """'reliable': "false" was read as true (a truthy string)."""
    from semslam.detection import Detection
    from semslam.errors import InputError

    good = Detection("elbow", 0.1, RigidTransform.identity(), np.eye(6), stamp_s=1.0).to_dict()
    assert Detection.from_dict(good).reliable is True
    for key, value, words in (("reliable", "false", "'reliable' must be true or false"),
                              ("label", 3, "'label' must be a string")):
        with pytest.raises(InputError, match=words):
            Detection.from_dict({**good, key: value})
    with pytest.raises(InputError, match="JSON object"):
        Detection.from_dict([1, 2])


def test_feed_message_rejects_an_unknown_kind():
    """A message kind that is none of merged_messages' four is an error naming it, never silently dropped."""
    from semslam.dataset import VehicleDescription
    from semslam.errors import SlamError

    session = SlamSession(VehicleDescription.girona500(), mode="dr", start_stamp_s=0.0)
    with pytest.raises(SlamError, match="'kind' argument of feed_message.*Got 'sonar'"):
        feed_message(session, 0.0, "sonar", ())
