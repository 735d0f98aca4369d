"""The streaming runner (semslam.run): one pass, every mode, the same numbers as the dataset loop; late messages
counted and dropped, never applied at the wrong time; the health verdict."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from semslam.dataset import PositionFixLog
from semslam.errors import InputError
from semslam.geometry import RigidTransform
from semslam.simulation.synthetic import square_dataset
from semslam.run import Attitude, Depth, Fix, Runner, open_dive, run_stream
from semslam.run.health import HealthLimits, health_verdict
from semslam.run.sources import dataset_messages
from semslam.run import run_slam
from semslam.evaluation.slam_run import evaluate_results


@pytest.fixture(scope="module")
def mission():
    return square_dataset(seed=4, loops=1)


@pytest.fixture(scope="module")
def dets(mission):
    from semslam.simulation.detections import simulate_detections
    from semslam.simulation.truth_slam import truth_detection_config

    return simulate_detections(mission, truth_detection_config(mission), seed=4, symmetries={})


def test_all_modes_in_one_pass_equal_the_dataset_loop_bit_for_bit(mission, dets):
    out = run_stream(open_dive(mission), modes=("dr", "pose"), detections_by_scan=dets, symmetries={})
    out.results = evaluate_results(out.results, mission, {})   # after the run, as evaluation does
    for mode in ("dr", "pose"):
        ref = run_slam(mission, dets, mode=mode, symmetries={})
        np.testing.assert_array_equal(out.results[mode].position_ned_m, ref.position_ned_m)
        np.testing.assert_array_equal(out.results[mode].position_cov_m2, ref.position_cov_m2)
        assert out.results[mode].metrics["ate_rmse_m"] == ref.metrics["ate_rmse_m"]
    assert out.results["pose"].metrics["n_landmarks"] == 4


def test_a_message_older_than_the_processed_time_is_counted_and_dropped(mission):
    r = Runner(mission.vehicle, modes=("dr",))
    msgs = list(dataset_messages(mission, scans=False))
    for m in msgs[:400]:
        r.feed(m)
    assert r._released > 1.0   # the delay line released messages up to here
    r.feed(Depth(0.05, 100.0))                         # far behind: would be applied at the wrong time
    r.feed(Attitude(float("nan"), np.zeros(3)))       # a broken stamp
    for m in msgs[400:]:
        r.feed(m)
    out = r.finish()
    assert out.counts["late_dropped"] == {"depth": 1}
    assert out.counts["non_finite_stamp"] == {"attitude": 1}
    v = health_verdict(out.results["dr"], counts=out.counts)
    assert any(c["check"] == "stream" and c["level"] == "warning" for c in v.checks)


def test_the_start_waits_for_the_start_window_and_takes_the_fix_before_the_dive(mission):
    p0 = mission.truth.interpolate_position(0.0)[0, :2]
    m = replace(mission, fixes=PositionFixLog([-3.0], [p0 + [1.0, 2.0]], [np.eye(2) * 4.0], ("gps",)))
    r = Runner(m.vehicle, modes=("dr",))
    msgs = dataset_messages(m, scans=False)
    first = next(msgs)
    assert isinstance(first, Fix) and first.stamp_s == -3.0
    r.feed(first)
    for msg in msgs:
        r.feed(msg)
        if msg.stamp_s < 1.9:
            assert r.start is None    # 2 s of data after the first attitude before the start is decided
    out = r.finish()
    assert out.start.frame == "world"
    out.results = evaluate_results(out.results, m)
    np.testing.assert_allclose(out.start.position_ned_m[:2], p0 + [1.0, 2.0])
    assert out.results["dr"].metrics["launch_error_m"] == pytest.approx(np.sqrt(5.0), abs=0.05)


def test_detections_recognised_elsewhere_enter_at_their_stamps_or_are_counted_late(mission, dets):
    """The live node's path: each scan's detections arrive 0.5 s after their stamps (recognition off the callback
    thread): inside the delay line, they give the same map as the offline run; one arriving long after is counted
    and dropped."""
    r = Runner(mission.vehicle, modes=("pose",), symmetries={})
    pending = sorted(dets.items(), key=lambda kv: kv[1][0].stamp_s)
    for msg in dataset_messages(mission, scans=False):
        r.feed(msg)
        while pending and msg.stamp_s > pending[0][1][0].stamp_s + 0.5:
            r.add_scan_detections(*pending.pop(0))
    for sid, group in pending:
        r.add_scan_detections(sid, group)
    r.add_scan_detections(99, [replace(dets[min(dets)][0], stamp_s=0.1)])   # far too late
    out = r.finish()
    assert out.counts["late_dropped"] == {"detections": 1}
    ref = run_slam(mission, dets, mode="pose", symmetries={})
    np.testing.assert_array_equal(out.results["pose"].position_ned_m, ref.position_ned_m)
    assert r.estimate("pose") is not None and r.estimate("dr") is None


def test_a_scan_made_final_after_it_was_fed_replaces_what_it_fed(mission, dets):
    """The live node's scan before, made final from the scan after: each scan first fed with a wrong detection
    (moved 2 m) besides its own, then replaced by its final detections before the filter passes it, gives the map of
    the final detections fed once; its record and stats are the final ones, nothing counted late."""
    ref = run_slam(mission, dets, mode="pose", symmetries={})
    r = Runner(mission.vehicle, modes=("pose",), symmetries={})
    pending = sorted(dets.items(), key=lambda kv: kv[1][0].stamp_s)
    for msg in dataset_messages(mission, scans=False):
        while pending and msg.stamp_s > pending[0][1][0].stamp_s - 1.0:
            sid, group = pending.pop(0)
            wrong = replace(group[0], T_sensor_object=group[0].T_sensor_object @ RigidTransform.from_xyz_rpy(
                [2.0, 0.0, 0.0], [0.0, 0.0, 0.0]))
            r.add_scan_detections(sid, [wrong, *group[1:]], {"scan_id": sid, "n_kept": len(group)})
            r.replace_scan_detections(sid, group, {"scan_id": sid, "n_kept": len(group), "final": True})
        r.feed(msg)
    out = r.finish()
    assert out.counts["late_dropped"] == {}
    np.testing.assert_array_equal(out.results["pose"].position_ned_m, ref.position_ned_m)
    assert all(out.detections_by_scan[sid] == group for sid, group in dets.items())
    assert len(r.scans) == len(dets) and all(st["final"] for st in r.scans)


def test_health_verdict_levels_follow_the_documented_limits(mission):
    res = run_slam(mission, {}, mode="dr")
    ok = health_verdict(res)
    assert ok.level == "ok", ok.checks
    m = dict(res.metrics, depth_rejected=int(0.2 * res.metrics["depth_updates"]))
    bad = health_verdict(replace(res, metrics=m))
    assert bad.level == "bad" and any(c["check"] == "depth gate" and c["level"] == "bad" for c in bad.checks)
    m = dict(res.metrics, fix_updates=10, fix_rejected=10)   # every fix rejected: a dive far from its fixes
    assert health_verdict(replace(res, metrics=m)).level == "bad"
    strict = HealthLimits(nis_factor_warning=0.01, nis_factor_bad=0.02)   # limits are honoured
    assert health_verdict(res, limits=strict).level == "bad"
    P = res.position_cov_m2.copy()
    P[-1] = np.eye(3) * 1e6
    assert health_verdict(replace(res, position_cov_m2=P)).level == "bad"


class _Jittery:
    """The real recogniser, each scan delayed by a seeded 0-20 ms (scans finish out of order in the threads), the
    scans of ``slow`` by 0.6 s (longer than the delay line takes to reach them)."""

    def __init__(self, recognizer, slow=()) -> None:
        self.r, self.config, self.slow = recognizer, recognizer.config, set(slow)

    def recognize(self, cloud, **kw):
        import time

        sid = kw["scan_id"]
        time.sleep(0.6 if sid in self.slow else float(np.random.default_rng(sid).uniform(0.0, 0.02)))
        return self.r.recognize(cloud, **kw)


def test_scans_recognised_ahead_in_threads_give_the_one_at_a_time_run_bit_for_bit():
    """A one-loop simulated dive (scans with objects) recognised one at a time, then with lookahead 1 and 8 (8 scans
    span more than the delay line; some scans with detections slow, the others finishing out of order): the same
    detections in the same order, the same per-scan statistics order and every mode's trajectory, covariance and
    map bit for bit (the filters wait for a scan still in recognition)."""
    from semslam.pipeline import ScanRecognizer
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset
    from semslam.simulation.builtin_db import builtin_database
    from semslam.simulation.config import ScannerConfig
    from semslam.simulation.truth_slam import builtin_symmetries

    ds = simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1),
                                                    scanner=ScannerConfig(n_lines=150, points_per_line=150)), seed=3)
    rec = ScanRecognizer(builtin_database(seed=0), seed=0)
    ref = run_stream(open_dive(ds), modes=("dr", "pose"), recognizer=rec, symmetries=builtin_symmetries())
    assert sum(len(v) for v in ref.detections_by_scan.values()) >= 3
    slow = sorted(ref.detections_by_scan)[::3]  # some scans with detections come too late for the delay line
    runs = {k: run_stream(open_dive(ds), modes=("dr", "pose"), recognizer=_Jittery(rec, slow), lookahead=k,
                          symmetries=builtin_symmetries()) for k in (1, 8)}
    for k, out in runs.items():
        assert [s["scan_id"] for s in out.scans] == [s["scan_id"] for s in ref.scans], k
        assert {sid: [(d.label, d.stamp_s, d.T_sensor_object.matrix.tobytes()) for d in v]
                for sid, v in out.detections_by_scan.items()} == \
               {sid: [(d.label, d.stamp_s, d.T_sensor_object.matrix.tobytes()) for d in v]
                for sid, v in ref.detections_by_scan.items()}, k
        for mode in ("dr", "pose"):
            np.testing.assert_array_equal(out.results[mode].position_ned_m, ref.results[mode].position_ned_m)
            np.testing.assert_array_equal(out.results[mode].position_cov_m2, ref.results[mode].position_cov_m2)
        assert [lm.pose_xyzrpy.tolist() for lm in out.results["pose"].landmarks] == \
               [lm.pose_xyzrpy.tolist() for lm in ref.results["pose"].landmarks], k
        assert out.counts.get("late_dropped", {}).get("detections", 0) == 0


def test_lookahead_must_be_a_small_non_negative_integer(mission):
    for bad in (-1, 1.5, True, 65):
        with pytest.raises(InputError, match="lookahead"):
            Runner(mission.vehicle, modes=("dr",), lookahead=bad)


def test_a_run_abandoned_mid_dive_stops_its_recognition_threads_before_the_error_leaves():
    """The dive's reader fails after a few scans while scans are in recognition in background threads: when the
    error reaches the caller no recognition thread is left running and BLAS has its thread count back (a worker
    still inside BLAS while the caller restores its own limits crashed the process on Ctrl-C: SIGSEGV)."""
    import threading

    from threadpoolctl import threadpool_info

    from semslam.pipeline import ScanRecognizer
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset
    from semslam.simulation.builtin_db import builtin_database
    from semslam.simulation.config import ScannerConfig

    ds = simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1),
                                                    scanner=ScannerConfig(n_lines=100, points_per_line=100)), seed=3)
    rec = _Jittery(ScanRecognizer(builtin_database(seed=0), seed=0), slow=range(1000))  # every scan 0.6 s
    dive = open_dive(ds)

    class Failing:
        vehicle, counts, geodetic_origin = dive.vehicle, dive.counts, dive.geodetic_origin

        def messages(self):
            n = 0
            for m in dive.messages():
                yield m
                n += m.kind == "scan"
                if n == 3:
                    raise OSError("the disk went away")

    blas = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    with pytest.raises(OSError, match="disk went away"):
        run_stream(Failing(), modes=("pose",), recognizer=rec, lookahead=2)
    assert not [t for t in threading.enumerate() if t.name.startswith("semslam-recognition") and t.is_alive()]
    assert [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"] == blas
