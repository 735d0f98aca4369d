"""Tests that kill surviving mutants of ``semslam/slam/_ekf_kernels.py`` (benchmarks/mutation.py).

Oracles: scipy's rotations, closed forms and dense recomputations, never the kernel under test.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.slam import _ekf_kernels as kern


@pytest.mark.parametrize("angle", [1e-9, 3e-7, 9e-7, 2e-6, 1e-3, 1.0, 3.0, np.pi - 2e-4, np.pi - 2e-5, np.pi - 1e-9])
def test_so3_log_matches_scipy_at_all_scales(angle):
    """Catches a wrong small-angle branch of ``so3_log`` (e.g. ``1.5 v`` for ``0.5 v``: below 1e-6 rad the
    rotation vector is half the skew part of R) and errors in the general and near-pi branches: the rotation
    vector of ``Rotation.from_rotvec(w)`` must be ``w`` (scipy), for angles from 1e-9 rad to pi."""
    rng = np.random.default_rng(int(angle * 1e9) % 2**32)
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    w = angle * u
    R = Rotation.from_rotvec(w).as_matrix()
    # within 1e-4 rad of pi the axis comes from the symmetric part of R: full precision there too
    rtol = 1e-6
    np.testing.assert_allclose(kern.so3_log(R), Rotation.from_matrix(R).as_rotvec(), rtol=rtol, atol=1e-15)
    np.testing.assert_allclose(kern.so3_log(R), w, rtol=rtol, atol=1e-15)


@pytest.mark.parametrize("pitch_deg", [-80.0, -30.0, 0.0, 45.0, 79.0])
def test_world_rate_to_rpy_inverts_rpy_to_world_rate(pitch_deg):
    """Catches a wrong inverse of the Euler-rate matrix (a sign, e.g. ``+sin(yaw)`` in the second row) and a
    clamp of ``cos(pitch)`` that bites away from gimbal lock (default ``min_cos_pitch`` must be tiny, 1e-3):
    ``world_rate_to_rpy(rpy) @ rpy_to_world_rate(rpy) = I`` wherever the filter uses it (|pitch| <= 80 deg), and
    ``rpy_to_world_rate`` maps Euler-angle rates to the world angular velocity (finite differences of scipy)."""
    rpy = np.array([0.3, np.radians(pitch_deg), 2.5])
    E = kern.rpy_to_world_rate(rpy)
    np.testing.assert_allclose(kern.world_rate_to_rpy(rpy) @ E, np.eye(3), atol=1e-12)
    h = 1e-7
    for k in range(3):   # w = Log(R(rpy + h e_k) R(rpy)^T) / h  (world frame, left perturbation)
        d = np.zeros(3)
        d[k] = h
        R1 = Rotation.from_euler("ZYX", (rpy + d)[::-1]).as_matrix()
        R0 = Rotation.from_euler("ZYX", rpy[::-1]).as_matrix()
        np.testing.assert_allclose(Rotation.from_matrix(R1 @ R0.T).as_rotvec() / h, E[:, k], atol=1e-6)


def test_world_rate_to_rpy_clamps_only_near_gimbal_lock():
    """Catches a clamp threshold that is not the argument: at pitch 90 deg (cos = 6e-17) the result is finite and
    equals the formula with ``cos(pitch)`` replaced by ``min_cos_pitch``."""
    rpy = np.array([0.0, np.pi / 2, 0.0])
    M = kern.world_rate_to_rpy(rpy, min_cos_pitch=1e-3)
    assert np.isfinite(M).all()
    assert M[0, 0] == pytest.approx(1.0 / 1e-3) and M[2, 0] == pytest.approx(1.0 / 1e-3)


@pytest.mark.parametrize("cols", [0, 1, 2, 5])
def test_subtract_outer_inplace_equals_dense(cols):
    """Catches an early return on the wrong shape (e.g. on a single-column ``W``, the usual rank-one downdate):
    ``P`` must become ``P - W W^T`` in place for any number of columns (nothing to do for none)."""
    rng = np.random.default_rng(cols)
    A = rng.normal(size=(7, 7))
    P = np.ascontiguousarray(A @ A.T + 7 * np.eye(7))
    W = rng.normal(size=(7, cols))
    expected = P - W @ W.T
    ref = P
    kern.subtract_outer_inplace(P, W)
    assert P is ref
    np.testing.assert_allclose(P, expected, rtol=1e-13, atol=1e-13)
