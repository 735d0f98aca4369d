"""Scans deskewed with the vehicle's own navigation on the user's path: against the simulator's true motion, the
streaming runner (which waits for the navigation after a scan's end) against the dataset loop, and the verdict of a
dive whose scans could not be deskewed."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from semslam.pipeline import ScanRecognizer
from semslam.pipeline.dataset_detection import _scan_motion, detect_dataset
from semslam.pipeline.deskew import deskew_points
from semslam.run import open_dive, run_stream
from semslam.run.health import health_verdict


@pytest.fixture(scope="module")
def dive():
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset
    from semslam.simulation.config import ScannerConfig

    return simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1),
                                                      scanner=ScannerConfig(n_lines=150, points_per_line=150)), seed=3)


@pytest.fixture(scope="module")
def recognizer():
    from semslam.simulation.builtin_db import builtin_database

    return ScanRecognizer(builtin_database(seed=0), seed=0)


def _true_deskew(ds, pts, stamps, t_ref):
    """Each point through the true vehicle pose at its stamp into the scanner frame at ``t_ref`` (the oracle)."""
    tr = ds.truth
    slerp = Slerp(tr.stamp_s, Rotation.from_euler("xyz", tr.rpy_rad))
    T = ds.vehicle.scanner.T_vehicle_scanner.matrix

    def pose(t):
        return slerp(t).as_matrix(), np.column_stack([np.interp(t, tr.stamp_s, tr.position_ned_m[:, k])
                                                      for k in range(3)])

    R, p = pose(stamps)
    Rr, pr = pose(np.array([t_ref]))
    world = np.einsum("nij,nj->ni", R, pts @ T[:3, :3].T + T[:3, 3]) + p
    return ((world - pr) @ Rr[0] - T[:3, 3]) @ T[:3, :3]


@pytest.mark.parametrize("lookahead_s, median_m, p90_m", [(0.5, 0.006, 0.02), (0.0, 0.015, 0.035)])
def test_navigation_deskewing_comes_within_millimetres_of_the_true_motion(dive, lookahead_s, median_m, p90_m):
    """With the default half-second of navigation after a scan's end, and with none (a live node that must not
    wait): both far better than the raw scan, the former ~3x better than the latter."""
    errs, raw = [], []
    for sid in range(2, len(dive.scans), 5):
        rec = dive.scan_record(sid)
        cloud = dive.load_scan(sid)
        st = dive.point_stamps_s(rec, cloud)
        if cloud.n_points < 100:
            continue
        truth = _true_deskew(dive, cloud.points_xyz_m, st, rec.end_stamp_s)
        out = deskew_points(cloud.points_xyz_m, st, _scan_motion(dive, st, rec.end_stamp_s, lookahead_s),
                            dive.vehicle.scanner.T_vehicle_scanner, rec.end_stamp_s)
        errs.append(np.linalg.norm(out - truth, axis=1))
        raw.append(np.linalg.norm(cloud.points_xyz_m - truth, axis=1))
    errs, raw = np.concatenate(errs), np.concatenate(raw)
    assert np.median(raw) > 0.03  # a 1/3 s scan at 0.3 m/s: centimetres of distortion
    assert np.median(errs) < median_m and np.percentile(errs, 90) < p90_m


@pytest.mark.parametrize("lookahead_s", [0.5, 0.0])
def test_streamed_scans_are_deskewed_as_the_dataset_loop_deskews_them(dive, recognizer, lookahead_s):
    """The runner waits for the navigation after each scan's end (``deskew_lookahead_s``) before recognising it,
    so the detections equal those of the dataset loop, which reads the whole logs, bit for bit; with no wait too."""
    if lookahead_s != recognizer.config.deskew_lookahead_s:
        recognizer = ScanRecognizer(recognizer.db, replace(recognizer.config, deskew_lookahead_s=lookahead_s), seed=0)
    out = run_stream(open_dive(dive), modes=("pose",), recognizer=recognizer)
    ref = detect_dataset(dive, recognizer)
    assert all(s["deskewed"] for s in out.scans) and len(out.scans) == len(dive.scans)
    assert out.counts.get("scans_not_deskewed", 0) == 0
    assert sum(len(v) for v in ref.detections_by_scan.values()) >= 2
    key = lambda by: {sid: [(d.label, d.stamp_s, d.T_sensor_object.matrix.tobytes()) for d in v]  # noqa: E731
                      for sid, v in by.items()}
    assert key(out.detections_by_scan) == key(ref.detections_by_scan)
    for sid, v in out.detections_by_scan.items():  # each at its own points' median stamp, inside the scan
        rec = dive.scan_record(sid)
        assert all(rec.start_stamp_s <= d.stamp_s < rec.end_stamp_s for d in v)


def test_a_dive_without_bottom_lock_is_recognised_as_scanned_and_the_verdict_says_so(dive, recognizer):
    dvl = replace(dive.dvl, valid=np.zeros_like(dive.dvl.valid), velocity_body_mps=np.full_like(
        dive.dvl.velocity_body_mps, np.nan))
    lost = replace(dive, dvl=dvl)
    out = run_stream(open_dive(lost), modes=("dr",), recognizer=recognizer)
    assert not any(s["deskewed"] for s in out.scans)
    assert out.counts["scans_not_deskewed"] == len(dive.scans)
    v = health_verdict(out.results["dr"], counts=out.counts)
    assert v.level != "ok" and any(c["check"] == "scans" and "motion compensation" in c["message"] for c in v.checks)


def test_the_border_test_reads_the_scan_as_measured(recognizer):
    """A box top cut by the swath's edge (a floor seen over +-25 degrees): deskewing moves its lines 5 cm inward, off
    the deskewed cloud's footprint edge, but the scanner measured it at the edge: with ``measured`` it is still cut
    by the border, as on the raw scan; the deskewed cloud alone would take it for a whole object."""
    from semslam.cloud import PointCloud

    a = np.radians(np.linspace(-25.0, 25.0, 200))
    A, B = np.meshgrid(a, a)
    floor = 1.5 * np.column_stack([np.tan(A).ravel(), np.tan(B).ravel(), np.ones(A.size)])
    xs, ys = np.meshgrid(np.linspace(0.55, 0.64, 30), np.linspace(-0.05, 0.05, 30))
    top = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 1.35)])
    top = top[np.degrees(np.arctan2(top[:, 0], top[:, 2])) <= 25.0]  # cut by the field of view
    under = (floor[:, 0] > 0.55 * 1.5 / 1.35) & (np.abs(floor[:, 1]) < 0.06)  # the floor the box hides
    raw = PointCloud(np.vstack([floor[~under], top]))
    moved = raw.points_xyz_m.copy()
    moved[-len(top):, 0] -= 0.05
    desk = PointCloud(moved)
    flags = {name: [c.touches_border for c in rec.clusters]  # one cluster: the box top
             for name, rec in (("raw", recognizer.recognize(raw, seed=0)),
                               ("alone", recognizer.recognize(desk, seed=0)),
                               ("measured", recognizer.recognize(desk, seed=0, measured=raw)))}
    assert flags == {"raw": [True], "alone": [False], "measured": [True]}


def test_a_measured_scan_of_another_size_is_refused(recognizer):
    from semslam.cloud import PointCloud
    from semslam.errors import InputError

    scan = PointCloud(np.random.default_rng(0).uniform(-1, 1, (200, 3)) + [0, 0, 2])
    with pytest.raises(InputError, match="measured"):
        recognizer.recognize(scan, measured=PointCloud(scan.points_xyz_m[:100]))


def test_the_live_node_waits_for_a_scans_navigation_while_it_keeps_coming(monkeypatch):
    """A loaded machine delivers navigation slowly: a scan waits for its own (0.5 s of stamps past its end) however
    long that takes in wall clock, and is given up to with what came only once no navigation has come for
    NAVIGATION_WAIT_S (the recording ended)."""
    from types import SimpleNamespace

    from semslam.run.ros1 import live_deskew
    from semslam.run.ros1.live_deskew import NAVIGATION_WAIT_S, DeskewQueue

    clock = {"t": 100.0}
    monkeypatch.setattr(live_deskew.time, "monotonic", lambda: clock["t"])
    q = DeskewQueue(np.eye(3))
    stamps = np.linspace(9.67, 10.0, 50)
    job = SimpleNamespace(end_s=10.0, received_wall_s=100.0, abandoned=False, motion=None,
                          scan=SimpleNamespace(point_stamps_s=stamps))
    q.waiting.append(job)
    for k, t in enumerate(np.arange(8.0, 10.4, 0.05)):  # navigation up to 0.4 s past the end, 0.5 s of wall apart
        clock["t"] = 100.0 + 0.5 * k
        q.add_navigation(SimpleNamespace(kind="attitude", stamp_s=float(t), rpy_rad=np.zeros(3)))
        q.add_navigation(SimpleNamespace(kind="dvl", stamp_s=float(t), velocity_mps=np.array([0.3, 0, 0]), valid=True))
        assert q.ready(final=False) == []  # waited far longer than NAVIGATION_WAIT_S, but navigation keeps coming
    clock["t"] += NAVIGATION_WAIT_S + 0.1  # the navigation stopped
    assert q.ready(final=False) == [job] and job.motion is not None and q.not_deskewed == 0


def test_the_live_node_waits_for_each_navigation_kind_as_the_topics_arrive_apart(monkeypatch):
    """Attitude and DVL come on their own connections: a scan whose window the attitude has passed still waits for
    the DVL samples of its window, so it is deskewed as offline; a DVL that stops is waited for NAVIGATION_WAIT_S of
    wall clock, not forever, and once silent that long it is not waited for."""
    from types import SimpleNamespace

    from semslam.pipeline.deskew import NavigationHistory
    from semslam.run.ros1 import live_deskew
    from semslam.run.ros1.live_deskew import NAVIGATION_WAIT_S, DeskewQueue

    clock = {"t": 100.0}
    monkeypatch.setattr(live_deskew.time, "monotonic", lambda: clock["t"])
    stamps = np.linspace(9.67, 10.0, 50)

    def job():
        return SimpleNamespace(end_s=10.0, received_wall_s=100.0, abandoned=False, motion=None,
                               scan=SimpleNamespace(point_stamps_s=stamps))

    def att(t):
        return SimpleNamespace(kind="attitude", stamp_s=float(t), rpy_rad=np.array([0.0, 0.0, 0.2 * t]))

    def dvl(t):
        return SimpleNamespace(kind="dvl", stamp_s=float(t), velocity_mps=np.array([0.3 + 0.05 * t, 0.0, 0.0]),
                               valid=True)

    nav_t = np.arange(8.0, 11.0, 0.05)
    q, j = DeskewQueue(np.eye(3)), job()
    q.waiting.append(j)
    for t in nav_t:
        q.add_navigation(att(t))
    for t in nav_t[nav_t <= 10.3]:
        q.add_navigation(dvl(t))
    assert q.ready(final=False) == []  # the attitude is past the window, the DVL is not
    for t in nav_t[nav_t > 10.3]:
        q.add_navigation(dvl(t))
    assert q.ready(final=False) == [j]
    # the same motion as from every sample in stamp order (the offline runner's)
    ref = NavigationHistory()
    for t in nav_t:
        ref.add_attitude(t, att(t).rpy_rad)
        ref.add_dvl(t, dvl(t).velocity_mps, True)
    want = ref.scan_motion(np.eye(3), stamps, 10.0, lookahead_s=q.lookahead_s)
    assert j.motion is not None and want is not None
    for name in vars(want):
        np.testing.assert_array_equal(getattr(j.motion, name), getattr(want, name))
    # the DVL stops short of the window while the attitude keeps coming: given up on after NAVIGATION_WAIT_S
    q, j = DeskewQueue(np.eye(3)), job()
    q.waiting.append(j)
    for t in nav_t[nav_t <= 10.2]:
        q.add_navigation(dvl(t))
    for k, t in enumerate(nav_t):
        clock["t"] = 100.0 + 0.01 * k
        q.add_navigation(att(t))
        assert q.ready(final=False) == []
    clock["t"] = 100.0 + NAVIGATION_WAIT_S + 0.1
    assert q.ready(final=False) == [j] and j.motion is not None
    # the DVL silent for longer than that already (an outage): a new scan does not wait for it at all
    j2 = job()
    j2.received_wall_s = clock["t"]
    q.waiting.append(j2)
    q.add_navigation(att(11.0))
    assert q.ready(final=False) == [j2]
