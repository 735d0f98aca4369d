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


def _flip_oracle_error(Re, Rt, a, flip_axis):
    """Brute force: the smallest angle of ``Rt^T Re S`` over S = Exp(theta a) F^k, k = 0, 1."""
    thetas = np.linspace(-np.pi, np.pi, 721)
    F = _rot(flip_axis, np.pi)
    return min(Rotation.from_matrix(Rt.T @ Re @ _rot(a, t) @ G).magnitude() for t in thetas for G in (np.eye(3), F))


def test_cylinder_turned_end_for_end_is_the_same_only_with_flip():
    a = np.array([1.0, 0.0, 0.0])
    plain, cylinder = Symmetry("continuous", a), Symmetry("continuous", a, flip=True)
    R = _random_rotations(1, 11)[0]
    turned = R @ _rot([0, 0, 1], np.pi)  # end for end: a half turn about an axis perpendicular to x
    assert plain.rotation_error_rad(turned, R) == pytest.approx(np.pi, abs=1e-7)
    assert cylinder.rotation_error_rad(turned, R) == pytest.approx(0.0, abs=1e-7)
    # matches the brute-force minimum over the group (continuous angle x the two ends)
    for Re, Rt in zip(_random_rotations(15, 12), _random_rotations(15, 13)):
        brute = _flip_oracle_error(Re, Rt, a, [0, 1, 0])
        assert cylinder.rotation_error_rad(Re, Rt) <= brute + 1e-9
        assert cylinder.rotation_error_rad(Re, Rt) == pytest.approx(brute, abs=5e-3)


def test_flip_rotation_reverses_the_axis_and_finite_part_lists_both_ends():
    s = Symmetry("continuous", [0.0, 1.0, 1.0], flip=True)
    F = s.flip_rotation
    np.testing.assert_allclose(F @ F.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(F) == pytest.approx(1.0)
    np.testing.assert_allclose(F @ s.axis_object, -s.axis_object, atol=1e-12)
    assert s.perpendicular_axis() @ s.axis_object == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(s.finite_rotations(), [np.eye(3), F])
    assert Symmetry("continuous", [0, 0, 1]).finite_rotations().shape == (1, 3, 3)
    assert Symmetry("discrete", [0, 0, 1], 3).finite_rotations().shape == (3, 3, 3)
    assert Symmetry("continuous", [0, 0, 1]).flip_rotation is None
    np.testing.assert_allclose(s.unobservable_axes, [s.axis_object])  # the flip is isolated, not unobservable


def test_canonicalize_flipped_cylinder_is_invariant_over_both_ends():
    a = np.array([0.0, 0.0, 1.0])
    s = Symmetry("continuous", a, flip=True)
    for R in _random_rotations(20, 14):
        c1 = s.canonicalize(R)
        c2 = s.canonicalize(R @ _rot(a, 0.7) @ _rot([1, 0, 0], np.pi))
        np.testing.assert_allclose(c1, c2, atol=1e-9)
        assert s.rotation_error_rad(c1, R) == pytest.approx(0.0, abs=1e-6)
        assert (c1 @ a)[2] >= 0.0  # the end chosen: the axis pointing down (the default reference, +z)
    # a horizontal axis: the end is chosen by the next reference, +x
    c = s.canonicalize(_rot([0, 1, 0], -np.pi / 2))  # object z -> parent -x
    assert (c @ a)[0] == pytest.approx(1.0)


def test_flip_is_refused_outside_a_continuous_symmetry_and_round_trips():
    with pytest.raises(InputError, match="flip.*continuous.*'discrete'"):
        Symmetry("discrete", [0, 0, 1], 2, flip=True)
    with pytest.raises(InputError, match="'flip'.*True or False"):
        Symmetry("continuous", [0, 0, 1], flip="yes")
    s = Symmetry.from_dict(Symmetry("continuous", [0, 0, 1], flip=True).to_dict())
    assert s.flip and s.kind == "continuous"
    assert not Symmetry.from_dict({"kind": "continuous", "axis_object": [0, 0, 1]}).flip  # databases written before
    assert "flip" not in Symmetry("continuous", [0, 0, 1]).to_dict()
