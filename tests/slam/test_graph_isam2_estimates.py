"""The factor-graph backends (``semslam/slam/graph/``): what iSAM2's streaming estimate is, and which landmark
updates become graph factors.

One seeded square mission (``square_dataset(seed=3, loops=1)``), streamed in ``pose+heading`` mode (AHRS yaw
bias estimated): there the graph's optimum of the present and the front-end filter's estimate differ by millimetres
(the filter's observability-constrained heading Jacobian, the graph's own linearisation points), so a test can
tell which of the two an estimate is. Each test streams ~25 s of the dive: well under a second."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip('gtsam', reason='the graph backends need GTSAM (pip install gtsam)')

from semslam.geometry import RigidTransform, rotation_from_rpy  # noqa: E402
from semslam.run.dataset_loop import feed_message, merged_messages  # noqa: E402
from semslam.simulation.detections import simulate_detections  # noqa: E402
from semslam.simulation.synthetic import square_dataset  # noqa: E402
from semslam.simulation.truth_slam import truth_detection_config  # noqa: E402
from semslam.slam.association import measurement_from_detection  # noqa: E402
from semslam.slam.graph import GraphSession  # noqa: E402


T_STOP = 25.0  #: seconds of the dive streamed: two landmarks mapped by then, several updates of each


@pytest.fixture(scope="module")
def stream():
    mission = square_dataset(seed=3, loops=1)
    dets = simulate_detections(mission, truth_detection_config(mission), seed=3, symmetries={})
    msgs = [m for m in merged_messages(mission, dets) if m[0] <= T_STOP]
    return mission, msgs


def _session(mission):
    return GraphSession(mission.vehicle, backend="isam2", mode="pose+heading", symmetries={}, start_stamp_s=0.0,
                        initial_position_ned_m=mission.truth.position_ned_m[0],
                        initial_velocity_body_mps=mission.dvl.velocity_body_mps[0])


def _feed(s, msgs):
    last = {}
    for t, kind, payload in msgs:
        feed_message(s, t, kind, payload)
        if kind == "attitude":
            last["rpy"] = payload[0]
        elif kind == "detections":
            last["dets"] = (t, payload[0])
    return last


def test_isam2_estimate_mid_run_is_the_graphs_optimum_not_the_filters(stream):
    """Catches an iSAM2 ``estimate()`` that returns the front-end filter's estimate instead of the graph's optimum
    (``not self.ekf is None`` for ``self.ekf is None``): mid-run, the estimate of the present must be the iSAM2
    optimum of the present keyframe (GTSAM's ``calculateBestEstimate``) -- position, its marginal covariance and
    the landmarks -- which here differs from the filter's by millimetres."""
    import gtsam

    from semslam.slam.graph.factors import L, X

    mission, msgs = stream
    s = _session(mission)
    _feed(s, msgs)
    est = s.estimate()
    g = s.graph
    assert est.stamp_s == pytest.approx(msgs[-1][0])
    best = g.isam.calculateBestEstimate()
    key = X(len(g.kf_t) - 1)
    x = np.asarray(best.atVector(key))
    assert np.abs(x[:3] - s.ekf.position_ned_m).max() > 1e-3  # the case tells the two apart...
    np.testing.assert_allclose(est.position_ned_m, x[:3], atol=1e-9)  # ...and the estimate is the graph's
    np.testing.assert_allclose(est.velocity_body_mps, x[3:6], atol=1e-9)
    np.testing.assert_allclose(est.position_cov_m2, np.asarray(g.isam.marginalCovariance(key))[:3, :3],
                               rtol=1e-9, atol=1e-15)
    assert len(est.landmarks) == len(s.ekf.landmarks) >= 2
    for lm in est.landmarks:
        np.testing.assert_allclose(lm.pose_xyzrpy[:3], np.asarray(best.atVector(L(lm.landmark_id)))[:3], atol=1e-9)
    assert isinstance(best, gtsam.Values)


def test_a_gated_out_landmark_update_adds_no_graph_factor(stream):
    """Catches a graph front end that turns a landmark update the filter *rejected* into a factor (``new or ...``
    for ``new and ...`` in ``GraphMapper._update_landmark``): a detection of a mapped landmark displaced by 3 m
    fails the filter's gate (logged ``accepted=False``), and the graph must then be exactly the graph without
    that detection: same factor count, same optimum of the present."""
    mission, msgs = stream
    ref, s = _session(mission), _session(mission)
    _feed(ref, msgs)
    last = _feed(s, msgs)
    t, dets = last["dets"]
    det = dets[0]
    j = next(k for k, lm in enumerate(s.ekf.landmarks) if lm.label == det.label)
    T = det.T_sensor_object
    moved = type(det)(det.label, det.score, RigidTransform.from_rotation_translation(
        T.rotation, T.translation_m + np.array([3.0, 0.0, 0.0])), det.covariance_6x6, stamp_s=det.stamp_s)
    x = measurement_from_detection(moved, mission.vehicle.T_vehicle_scanner, symmetry=None,
                                   unobservable_var_rad2=s.cfg.initialisation.unobservable_var_rad2, index=0)
    n_factors, n_log = s.graph.n_factors, len(s.log)
    s.mapper._update_landmark(t, x, j, rotation_from_rpy(*last["rpy"]), None, moved)
    (rec,) = s.log[n_log:]
    assert rec["kind"] == "landmark" and rec["accepted"] is False and rec["landmark"] == j
    assert s.graph.n_factors == n_factors == ref.graph.n_factors
    a, b = s.estimate(), ref.estimate()
    np.testing.assert_array_equal(a.position_ned_m, b.position_ned_m)
    for la, lb in zip(a.landmarks, b.landmarks):
        np.testing.assert_array_equal(la.pose_xyzrpy, lb.pose_xyzrpy)


def test_isam2_reports_no_batch_iteration_and_batch_at_least_one():
    """Catches a batch-iteration counter that does not start at 0 (``iterations = 1``): an iSAM2 run never runs
    the batch Levenberg-Marquardt, so its ``metrics["graph"]["batch_iterations"]`` is 0; a batch run reports the
    optimiser's own count (>= 1)."""
    from semslam.dataset.vehicle import VehicleDescription

    out = {}
    for backend in ("isam2", "batch"):
        s = GraphSession(VehicleDescription.girona500(), mode="dr", backend=backend, start_stamp_s=0.0)
        for k in range(10):
            s.add_attitude(0.1 * k, [0.0, 0.0, 0.3])
            s.add_dvl(0.1 * k + 0.05, [0.3, 0.0, 0.0])
            s.add_depth(0.1 * k + 0.05, 2.0)
        out[backend] = s.finish().metrics["graph"]["batch_iterations"]
    assert out["isam2"] == 0
    assert out["batch"] >= 1


def test_front_end_add_landmark_options_are_keyword_only():
    """Catches ``/`` for ``*`` in ``FrontEkf.add_landmark``'s signature: ``label`` and ``stamp_s`` are keyword-only
    (as the filter's), so a positional call fails instead of being misread, and every argument may be named."""
    from types import SimpleNamespace

    from semslam.slam.graph.frontend import FrontEkf

    ekf = FrontEkf(np.zeros(3), np.zeros(3), np.eye(6) * 1e-4)
    ekf.backend = SimpleNamespace(keyframe=lambda t, x: 0, new_landmark=lambda x: 1, add_factor=lambda f: None)
    G = np.zeros((6, 6))
    G[0:3, 0:3] = np.eye(3)
    with pytest.raises(TypeError):
        ekf.add_landmark(np.zeros(6), G, np.eye(6) * 1e-3, "valve", 0.0)
    j = ekf.add_landmark(pose_xyzrpy=np.zeros(6), G_vehicle=G, noise_cov=np.eye(6) * 1e-3, label="valve", stamp_s=0.0)
    assert j == 0 and ekf.landmarks[0].label == "valve"


def test_surveyed_landmarks_are_graph_variables_with_their_survey_prior():
    """Catches a front end that drops the surveyed landmarks from the graph (the loop over them skipped in
    ``FrontEkf.add_prior_landmarks``): a GraphSession with one surveyed valve has one landmark variable, and before
    any detection its estimate is the surveyed pose with the survey's position variance."""
    from semslam.dataset.vehicle import VehicleDescription

    s = GraphSession(VehicleDescription.girona500(), mode="pose", backend="isam2", start_stamp_s=0.0)
    T = RigidTransform.from_rotation_translation(rotation_from_rpy(0.0, 0.0, 0.5), [5.0, 1.0, 3.0])
    s.add_surveyed_landmarks(["v1"], ["valve"], [T])
    for k in range(5):
        s.add_attitude(0.1 * k, [0.0, 0.0, 0.3])
        s.add_dvl(0.1 * k + 0.05, [0.3, 0.0, 0.0])
    est = s.estimate()
    assert s.graph.n_landmarks == 1 and len(est.landmarks) == 1
    np.testing.assert_allclose(est.landmarks[0].pose_xyzrpy[:3], [5.0, 1.0, 3.0], atol=1e-9)
    sig = s.cfg.initialisation.survey_position_sigma_m
    np.testing.assert_allclose(np.diag(est.landmarks[0].covariance_6x6)[:3], sig**2, rtol=1e-6)


def test_graph_wrap_maps_angles_into_minus_pi_pi():
    """Catches a wrong period in the graph's angle wrap (``% (2 / pi)``): landmark angles are wrapped into
    [-pi, pi) modulo 2 pi, so 3.5 rad becomes 3.5 - 2 pi and 0.2 stays 0.2."""
    from semslam.slam.graph.session import _wrap

    np.testing.assert_allclose(_wrap(np.array([3.5, -3.5, 0.2, np.pi])), [3.5 - 2 * np.pi, 2 * np.pi - 3.5, 0.2, -np.pi],
                               atol=1e-15)


def test_huber_threshold_below_one_sigma_is_accepted():
    """Catches a Huber-threshold check that refuses thresholds in (0, 1] (``huber_k <= 1``): any number > 0 is a
    valid threshold (in sigmas of the whitened residual)."""
    from semslam.dataset.vehicle import VehicleDescription

    s = GraphSession(VehicleDescription.girona500(), mode="dr", huber_k=0.5)
    assert s.huber_k == 0.5


def test_detection_covariance_at_the_psd_tolerance_is_accepted():
    """Catches a PSD check of the detection covariances that is strict at its tolerance (``<=`` for ``<``): an
    eigenvalue of exactly -1e-12 (times max(|largest|, 1)) is rounding, accepted as ``Detection`` itself accepts
    it, and the detection is processed."""
    from semslam.dataset.vehicle import VehicleDescription
    from semslam.detection import Detection

    s = GraphSession(VehicleDescription.girona500(), mode="pose", start_stamp_s=0.0)
    s.add_attitude(0.0, [0.0, 0.0, 0.0])
    T = RigidTransform.from_rotation_translation(np.eye(3), [3.0, 0.0, 0.0])
    s.add_detections(0.5, [Detection("valve", 0.9, T, np.diag([1.0, 1.0, 1.0, 1.0, 1.0, -1e-12]))])
    s.add_attitude(1.0, [0.0, 0.0, 0.0])   # the detection was processed (not refused)
    assert any(r["kind"] == "candidate" for r in s.log)


def test_graph_wall_time_and_real_time_factor_of_a_short_run():
    """Catches a wall time that adds the start instead of subtracting it (``perf_counter() + t0``) and a real-time
    factor reported as infinite below one second of wall time (``_wall > 1``): a one-second dive processed in well
    under a second reports 0 < wall_s <= the test's own elapsed time and real_time_factor = duration / wall_s."""
    import time

    from semslam.dataset.vehicle import VehicleDescription

    t0 = time.perf_counter()
    s = GraphSession(VehicleDescription.girona500(), mode="dr", backend="isam2", start_stamp_s=0.0)
    for k in range(11):
        s.add_attitude(0.1 * k, [0.0, 0.0, 0.3])
        s.add_dvl(0.1 * k + 0.05, [0.3, 0.0, 0.0])
    m = s.finish().metrics
    elapsed = time.perf_counter() - t0
    g = m["graph"]
    assert 0.0 < g["wall_s"] <= elapsed < 60.0
    assert g["real_time_factor"] == pytest.approx(m["duration_s"] / g["wall_s"], rel=1e-12)
    assert np.isfinite(g["real_time_factor"])


def test_batch_counts_its_factors_and_times_its_optimisation():
    """Catches a factor count that adds 2 per factor (``n_factors += 2``) and a batch optimisation time that adds the
    start instead of subtracting it (``perf_counter() + t0``): a batch run's ``n_factors`` is the size of the graph it
    optimised, and its update time is positive and no longer than the test's own elapsed time."""
    import time

    from semslam.dataset.vehicle import VehicleDescription

    t0 = time.perf_counter()
    s = GraphSession(VehicleDescription.girona500(), mode="dr", backend="batch", start_stamp_s=0.0)
    for k in range(11):
        s.add_attitude(0.1 * k, [0.0, 0.0, 0.3])
        s.add_dvl(0.1 * k + 0.05, [0.3, 0.0, 0.0])
    m = s.finish().metrics["graph"]
    elapsed = time.perf_counter() - t0
    assert m["n_factors"] == s.graph._all_f.size() > 1
    assert 0.0 < m["update_max_s"] <= elapsed


def test_segment_keeps_the_right_hand_side_of_rows_at_the_keyframe():
    """Catches a fold of the keyframe's own rows that also zeroes their right-hand side (``old[:, n:3n] = 0`` for
    ``n:2n`` at the first prediction): a measurement at the keyframe's stamp followed by a prediction gives the same
    least-squares system (normal equations of ``[A_k A_c | b]``) as the measurement alone (a unary segment) plus the
    prediction alone."""
    from semslam.slam.graph.segment import SegmentAccumulator

    rng = np.random.default_rng(5)
    n = 3
    H, z, Rn = rng.normal(size=(2, n)), np.array([0.7, -1.3]), np.diag([0.04, 0.09])
    F, u, Q = np.eye(n) + 0.1 * rng.normal(size=(n, n)), np.array([0.2, -0.1, 0.3]), np.diag([0.01, 0.02, 0.03])

    def aug(out):
        Ak, Ac, b, _ = out
        return np.hstack([Ak, Ac, b[:, None]])

    both = SegmentAccumulator(n)
    both.measure(H, z, Rn)
    both.predict(F, u, Q)
    M1 = aug(both.close())
    unary = SegmentAccumulator(n)
    unary.measure(H, z, Rn)
    Ak2, _, b2, is_unary = unary.close()
    assert is_unary
    pred = SegmentAccumulator(n)
    pred.predict(F, u, Q)
    M2 = np.vstack([np.hstack([Ak2, np.zeros_like(Ak2), b2[:, None]]), aug(pred.close())])
    np.testing.assert_allclose(M1.T @ M1, M2.T @ M2, rtol=1e-9, atol=1e-9)


def test_a_non_square_covariance_is_a_slam_error_naming_it():
    """Catches a square-shape check that compares a dimension with itself (``C.shape[1] != C.shape[1]``): a 2 x 3
    covariance given to the graph is a SlamError naming what it belongs to, not a numpy broadcasting error."""
    from semslam.errors import SlamError
    from semslam.slam.graph.factors import gaussian

    with pytest.raises(SlamError, match="covariance of the test factor must be a finite square matrix"):
        gaussian(np.ones((2, 3)), "the test factor")
