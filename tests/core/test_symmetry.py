"""Symmetry maths: errors modulo the group, canonical representatives, unobservable axes (analytic cases)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.errors import InputError
from semslam.symmetry import Symmetry


def _rot(axis, angle_rad):
    axis = np.asarray(axis, float)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle_rad).as_matrix()


def _random_rotations(n, seed):
    return Rotation.random(n, random_state=seed).as_matrix()


def test_none_error_is_geodesic_angle():
    s = Symmetry()
    R = _random_rotations(1, 0)[0]
    assert s.rotation_error_rad(R @ _rot([1, 2, 3], 0.3), R) == pytest.approx(0.3, abs=1e-9)
    assert s.unobservable_axes.shape == (0, 3)
    np.testing.assert_allclose(s.canonicalize(R), R)


def test_discrete_error_modulo_group():
    s = Symmetry("discrete", [0, 0, 1], 2)
    R = _random_rotations(1, 1)[0]
    flipped = R @ _rot([0, 0, 1], np.pi)
    assert s.rotation_error_rad(flipped, R) == pytest.approx(0.0, abs=1e-7)
    assert Symmetry().rotation_error_rad(flipped, R) == pytest.approx(np.pi, abs=1e-7)
    # 170 degrees about the axis is 10 degrees away from the flipped twin
    assert s.rotation_error_rad(R @ _rot([0, 0, 1], np.radians(170)), R) == pytest.approx(np.radians(10), abs=1e-9)
    # a rotation about a perpendicular axis is not hidden by the group
    assert s.rotation_error_rad(R @ _rot([1, 0, 0], 0.2), R) == pytest.approx(0.2, abs=1e-9)
    assert s.unobservable_axes.shape == (0, 3)


def test_discrete_error_matches_brute_force_order_4():
    s = Symmetry("discrete", [1, 1, 0], 4)
    Rs = _random_rotations(40, 2)
    Rt = _random_rotations(40, 3)
    a = s.axis_object
    for Re, Rtr in zip(Rs, Rt):
        brute = min(Rotation.from_matrix(Rtr.T @ Re @ _rot(a, k * np.pi / 2)).magnitude() for k in range(4))
        assert s.rotation_error_rad(Re, Rtr) == pytest.approx(brute, abs=1e-7)


def test_continuous_error_ignores_rotation_about_axis():
    a = np.array([0.0, 1.0, 0.0])
    s = Symmetry("continuous", a)
    R = _random_rotations(1, 4)[0]
    assert s.rotation_error_rad(R @ _rot(a, 2.0), R) == pytest.approx(0.0, abs=1e-7)
    assert s.rotation_error_rad(R @ _rot([1, 0, 0], 0.25), R) == pytest.approx(0.25, abs=1e-9)
    # brute force: minimum over the rotations about the axis
    Re = _random_rotations(1, 5)[0]
    thetas = np.linspace(-np.pi, np.pi, 20001)
    brute = min(Rotation.from_matrix(R.T @ Re @ _rot(a, t)).magnitude() for t in thetas[::50])
    assert s.rotation_error_rad(Re, R) == pytest.approx(brute, abs=2e-3)
    assert s.rotation_error_rad(Re, R) <= brute + 1e-9
    np.testing.assert_allclose(s.unobservable_axes, [a])


def test_canonicalize_discrete_is_group_invariant_and_equivalent():
    s = Symmetry("discrete", [0, 0, 1], 2)
    for R in _random_rotations(20, 6):
        c1 = s.canonicalize(R)
        c2 = s.canonicalize(R @ _rot([0, 0, 1], np.pi))
        np.testing.assert_allclose(c1, c2, atol=1e-9)
        assert s.rotation_error_rad(c1, R) == pytest.approx(0.0, abs=1e-6)
        # the representative is the one closest to the identity
        assert Rotation.from_matrix(c1).magnitude() <= Rotation.from_matrix(R).magnitude() + 1e-9


def test_canonicalize_continuous_is_invariant_and_points_u_to_reference():
    a = np.array([0.0, 0.0, 1.0])
    s = Symmetry("continuous", a)
    for R in _random_rotations(20, 7):
        c1 = s.canonicalize(R)
        c2 = s.canonicalize(R @ _rot(a, 1.234))
        np.testing.assert_allclose(c1, c2, atol=1e-9)
        np.testing.assert_allclose(c1 @ a, R @ a, atol=1e-9)  # the axis is untouched
        assert s.rotation_error_rad(c1, R) == pytest.approx(0.0, abs=1e-6)
        # u = object x axis (most perpendicular basis vector to a); it is as close to +z as possible
        thetas = np.linspace(-np.pi, np.pi, 3601)
        best = max((R @ _rot(a, t) @ [1, 0, 0])[2] for t in thetas)
        assert (c1 @ [1.0, 0, 0])[2] >= best - 1e-6
    # axis parallel to the reference: falls back to +x, still deterministic
    c = s.canonicalize(np.eye(3))
    assert (c @ [1.0, 0, 0])[0] == pytest.approx(1.0)


def test_bad_input_raises_named_error():
    s = Symmetry("discrete", [0, 0, 1], 2)
    with pytest.raises(InputError, match="R_est"):
        s.rotation_error_rad(np.ones((3, 3)), np.eye(3))
    with pytest.raises(InputError, match="continuous"):
        Symmetry("continuous", [0, 0, 1]).group_rotations()
    with pytest.raises(InputError, match="R_parent_object"):
        s.canonicalize(np.eye(4))


def test_to_dict_round_trip_unchanged():
    s = Symmetry("discrete", [0, 0, 2], 3)
    s2 = Symmetry.from_dict(s.to_dict())
    assert s2.kind == "discrete" and s2.order == 3
    np.testing.assert_allclose(s2.axis_object, [0, 0, 1])
