"""Tests that kill surviving mutants of ``semslam/slam/sensors.py`` (benchmarks/mutation.py): the depth update's
record, and the DVL's flat-bottom test from its beams' slant ranges (oracle: the ranges to a level plane computed
here from the beam geometry)."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.dataset.vehicle import VehicleDescription
from semslam.geometry import rotation_from_rpy
from semslam.slam import SlamConfig
from semslam.slam.ekf import SemanticEkf
from semslam.slam.sensors import DepthModel, DvlModel, SensorGate


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
