"""The honest pose covariance (issue 29, item 3): correlated residuals counted once, the search's alternative
hypotheses widening the covariance along a flip, symmetry-equivalent alternatives adding nothing, and untrusted poses
(ambiguous orientation, no alignment) given a wide covariance instead of a confident wrong one."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.pose.covariance import (AMBIGUOUS_ROTATION_VARIANCE_RAD2, CovarianceCalibration,
                                             effective_points, hypothesis_spread, pose_covariance,
                                             tangent_difference, widen_untrusted)
from semslam.symmetry import Symmetry


def _T(rotvec, t):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def test_effective_points_count_each_correlation_cell_once():
    g = np.arange(0.0005, 0.02, 0.001)  # 1 mm grid filling a 2 cm cube: 20^3 points in 2^3 cells of 1 cm
    pts = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    assert len(pts) == 8000
    assert effective_points(pts, 0.01) == 8
    assert effective_points(pts, 0.0005) == 8000


def test_tangent_difference_recovers_a_left_perturbation():
    T0 = _T([0.3, -0.2, 1.0], [0.5, -1.0, 2.0])
    delta = np.array([0.01, -0.02, 0.005, 0.05, -0.03, 0.2])
    P = _T(delta[3:], delta[:3])  # p -> R(phi) p + rho
    np.testing.assert_allclose(tangent_difference(T0, P @ T0), delta, atol=1e-12)


def test_an_equal_score_flip_widens_the_rotation_along_the_flip_only():
    T0 = _T([0.1, 0.2, -0.3], [0.2, 0.1, 1.5])
    flip = _T([np.pi, 0.0, 0.0], [0.0, 0.0, 0.0]) @ T0  # a half turn about the target x axis
    C, w = hypothesis_spread(T0, [(0.0, flip)], Symmetry(), 0.01)
    assert w == pytest.approx(1.0)
    # weight 1 against the estimate's own 1: variance (pi^2) / 2 along x, nothing else
    assert C[3, 3] == pytest.approx(np.pi ** 2 / 2, rel=1e-6)
    assert np.abs(C - np.diag(np.diag(C))).max() < 1e-9 and np.abs(np.delete(np.diag(C), 3)).max() < 1e-9


def test_a_much_worse_alternative_adds_nothing():
    T0 = _T([0.1, 0.2, -0.3], [0.2, 0.1, 1.5])
    flip = _T([np.pi, 0.0, 0.0], [0.0, 0.0, 0.0]) @ T0
    C, w = hypothesis_spread(T0, [(0.5, flip)], Symmetry(), 0.01)  # 50 score scales worse
    assert w < 1e-6 and np.abs(C).max() == 0.0


def test_a_symmetry_equivalent_alternative_adds_no_spread():
    """A half turn about the object's z axis is the same pose for an order-2 object: no spread."""
    sym = Symmetry("discrete", (0.0, 0.0, 1.0), 2)
    T0 = _T([0.4, -0.1, 0.7], [0.1, -0.2, 1.2])
    G = Rotation.from_rotvec([0.0, 0.0, np.pi]).as_matrix()
    Tk = T0.copy()
    Tk[:3, :3], Tk[:3, 3] = G.T @ T0[:3, :3], G.T @ T0[:3, 3]
    C, w = hypothesis_spread(T0, [(0.0, Tk)], sym, 0.01)
    assert w == pytest.approx(1.0) and np.abs(C).max() < 1e-18
    # without the symmetry the same alternative is a half-turn away
    C_none, _ = hypothesis_spread(T0, [(0.0, Tk)], Symmetry(), 0.01)
    assert np.trace(C_none[3:, 3:]) == pytest.approx(np.pi ** 2 / 2, rel=1e-6)


def _box_corner(spacing_m, seed, sigma_m=0.001):
    """Three orthogonal faces (10 cm) sampled at ``spacing_m``, noisy along their normals: aligned points, their
    model points and normals (the truth pose is the identity)."""
    rng = np.random.default_rng(seed)
    g = np.arange(0.0, 0.1, spacing_m)
    u, v = [a.ravel() for a in np.meshgrid(g, g, indexing="ij")]
    faces = []
    for axis in range(3):
        q = np.zeros((len(u), 3))
        others = [a for a in range(3) if a != axis]
        q[:, others[0]], q[:, others[1]] = u, v
        n = np.zeros_like(q)
        n[:, axis] = 1.0
        faces.append((q, n))
    q = np.vstack([f[0] for f in faces])
    n = np.vstack([f[1] for f in faces])
    p = q + rng.normal(0.0, sigma_m, (len(q), 1)) * n
    return p, q, n


