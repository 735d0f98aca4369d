"""Sensor updates (``semslam/slam/sensors.py``): the DVL update's noise and calibration Jacobian, the depth
update's record, the DVL's flat-bottom test from its beams' slant ranges, the attitude input's stamps.

Oracles: the dense Kalman update written here, with the DVL model's Jacobian from central differences of
``h(x) = (1 + k) Rz(delta) v + b + s`` and its noise ``noise_abs + noise_rel |z|`` from the vehicle file; the
ranges to a level plane computed here from the beam geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from semslam.dataset.vehicle import VehicleDescription
from semslam.geometry import rotation_from_rpy
from semslam.slam import SlamConfig
from semslam.slam.ekf import SemanticEkf
from semslam.slam.sensors import AttitudeInput, DepthModel, DvlModel, SensorGate


def _dense(x, P, idx, H, nu, Rn):
    Hf = np.zeros((len(nu), len(x)))
    Hf[:, idx] = H
    S = Hf @ P @ Hf.T + Rn
    K = P @ Hf.T @ np.linalg.inv(S)
    return x + K @ nu, P - K @ S @ K.T


@pytest.mark.parametrize("flat", [True, None])
def test_dvl_update_uses_the_nominal_speed_dependent_noise(flat):
    """Catches a wrong DVL noise (``noise_abs - noise_rel |v|`` for ``+``) and a nominal hypothesis that is not
    the specified noise (factor 2 for 1): a consistent DVL sample over a flat (or unknown) bottom updates the
    velocity exactly as the dense Kalman update with ``R = (noise_abs + noise_rel |z|)^2 I``."""
    vehicle = VehicleDescription.girona500()
    spec = vehicle.dvl
    ekf = SemanticEkf(np.zeros(3), np.array([0.5, 0.05, 0.0]), np.diag([1e-2] * 3 + [1e-4] * 3))
    z = np.array([0.5003, 0.0498, 0.0002])
    x0, P0 = ekf.full_state()
    out = DvlModel(vehicle).update(ekf, SensorGate(SlamConfig()), z, flat)
    assert out["accepted"] and out["reason"] == "nominal"
    sigma = spec.noise_abs_mps + spec.noise_rel * np.linalg.norm(z)
    x1, P1 = _dense(x0, P0, np.arange(3, 6), np.eye(3), z - x0[3:6], np.eye(3) * sigma**2)
    x, P = ekf.full_state()
    np.testing.assert_allclose(x, x1, atol=1e-12)
    np.testing.assert_allclose(P, P1, atol=1e-14)


def test_dvl_calibration_jacobian_matches_finite_differences():
    """Catches an error in the Jacobian of the calibrated DVL model (e.g. a sign in ``dRz/ddelta``, the
    misalignment column): with scale factor k and misalignment delta non-zero, the update equals the dense
    Kalman update whose ``H`` is the central-difference derivative of ``h = (1 + k) Rz(delta) v + b + s``."""
    vehicle = VehicleDescription.girona500()
    spec = vehicle.dvl
    ekf = SemanticEkf(np.zeros(3), np.array([0.6, 0.2, 0.05]), np.diag([1e-2] * 3 + [1e-4] * 3 + [1e-6] * 6
                                                                      + [1e-5, 1e-4]), dvl_calibration=True)
    cal = ekf.indices("dvl_calibration")
    ekf.xa[cal] = [0.001, -0.002, 0.0005, 0.0, 0.0, 0.0, 0.01, math.radians(2.0)]
    idx = np.concatenate([ekf.indices("velocity"), cal])
    x0, P0 = ekf.full_state()

    def h(xs):
        v, b, s, k, dl = xs[0:3], xs[3:6], xs[6:9], xs[9], xs[10]
        Rz = np.array([[math.cos(dl), -math.sin(dl), 0.0], [math.sin(dl), math.cos(dl), 0.0], [0.0, 0.0, 1.0]])
        return (1.0 + k) * Rz @ v + b + s

    xs0 = x0[idx]
    H = np.column_stack([(h(xs0 + e) - h(xs0 - e)) / 2e-7 for e in np.eye(len(idx)) * 1e-7])
    z = h(xs0) + np.array([0.0004, -0.0003, 0.0002])
    out = DvlModel(vehicle).update(ekf, SensorGate(SlamConfig()), z, True)
    assert out["accepted"]
    sigma = spec.noise_abs_mps + spec.noise_rel * np.linalg.norm(z)
    x1, P1 = _dense(x0, P0, idx, H, z - h(xs0), np.eye(3) * sigma**2)
    x, P = ekf.full_state()
    np.testing.assert_allclose(x, x1, atol=1e-9)
    np.testing.assert_allclose(P, P1, atol=1e-11)


def test_attitude_input_stamps_when_empty():
    """Catches a wrong "no sample yet" stamp: an empty AHRS input's last stamp is -inf (every sample is newer)
    and its first +inf."""
    att = AttitudeInput([0.01, 0.01, 0.02])
    assert len(att) == 0 and att.last_stamp_s == -math.inf and att.first_stamp_s == math.inf


def test_depth_record_says_accepted_for_an_update_in_the_gate_and_a_forced_one():
    """Catches ``ok and forced`` for ``ok or forced`` in the depth update's record: a depth inside the gate is
    applied and logged ``accepted=True``; a gross one is rejected (``False``) until ``max_rejections`` in a row,
    after which the next is forced in and logged ``accepted=True`` with ``reason="gate_reset"``."""
    v = VehicleDescription.girona500()
    cfg = SlamConfig()
    gate, depth = SensorGate(cfg), DepthModel(v)
    ekf = SemanticEkf(np.array([0.0, 0.0, 5.0]), np.zeros(3), np.eye(6) * 1e-4)
    rec = depth.update(ekf, gate, 5.0 + 0.1 * v.depth.noise_m)
    assert rec["accepted"] is True and "reason" not in rec
    recs = [depth.update(ekf, gate, 50.0) for _ in range(gate.max_rejections + 1)]
    assert [r["accepted"] for r in recs] == [False] * gate.max_rejections + [True]
    assert recs[-1]["reason"] == "gate_reset"
    assert ekf.position_ned_m[2] > 5.1  # the forced update moved the depth


@pytest.mark.parametrize("rpy", [(0.0, 0.0, 0.0), (0.1, -0.25, 1.0)])
def test_bottom_is_flat_from_the_slant_ranges_to_a_level_plane(rpy):
    """Catches a wrong vertical drop of the beams' bottom points (``beams / r`` for ``beams * r``): with the ranges
    to a level seabed 3 m below the vehicle, seen with a pitched and rolled vehicle (ranges then differ), the
    bottom is flat; with one beam's range 20 % longer (a hole), it is not."""
    v = VehicleDescription.girona500()
    dvl = DvlModel(v)
    R = rotation_from_rpy(*rpy)
    down = dvl.beams_vehicle @ R[2]   # the vertical component (NED z) of each beam's unit direction
    assert np.all(down > 0.3)
    r = 3.0 / down
    if rpy != (0.0, 0.0, 0.0):
        assert np.ptp(r) > 0.1   # the ranges differ: only their vertical drops agree
    assert dvl.bottom_flat(r, R) is True
    r_hole = r.copy()
    r_hole[0] *= 1.2
    assert dvl.bottom_flat(r_hole, R) is False


def test_attitude_input_first_stamp_is_the_oldest_sample():
    """Catches ``_t[1]`` for ``_t[0]`` in ``AttitudeInput.first_stamp_s``: with samples at 2.0, 2.1 and 2.2 s the
    first stamp is 2.0 s (the last 2.2 s); after dropping what a filter at 2.15 s no longer needs (nothing, below
    the trimming batch), still 2.0 s."""
    from semslam.slam.sensors import AttitudeInput

    att = AttitudeInput([0.01, 0.01, 0.02])
    for t in (2.0, 2.1, 2.2):
        att.add(t, np.array([0.0, 0.0, t]))
    assert att.first_stamp_s == 2.0 and att.last_stamp_s == 2.2
    att.forget_before(2.15)
    assert att.first_stamp_s == 2.0
