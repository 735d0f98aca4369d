"""The graph backend's cost and structure (issue 17): iSAM2 never hands GTSAM a Python factor to linearise against
the whole graph (GTSAM's wrapper copies every variable for each such call: update time grew linearly with the dive),
its detection factors are relinearised past the threshold and then agree with batch Levenberg-Marquardt, and
GraphSession builds its filter and mapper through SlamSession's factory hooks."""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam", reason="the graph backends need GTSAM (pip install gtsam)")

from semslam.detection import Detection  # noqa: E402
from semslam.errors import SlamError  # noqa: E402
from semslam.simulation.synthetic import square_dataset  # noqa: E402
from semslam.geometry import RigidTransform  # noqa: E402
from semslam.simulation.detections import simulate_detections  # noqa: E402
from semslam.simulation.truth_slam import truth_detection_config  # noqa: E402
from semslam.slam import SlamSession
from semslam.run import run_slam
from semslam.slam.association import measurement_from_detection  # noqa: E402
from semslam.slam.graph import GraphBackend, GraphSession  # noqa: E402
from semslam.slam.graph import factors as fac  # noqa: E402
from semslam.slam.graph.frontend import FrontEkf, GraphMapper  # noqa: E402
from semslam.slam.mapping import ObjectMapper  # noqa: E402


@pytest.fixture(scope="module")
def mission():
    return square_dataset(seed=5, loops=1)


@pytest.fixture(scope="module")
def dets(mission):
    return simulate_detections(mission, truth_detection_config(mission), seed=5, symmetries={})


def test_no_python_factor_is_linearised_against_the_whole_graph(mission, dets, monkeypatch):
    """Every call of a Python error function sees only its own factor's variables (iSAM2); batch keeps the
    nonlinear factors (Levenberg-Marquardt relinearises them)."""
    sizes = []
    native = gtsam.CustomFactor

    def counting(noise, keys, err):
        def wrapped(this, values, H):
            sizes.append((values.size(), len(keys)))
            return err(this, values, H)
        return native(noise, keys, wrapped)

    monkeypatch.setattr(gtsam, "CustomFactor", counting)
    res = run_slam(mission, dets, mode="pose", backend="isam2", symmetries={})
    assert res.metrics["landmark_updates"]["pose"] > 10 and sizes  # detection factors were linearised...
    assert max(n - k for n, k in sizes) == 0  # ...each against its own two variables only
    sizes.clear()
    run_slam(mission, dets, mode="pose", backend="batch", symmetries={})
    assert max(n for n, _ in sizes) > 50  # batch: LM evaluates the nonlinear factors on the whole Values


def _two_keyframes(kind: str, yaw_err: float, pos_err: float, huber_k: float | None = None, shift_m: float = 0.0):
    """A vehicle known to 1 mm at two keyframes 1 m apart and one landmark seen from both, created off its true pose
    by ``pos_err`` (m) and ``yaw_err`` (rad): a nonlinear problem whose optimum is near the truth."""
    g = GraphBackend(kind, 6)
    P = np.diag([1e-6] * 3 + [1e-4] * 3)
    x0 = np.array([0.0, 0.0, 5.0, 0.5, 0.0, 0.0])
    g.start(0.0, x0, P)
    lm = np.array([0.5, 1.0, 5.0, 0.1, 0.2, 0.3])
    cov = np.diag([1e-4] * 3 + [1e-3] * 3)
    kl = g.new_landmark(lm + np.r_[pos_err, 0.0, 0.0, 0.0, 0.0, yaw_err])
    g.add_factor(fac.prior_factor(kl, lm, np.eye(6) * 100.0, "a weak landmark prior"))
    for k, x in enumerate((x0, x0 + np.r_[1.0, 0, 0, 0, 0, 0])):
        if k:
            g.seg.predict(np.eye(6), x - x0, np.eye(6) * 1e-6)
            g.keyframe(float(k), x)
        T_wv = RigidTransform.from_xyz_rpy(x[0:3], [0.0, 0.0, 0.0])
        seen = lm[:3] + [0.0, shift_m * k, 0.0]  # shift_m: the second detection displaced (an outlier)
        det = Detection("a", 0.0, T_wv.inverse() @ RigidTransform.from_xyz_rpy(seen, lm[3:]), cov, stamp_s=float(k))
        m = measurement_from_detection(det, RigidTransform.identity())
        g.add_landmark_factor((g.key, kl), partial(fac.landmark_factor, g.key, kl, m, np.eye(3), "pose", m.noise_cov,
                                                   n_v=6, yaw_bias=False, i_yaw=-1, huber_k=huber_k),
                              robust=huber_k is not None)
        g.flush()
    g.solve()
    return g, kl


def test_detection_factors_are_relinearised_past_the_threshold_and_agree_with_batch():
    g, kl = _two_keyframes("isam2", yaw_err=0.4, pos_err=0.3)
    assert g.n_relinearized >= 1  # the landmark moved 0.3 m / 0.4 rad from where it was created
    b, _ = _two_keyframes("batch", yaw_err=0.4, pos_err=0.3)
    assert np.abs(g.vector(kl, True) - b.vector(kl, True)).max() < 1e-6
    assert np.abs(g.cov(kl) - b.cov(kl)).max() < 1e-9
    small, _ = _two_keyframes("isam2", yaw_err=0.01, pos_err=0.01)
    assert small.n_relinearized == 0  # within the threshold: linearised once, where the variables were created
    with pytest.raises(SlamError, match=r"refers to variables the graph does not have: \['l7'\]"):
        small.add_landmark_factor((small.key, fac.L(7)), None)  # never a raw KeyError