def test_denser_sampling_of_the_same_surface_does_not_shrink_the_covariance():
    """Residuals within a correlation cell are not independent information: sampling the same faces 4x denser
    (16x the points) leaves the Hessian term within 20 % (Gauss-Newton alone would shrink it 16x)."""
    cal = CovarianceCalibration(correlation_length_m=0.01, scale=1.0, floor_translation_m=0.0, floor_rotation_rad=0.0,
                                floor_arc_m=0.0)
    out = []
    for spacing in (0.004, 0.001):
        p, q, n = _box_corner(spacing, seed=1)
        rows = np.arange(len(q))
        cov, _, diag = pose_covariance(p, np.zeros(len(p)), rows, q, n, np.eye(4), Symmetry(), calibration=cal)
        out.append(np.diag(cov))
        assert diag["n_inliers"] == len(p)
    ratio = out[1] / out[0]
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio


def test_independent_residuals_give_a_consistent_covariance():
    """Points farther apart than the correlation length: the covariance is Gauss-Newton's, and the linearised
    least-squares estimates from 300 noise draws have a mean NEES of 6 (chi-square with 6 dof)."""
    cal = CovarianceCalibration(correlation_length_m=0.001, scale=1.0, floor_translation_m=0.0, floor_rotation_rad=0.0,
                                floor_arc_m=0.0)
    nees = []
    for seed in range(300):
        p, q, n = _box_corner(0.02, seed=seed, sigma_m=0.002)
        J = np.hstack([n, np.cross(p, n)])
        r = np.einsum("ij,ij->i", p - q, n)
        delta = -np.linalg.lstsq(J, r, rcond=None)[0]  # the Gauss-Newton step from the identity: T = Exp(delta)
        T_est = _T(delta[3:], delta[:3])
        p_est = p @ T_est[:3, :3].T + T_est[:3, 3]
        cov, T_so, _ = pose_covariance(p_est, np.zeros(len(p)), np.arange(len(q)), q, n, T_est, Symmetry(),
                                       calibration=cal)
        from semslam.geometry import rpy_from_rotation, wrap_angle

        e = np.concatenate([T_so[:3, 3], wrap_angle(rpy_from_rotation(T_so[:3, :3]))])  # truth: identity
        nees.append(e @ np.linalg.solve(cov, e))
    assert 5.2 <= np.mean(nees) <= 6.8, np.mean(nees)


def test_an_ambiguous_orientation_keeps_its_position_and_loses_its_rotation():
    C = np.diag([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4])
    W = widen_untrusted(C, aligned=True, ambiguous=True, radius_m=0.2)
    np.testing.assert_array_equal(W[:3, :3], C[:3, :3])
    np.testing.assert_allclose(np.diag(W)[3:], 1e-4 + AMBIGUOUS_ROTATION_VARIANCE_RAD2)
    # a half-turn error about one axis then costs at most pi^2 / (pi^2 / 3) = 3 in the NEES
    e = np.array([0, 0, 0, np.pi, 0, 0])
    assert e @ np.linalg.solve(W, e) <= 3.0


def test_a_pose_that_does_not_align_is_not_trusted_anywhere_and_a_trusted_one_is_unchanged():
    C = np.diag([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4])
    W = widen_untrusted(C, aligned=False, ambiguous=False, radius_m=0.2)
    assert np.all(np.diag(W)[:3] >= 0.04) and np.all(np.diag(W)[3:] >= AMBIGUOUS_ROTATION_VARIANCE_RAD2)
    np.testing.assert_array_equal(widen_untrusted(C, aligned=True, ambiguous=False, radius_m=0.2), C)


def test_half_turns_turn_the_aligned_cluster_about_its_principal_axes_through_its_centroid():
    from semslam.registration.ambiguity import half_turns

    rng = np.random.default_rng(0)
    src = rng.normal(0.0, 1.0, (500, 3)) * [0.3, 0.1, 0.02]  # principal axes x, y, z
    T = _T([0.2, -0.4, 0.1], [1.0, 2.0, -0.5])
    p = src @ T[:3, :3].T + T[:3, 3]
    c = p.mean(axis=0)
    turns = half_turns(T, src)
    assert len(turns) == 3
    axes = []
    for Tk in turns:
        pk = src @ Tk[:3, :3].T + Tk[:3, 3]
        np.testing.assert_allclose(pk.mean(axis=0), c, atol=1e-12)  # about the centroid
        rv = Rotation.from_matrix(Tk[:3, :3] @ T[:3, :3].T).as_rotvec()
        assert np.linalg.norm(rv) == pytest.approx(np.pi, abs=1e-6)
        axes.append(np.abs(T[:3, :3].T @ rv / np.pi))  # the turn's axis in the source frame
    np.testing.assert_allclose(sorted(np.argmax(a) for a in axes), [0, 1, 2])
    assert all(a.max() > 0.99 for a in axes)
