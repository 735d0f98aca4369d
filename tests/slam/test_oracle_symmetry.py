"""Oracle tests of orientation handling with symmetric objects: ``align_rotation`` against brute force over the
symmetry group, consensus initialisation across the +-pi heading cut and modulo discrete / continuous
symmetries, and the EKF orientation innovation of a symmetric landmark (issue 20, item 1)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.detection import Detection
from semslam.geometry import RigidTransform, rotation_from_rpy, rpy_from_rotation
from semslam.slam import _ekf_kernels as kern
from semslam.slam.association import align_rotation, innovation, measurement_from_detection
from semslam.slam.consensus import ConsensusInitializer, Observation, attitude_distance, quaternion_mean
from semslam.slam.ekf import SemanticEkf
from semslam.symmetry import Symmetry


def _angle(R1, R2):
    return float(np.linalg.norm(Rotation.from_matrix(R1 @ R2.T).as_rotvec()))


def _random_rotations(rng, n):
    return Rotation.random(n, random_state=int(rng.integers(2**31))).as_matrix()


# ------------------------------------------------------------------------------------ align_rotation
@pytest.mark.parametrize("order", [2, 3, 4, 6])
def test_align_rotation_discrete_is_brute_force_closest(order):
    """Catches a group element applied on the wrong side (``S_k R`` in the world frame instead of ``R S_k`` in
    the object frame), the wrong step (``pi / order``), an off-by-one in the loop, or the farthest element
    kept: the result is the element of ``{R S_k}`` closest to ``R_ref``, found here by brute force with
    scipy rotations, and it is equivalent to ``R`` under the symmetry."""
    rng = np.random.default_rng(order)
    for _ in range(50):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        sym = Symmetry("discrete", axis_object=axis, order=order)
        R, R_ref = _random_rotations(rng, 2)
        cands = [R @ Rotation.from_rotvec(axis * 2 * math.pi * k / order).as_matrix() for k in range(order)]
        best = min(cands, key=lambda C: _angle(C, R_ref))
        got = align_rotation(R, R_ref, sym, np.zeros((0, 3)))
        np.testing.assert_allclose(got, best, atol=1e-12)
        assert sym.rotation_error_rad(got, R) < 1e-6  # same physical orientation
        assert _angle(got, R_ref) <= min(_angle(C, R_ref) for C in cands) + 1e-12


def test_align_rotation_order_two_about_z_flips_heading():
    """Catches an order-2 symmetry that is not applied: an elbow (order 2 about its z axis) seen at yaw
    10 deg + 180 deg against a landmark at yaw 10 deg aligns to yaw 10 deg exactly."""
    sym = Symmetry("discrete", axis_object=[0.0, 0.0, 1.0], order=2)
    R = rotation_from_rpy(0.0, 0.0, math.radians(190.0))
    got = align_rotation(R, rotation_from_rpy(0.0, 0.0, math.radians(10.0)), sym, np.zeros((0, 3)))
    np.testing.assert_allclose(rpy_from_rotation(got), [0.0, 0.0, math.radians(10.0)], atol=1e-12)
    # no symmetry: unchanged
    np.testing.assert_array_equal(align_rotation(R, np.eye(3), Symmetry(), np.zeros((0, 3))), R)


def test_align_rotation_continuous_axis_is_brute_force_closest():
    """Catches a free rotation about an unobservable world axis that is not the closest one (wrong sign of
    the angle, rotation on the wrong side, or about the object axis instead of the world axis): the result
    ``Rot(u, beta) R`` is compared with a dense scan of ``beta`` refined by golden section."""
    rng = np.random.default_rng(11)
    for _ in range(30):
        R, R_ref = _random_rotations(rng, 2)
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        got = align_rotation(R, R_ref, Symmetry(), u[None])

        def f(betas):  # angle between Rot(u, beta) R and R_ref, for an array of beta
            M = Rotation.from_rotvec(np.outer(np.atleast_1d(betas), u)).as_matrix() @ R @ R_ref.T
            return np.arccos(np.clip((np.trace(M, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))

        grid = np.linspace(-math.pi, math.pi, 721)
        b0 = grid[int(np.argmin(f(grid)))]
        lo, hi = b0 - 0.01, b0 + 0.01
        for _ in range(60):
            m1, m2 = lo + 0.382 * (hi - lo), lo + 0.618 * (hi - lo)
            f1, f2 = f(np.array([m1, m2]))
            lo, hi = (lo, m2) if f1 < f2 else (m1, hi)
        best = Rotation.from_rotvec(u * 0.5 * (lo + hi)).as_matrix() @ R
        assert _angle(got, R_ref) <= f(0.5 * (lo + hi))[0] + 1e-7
        np.testing.assert_allclose(got, best, atol=1e-5)
        # the change is a rotation about u only
        w = Rotation.from_matrix(got @ R.T).as_rotvec()
        assert np.linalg.norm(np.cross(w, u)) < 1e-9


def test_align_rotation_discrete_and_free_axis_is_jointly_closest():
    """Catches a greedy (not joint) minimisation over the equivalence class ``{Rot(u, beta) R S_k}`` when the
    object has a discrete symmetry and the detection leaves a free world axis ``u`` (the docstring: "closest to
    R_ref" under both). Hand case: an elbow (order 2 about its z axis), free rotation about world x, measured at
    roll 180 deg, pitch -30 deg, landmark at identity: ``Rx(-180) R = Ry(+30 deg)`` is 30 deg away, but picking
    ``S_1`` first (trace -0.73 > -1) leaves ``Ry(150 deg)``, 150 deg away. Then 100 random cases against a
    dense scan of ``beta`` for each ``k``."""
    sym = Symmetry("discrete", axis_object=[0.0, 0.0, 1.0], order=2)
    R = rotation_from_rpy(math.pi, math.radians(-30.0), 0.0)
    got = align_rotation(R, np.eye(3), sym, np.array([[1.0, 0.0, 0.0]]))
    assert _angle(got, np.eye(3)) == pytest.approx(math.radians(30.0), abs=1e-9)
    rng = np.random.default_rng(12)
    betas = np.linspace(-math.pi, math.pi, 3601)
    for _ in range(100):
        R, R_ref = _random_rotations(rng, 2)
        a, u = rng.normal(size=(2, 3))
        a, u = a / np.linalg.norm(a), u / np.linalg.norm(u)
        sym = Symmetry("discrete", axis_object=a, order=2)
        got = align_rotation(R, R_ref, sym, u[None])
        Rb = Rotation.from_rotvec(np.outer(betas, u)).as_matrix()
        best = min(np.arccos(np.clip((np.trace(Rb @ R @ S @ R_ref.T, axis1=1, axis2=2) - 1) / 2, -1, 1)).min()
                   for S in sym.group_rotations())
        assert _angle(got, R_ref) <= best + 1e-5



def test_align_rotation_of_a_cylinder_takes_the_closer_end():
    """Catches a cylinder's end-for-end turn that is not tried (``continuous:AXIS:flip``): a sonobuoy seen the
    other way round (its axis reversed, then a free turn about the world axis it maps to) aligns to within the
    brute-force optimum over both ends and the free angle, which is 0 for an exact flip."""
    rng = np.random.default_rng(13)
    betas = np.linspace(-math.pi, math.pi, 3601)
    for _ in range(40):
        R_ref = _random_rotations(rng, 1)[0]
        a = rng.normal(size=3)
        a /= np.linalg.norm(a)
        sym = Symmetry("continuous", axis_object=a, flip=True)
        R = R_ref @ sym.flip_rotation @ Rotation.from_rotvec(a * rng.uniform(-3, 3)).as_matrix()
        u = R @ a  # the free world axis of this detection
        got = align_rotation(R, R_ref, sym, u[None])
        assert _angle(got, R_ref) < 1e-6
        assert _angle(align_rotation(R, R_ref, Symmetry("continuous", axis_object=a), u[None]), R_ref) > 3.0
        R2 = _random_rotations(rng, 1)[0]
        got = align_rotation(R2, R_ref, sym, (R2 @ a)[None])
        Rb = Rotation.from_rotvec(np.outer(betas, R2 @ a)).as_matrix()
        best = min(np.arccos(np.clip((np.trace(Rb @ R2 @ S @ R_ref.T, axis1=1, axis2=2) - 1) / 2, -1, 1)).min()
                   for S in (np.eye(3), sym.flip_rotation))
        assert _angle(got, R_ref) <= best + 1e-5


# ------------------------------------------------------------------------------------ consensus
def test_attitude_distance_and_quaternion_mean_hand_values():
    """Catches an attitude distance that is not ``sin^2(angle / 2)`` (or not sign invariant) and a mean that
    averages Euler angles (yaw 179 and -179 deg must average to 180, not 0)."""
    for deg in (0.0, 10.0, 90.0, 180.0):
        a = math.radians(deg)
        assert attitude_distance(np.eye(3), kern.axis_rotation(np.array([1.0, 2.0, 2.0]) / 3.0, a)) == pytest.approx(
            math.sin(a / 2) ** 2, abs=1e-12)
    Rm = quaternion_mean([rotation_from_rpy(0.0, 0.0, math.radians(y)) for y in (179.0, -179.0)])
    assert _angle(Rm, rotation_from_rpy(0.0, 0.0, math.pi)) < 1e-9
    Rm = quaternion_mean([rotation_from_rpy(0.0, 0.0, math.radians(y)) for y in (20.0, 40.0, 30.0)])
    assert _angle(Rm, rotation_from_rpy(0.0, 0.0, math.radians(30.0))) < 1e-9


def _obs(label, t, pos, R, sym=None, axes=None):
    return Observation(label, t, np.asarray(pos, dtype=float), R, sym or Symmetry(),
                       np.zeros((0, 3)) if axes is None else np.asarray(axes, dtype=float))


def test_consensus_heading_across_pi():
    """Catches consensus that compares or averages headings without wrapping: four valve observations at yaw
    179, -179, 178, -178 deg agree and initialise a landmark at yaw 180 deg (not 0), at the mean position."""
    ci = ConsensusInitializer(position_threshold_m=0.5, attitude_threshold=0.02, min_observations=4)
    yaws = [179.0, -179.0, 178.0, -178.0]
    positions = [[1.0, 2.0, 3.0], [1.1, 2.0, 3.0], [1.0, 2.1, 3.0], [1.1, 2.1, 3.2]]
    out = None
    for i, (y, p) in enumerate(zip(yaws, positions)):
        out = ci.add(_obs("valve", float(i), p, rotation_from_rpy(0.0, 0.0, math.radians(y))))
        if i < 3:
            assert out is None
    members, pos, Rm = out
    assert len(members) == 4
    np.testing.assert_allclose(pos, [1.05, 2.05, 3.05], atol=1e-12)
    yaw = rpy_from_rotation(Rm)[2]
    assert abs(abs(yaw) - math.pi) < math.radians(0.01)
    assert _angle(Rm, rotation_from_rpy(0.0, 0.0, math.pi)) < math.radians(0.01)
    assert ci.pools["valve"] == []


def test_consensus_excludes_a_minority_outlier():
    """Catches an average that includes an observation outside the consensus set: four observations at yaw
    ~30 deg and one at yaw 120 deg (same place); the landmark is at 30 deg and the outlier stays pooled."""
    ci = ConsensusInitializer(min_observations=4)
    out = ci.add(_obs("tee", 0.0, [0, 0, 0], rotation_from_rpy(0.0, 0.0, math.radians(120.0))))
    for i, y in enumerate([29.0, 31.0, 30.5, 29.5]):
        out = ci.add(_obs("tee", 1.0 + i, [0.01 * i, 0, 0], rotation_from_rpy(0.0, 0.0, math.radians(y))))
    members, pos, Rm = out
    assert len(members) == 4
    assert _angle(Rm, rotation_from_rpy(0.0, 0.0, math.radians(30.0))) < math.radians(0.01)
    np.testing.assert_allclose(pos, [0.015, 0.0, 0.0], atol=1e-12)
    assert len(ci.pools["tee"]) == 1


def test_consensus_discrete_symmetry_order_two():
    """Catches the class symmetry being ignored in agreement or averaging: an order-2 (about z) elbow observed
    at yaw 10, 190.5, 9.5, 190 deg is one orientation; the mean equals yaw 10 deg modulo the symmetry, and
    the quaternions are aligned before averaging (a naive mean of 10 and 190 deg would be ~100 deg or
    degenerate). Without the symmetry the same observations do not reach consensus."""
    sym = Symmetry("discrete", axis_object=[0.0, 0.0, 1.0], order=2)
    yaws = [10.0, 190.5, 9.5, 190.0]
    ci = ConsensusInitializer(min_observations=4)
    plain = ConsensusInitializer(min_observations=4)
    out = None
    for i, y in enumerate(yaws):
        R = rotation_from_rpy(0.0, 0.0, math.radians(y))
        out = ci.add(_obs("elbow", float(i), [2.0, 0.0, 1.0], R, sym))
        assert plain.add(_obs("elbow", float(i), [2.0, 0.0, 1.0], R)) is None
    members, _, Rm = out
    assert len(members) == 4
    assert sym.rotation_error_rad(Rm, rotation_from_rpy(0.0, 0.0, math.radians(10.0))) < math.radians(0.01)
    # the representative is one of the two equivalent orientations (a proper rotation, not a blend)
    err = min(_angle(Rm, rotation_from_rpy(0.0, 0.0, math.radians(a))) for a in (10.0, 190.0))
    assert err < math.radians(0.01)


def test_consensus_continuous_symmetry():
    """Catches the unobservable spin of an axisymmetric socket entering agreement or the mean: observations with
    arbitrary spins about the object's z axis (world axis given as ``axes_world``) and small tilts agree,
    and the mean's symmetry axis is the average one; spins alone never prevent consensus."""
    rng = np.random.default_rng(6)
    axis = np.array([0.0, 0.0, 1.0])
    sym = Symmetry("continuous", axis_object=axis)
    R_true = rotation_from_rpy(0.3, -0.2, 1.0)
    ci = ConsensusInitializer(min_observations=4)
    out = None
    tilts = [np.array([0.01, 0.0, 0.0]), np.array([-0.01, 0.0, 0.0]), np.array([0.0, 0.01, 0.0]),
             np.array([0.0, -0.01, 0.0])]
    for i, tilt in enumerate(tilts):
        spin = rng.uniform(-math.pi, math.pi)
        R = kern.so3_exp(tilt) @ R_true @ kern.axis_rotation(axis, spin)
        out = ci.add(_obs("socket", float(i), [0.0, 0.0, 0.0], R, sym, [R @ axis]))
    members, _, Rm = out
    assert len(members) == 4
    assert sym.rotation_error_rad(Rm, R_true) < 1e-4  # the tilts cancel


# ------------------------------------------------------------------------------------ the EKF orientation rows
def test_orientation_innovation_of_a_discrete_symmetric_landmark():
    """Catches a landmark update that ignores the discrete symmetry (an innovation of ~180 deg that would turn
    the landmark around or fail the gate): a tee at yaw 0.1 rad measured at yaw 0.1 + pi + 0.02 rad gives a
    0.02 rad orientation innovation about z, and across the +-pi cut as well."""
    sym = Symmetry("discrete", axis_object=[0.0, 0.0, 1.0], order=2)
    for yaw_l in (0.1, math.pi - 0.01):
        ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6) * 1e-4)
        G = np.zeros((6, 6))
        G[0:3, 0:3] = np.eye(3)
        ekf.add_landmark(np.r_[2.0, 0.0, 1.0, 0.0, 0.0, yaw_l], G, np.diag([1e-2] * 3 + [0.05**2] * 3), label="tee",
                         stamp_s=0.0)
        R_meas = rotation_from_rpy(0.0, 0.0, yaw_l + math.pi + 0.02)
        cov = np.diag([1e-4] * 3 + [0.02**2] * 3)
        det = Detection("tee", 0.0, RigidTransform.from_rotation_translation(R_meas, [2.0, 0.0, 1.0]), cov)
        meas = measurement_from_detection(det, RigidTransform.identity(), symmetry=sym)
        inn = innovation(ekf, 0, meas, np.eye(3), None)
        np.testing.assert_allclose(inn.nu[3:], [0.0, 0.0, 0.02], atol=1e-9)
        np.testing.assert_allclose(inn.nu[:3], 0.0, atol=1e-12)
        assert inn.d2_pose == pytest.approx(0.02**2 / (0.05**2 + 0.02**2), rel=1e-6)
        ekf.update(inn.idx, inn.H, inn.nu, inn.R)
        yaw = ekf.landmark_pose(0)[5]
        # Kalman gain on yaw: 0.05^2 / (0.05^2 + 0.02^2)
        expected = yaw_l + 0.02 * 0.05**2 / (0.05**2 + 0.02**2)
        assert abs(math.remainder(yaw - expected, 2 * math.pi)) < 1e-6