class _Mapper(ObjectMapper):
    pass


class _Session(SlamSession):
    def _make_mapper(self, ekf):
        return _Mapper(ekf, self.cfg, self.mode, self.symmetries, self.vehicle.T_vehicle_scanner, self._log)


def test_sessions_build_their_filter_and_mapper_through_the_factory_hooks(mission):
    g = GraphSession(mission.vehicle, mode="pose", symmetries={}, backend="isam2")
    s = _Session(mission.vehicle, mode="pose", symmetries={})
    for sess in (g, s):
        sess.add_attitude(0.0, [0.0, 0.0, 0.0])  # the first message starts the session
    assert type(g.ekf) is FrontEkf and g.ekf.backend is g.graph and g.ekf.recorder is None
    assert type(g.mapper) is GraphMapper and g.mapper.records is g.log
    assert type(s.mapper) is _Mapper and s.ekf.recorder is not None


def test_robust_detection_factors_are_reweighted_at_the_final_estimate():
    """With a Huber kernel, a factor's weight is that of its linearisation point: iSAM2 reweights every detection
    factor at the final estimate (IRLS rounds), so its end-of-dive map agrees with batch LM's (a 4 cm outlier,
    k = 1)."""
    gi, kl = _two_keyframes("isam2", yaw_err=0.05, pos_err=0.05, huber_k=1.0, shift_m=0.04)
    gb, _ = _two_keyframes("batch", yaw_err=0.05, pos_err=0.05, huber_k=1.0, shift_m=0.04)
    assert gi.robust and gi.n_relinearized >= 2
    assert np.abs(gi.vector(kl, True) - gb.vector(kl, True)).max() < 1e-8  # 3e-5 with the weights of creation


def _biased_sighting(kind: str, bias_true: float, bias_index: int = 6):
    """A vehicle known to 1 mm whose AHRS yaw is off by ``bias_true`` (rad; prior 0 +- 0.1) sees a surveyed landmark
    (known to 0.1 mm / 1e-4 rad) twice: the detections fix the bias, which moves far less than the 0.1 threshold."""
    g = GraphBackend(kind, 7, bias_index=bias_index)
    x0 = np.array([0.0, 0.0, 5.0, 0.5, 0.0, 0.0, 0.0])
    g.start(0.0, x0, np.diag([1e-6] * 3 + [1e-4] * 3 + [0.1 ** 2]))
    lm = np.array([1.0, 1.5, 5.0, 0.1, 0.2, 0.3])
    kl = g.new_landmark(lm)
    g.add_factor(fac.prior_factor(kl, lm, np.diag([1e-8] * 3 + [1e-8] * 3), "a surveyed landmark"))
    cov = np.diag([1e-6] * 3 + [1e-6] * 3)
    R_ahrs = fac.kern.rot_z(bias_true)  # AHRS yaw = true yaw (0) + bias
    for k, x in enumerate((x0, x0 + np.r_[0.5, 0, 0, 0, 0, 0, 0])):
        if k:
            F = np.eye(7)
            g.seg.predict(F, x - x0, np.diag([1e-6] * 6 + [1e-12]))
            g.keyframe(float(k), x)  # the guess: the prediction, at the prior's bias
        T_wv = RigidTransform.from_xyz_rpy(x[0:3], [0.0, 0.0, 0.0])
        det = Detection("a", 0.0, T_wv.inverse() @ RigidTransform.from_xyz_rpy(lm[:3], lm[3:]), cov, stamp_s=float(k))
        m = measurement_from_detection(det, RigidTransform.identity())
        g.add_landmark_factor((g.key, kl), partial(fac.landmark_factor, g.key, kl, m, R_ahrs, "pose", m.noise_cov,
                                                   n_v=7, yaw_bias=True, i_yaw=6))
        g.flush()
    g.solve()
    return g


def test_a_yaw_bias_that_moves_less_than_the_threshold_still_relinearises_the_detection_factors():
    """One threshold over mixed units (0.1) is 5.7 degrees for the yaw bias: a keyframe's bias has its own
    (``bias_threshold``, 0.005 rad), so a 0.05 rad bias relinearises the detections made at the prior's bias, and
    iSAM2 then reaches batch's optimum (the true bias); without it iSAM2 keeps the first linearisation."""
    b = _biased_sighting("batch", 0.05)
    g = _biased_sighting("isam2", 0.05)
    assert g.n_relinearized >= 2
    assert abs(b.vector(fac.X(1), True)[6] - 0.05) < 1e-4  # the oracle: batch recovers the true bias
    assert np.abs(g.vector(fac.X(1), True) - b.vector(fac.X(1), True)).max() < 1e-6
    old = _biased_sighting("isam2", 0.05, bias_index=-1)  # the bias' own threshold off: the former rule
    assert old.n_relinearized == 0
    assert np.abs(old.vector(fac.X(1), True) - b.vector(fac.X(1), True))[0:3].max() > 5e-4  # 0.6-1.5 mm off
