"""The factor-graph backends (``semslam/slam/graph/``): the graph's measurement model and
:class:`GraphSession`'s argument checks and estimates."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.dataset.vehicle import VehicleDescription
from semslam.errors import SlamError
from semslam.geometry import rotation_from_rpy
from semslam.slam.ekf import SemanticEkf


def test_graph_detection_model_uses_the_filters_yaw_bias_convention():
    """Catches a sign error of the yaw bias in the graph's detection model (``Rz(+b)`` for ``Rz(-b)``): the
    attitude the graph's factors use must be the filter's documented ``Rz(-b) R_ahrs`` (AHRS yaw = true + b)."""
    from semslam.slam.graph.factors import _Stub

    b = 0.2
    R = rotation_from_rpy(0.05, -0.1, 1.0)
    stub = _Stub(7, True, 6)
    stub.x[6] = b
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(7), yaw_bias=True)
    ekf.xa[ekf.i_yaw] = b
    np.testing.assert_allclose(stub.true_attitude(R), ekf.true_attitude(R), atol=1e-15)
    np.testing.assert_allclose(stub.true_attitude(R), rotation_from_rpy(0.05, -0.1, 1.0 - b), atol=1e-12)


@pytest.mark.parametrize("huber_k", [True, 0.0, -1.0, float("nan"), "2"])
def test_graph_session_rejects_a_bad_huber_threshold(huber_k):
    """Catches a Huber-threshold check that lets a bool (or a non-number) through (``and`` for ``or``): True,
    0, negatives, NaN and strings are refused, naming the argument."""
    from semslam.slam.graph.session import GraphSession

    with pytest.raises(SlamError, match="'huber_k' argument of GraphSession must be a number > 0 or None"):
        GraphSession(VehicleDescription.girona500(), mode="dr", huber_k=huber_k)


def test_isam2_estimate_has_3x3_covariances():
    """Catches a wrong slice of the graph estimate's velocity covariance (3 x 4): position and velocity covariances
    are 3 x 3, symmetric, positive definite."""
    from semslam.slam.graph.session import GraphSession

    s = GraphSession(VehicleDescription.girona500(), mode="dr", backend="isam2")
    for k in range(10):
        s.add_attitude(0.1 * k, [0.0, 0.0, 0.3])
        s.add_dvl(0.1 * k + 0.05, [0.3, 0.0, 0.0])
        s.add_depth(0.1 * k + 0.05, 2.0)
    est = s.estimate()
    for C in (est.position_cov_m2, est.velocity_cov):
        assert C.shape == (3, 3)
        np.testing.assert_allclose(C, C.T, atol=1e-15)
        assert np.linalg.eigvalsh(C).min() > 0


def _front_ekf():
    from types import SimpleNamespace

    from semslam.slam.graph.frontend import FrontEkf

    ekf = FrontEkf(np.zeros(3), np.array([0.4, 0.1, 0.0]), np.eye(14) * 0.01, dvl_calibration=True,
                   dvl_bias_sigma_mps=0.02, dvl_bias_tau_s=30.0, dvl_slope_bias_sigma_mps=0.05,
                   dvl_slope_bias_tau_s=8.0)
    rec = []
    ekf.backend = SimpleNamespace(seg=SimpleNamespace(predict=lambda F, u, Q: rec.append((F, u, Q))))
    return ekf, rec


@pytest.mark.parametrize("on_slope", [True, False])
def test_front_end_prediction_mirrors_the_filters_process_model(on_slope):
    """Catches a graph front end whose prediction segment is not the filter's process model (a growing DVL bias,
    ``exp(+dt / tau)``; the slope-bias noise applied off a slope): the segment ``(F, u, Q)`` it hands the graph
    must reproduce the filter's own step, ``x+ = F x + u`` and ``P+ = F P F^T + Q``, and ``Q`` must hold the
    Gauss-Markov gains ``sigma^2 (1 - exp(-2 dt / tau))`` (the slope bias's only on a slope)."""
    ekf, rec = _front_ekf()
    cal = ekf.indices("dvl_calibration")
    ekf.xa[cal[:6]] = [0.01, -0.02, 0.005, 0.03, 0.0, -0.01]
    x0, P0 = ekf.full_state()
    dt = 0.5
    ekf.predict(dt, rotation_from_rpy(0.0, 0.0, 0.4), velocity_rw=0.05, dvl_on_slope=on_slope)
    x1, P1 = ekf.full_state()
    (F, u, Q), = rec
    np.testing.assert_allclose(F @ x0 + u, x1, atol=1e-15)
    np.testing.assert_allclose(F @ P0 @ F.T + Q, P1, atol=1e-15)
    a, a2 = np.exp(-dt / 30.0), np.exp(-dt / 8.0)
    np.testing.assert_allclose(np.diag(Q)[cal[:3]], 0.02**2 * (1 - a * a), rtol=1e-12)
    np.testing.assert_allclose(np.diag(Q)[cal[3:6]], 0.05**2 * (1 - a2 * a2) if on_slope else 0.0, rtol=1e-12)
    np.testing.assert_allclose(x1[cal[:3]], a * np.array([0.01, -0.02, 0.005]), rtol=1e-12)


def test_front_end_signatures_keep_keyword_only_options():
    """Catches changed signatures of the front end (``predict``'s noise options and ``add_prior_landmarks``'s
    ``stamp_s`` are keyword-only, as the filter's): a positional call must fail, not be misread."""
    ekf, _ = _front_ekf()
    with pytest.raises(TypeError):
        ekf.predict(0.1, np.eye(3), 0.05)
    with pytest.raises(TypeError):
        ekf.add_prior_landmarks(np.zeros((1, 6)), np.eye(6)[None], ["valve"], 1.0)
