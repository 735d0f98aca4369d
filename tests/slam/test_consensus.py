"""New landmarks by consensus of observations (``semslam/slam/consensus.py``).

Each test states the bug it catches; the expected behaviour is the documented one (module and class
docstrings), checked at its exact boundaries."""

from __future__ import annotations

import math

import numpy as np

from semslam.geometry import rotation_from_rpy
from semslam.slam.consensus import ConsensusInitializer, Observation
from semslam.symmetry import Symmetry


def _obs(t, pos, yaw_deg=0.0, label="valve"):
    return Observation(label, float(t), np.asarray(pos, dtype=float), rotation_from_rpy(0.0, 0.0, math.radians(yaw_deg)))


def test_observation_defaults_and_identity():
    """Catches a wrong default for a fully observable object (``axes_world`` must be an empty (0, 3) array: no
    free axis; a (1, 3) zero axis or a (0, 4) array is not that) and an ``Observation`` compared by value
    (``eq=True`` makes it unhashable and its ``==`` compares arrays): observations are distinct objects."""
    a = _obs(0.0, [0, 0, 0])
    b = _obs(0.0, [0, 0, 0])
    assert a.axes_world.shape == (0, 3)
    assert a.symmetry.kind == Symmetry().kind and a.symmetry.order == 1
    assert a.payload is None
    assert a != b and a == a
    assert len({a, b}) == 2


def test_default_position_threshold_is_half_a_metre():
    """Catches a wrong default position threshold (documented 0.5 m): with the defaults, four equal-attitude
    observations 0.4 m apart agree; four 0.6 m apart do not."""
    ci = ConsensusInitializer()
    assert ci.position_threshold_m == 0.5 and ci.min_observations == 4 and ci.max_age_s == 120.0
    assert ci.attitude_threshold == 0.02 and ci.use_attitude
    near = [_obs(i, [0.4 * (i % 2), 0, 0]) for i in range(4)]
    assert ConsensusInitializer().agreement(near).all()
    far = [_obs(i, [0.6 * i, 0, 0]) for i in range(4)]
    np.testing.assert_array_equal(ConsensusInitializer().agreement(far), np.eye(4, dtype=bool))


def test_position_agreement_is_strictly_below_the_threshold():
    """Catches ``<=`` for ``<`` in the position test ("agree if their distance is below this"): two
    observations exactly 0.5 m apart (exactly representable) do not agree with a 0.5 m threshold."""
    ci = ConsensusInitializer(position_threshold_m=0.5)
    ok = ci.agreement([_obs(0, [0, 0, 0]), _obs(1, [0.5, 0, 0]), _obs(2, [0.25, 0, 0])])
    np.testing.assert_array_equal(ok, [[True, False, True], [False, True, True], [True, True, True]])


def test_pool_age_uses_the_time_difference_and_keeps_exactly_max_age():
    """Catches an age computed as ``t_new + t_old`` (late in a mission every observation would be forgotten)
    and ``<`` for ``<=`` (an observation exactly ``max_age_s`` old is not *older* than it, so it stays)."""
    ci = ConsensusInitializer(max_age_s=120.0, min_observations=3)
    assert ci.add(_obs(1000.0, [0, 0, 0])) is None
    assert ci.add(_obs(1060.0, [0.01, 0, 0])) is None
    out = ci.add(_obs(1120.0, [0.02, 0, 0]))          # first one exactly 120 s old: still in the pool
    assert out is not None and len(out[0]) == 3
    ci = ConsensusInitializer(max_age_s=120.0, min_observations=3)
    ci.add(_obs(1000.0, [0, 0, 0]))
    ci.add(_obs(1060.0, [0.01, 0, 0]))
    assert ci.add(_obs(1120.5, [0.02, 0, 0])) is None  # 120.5 s old: forgotten
    assert [o.stamp_s for o in ci.pools["valve"]] == [1060.0, 1120.5]


def test_attitude_agreement_is_strictly_below_the_threshold():
    """Catches ``<=`` for ``<`` in the attitude test ("agree if ``1 - <q1,q2>^2`` is below this"): two identity
    attitudes have distance exactly 0, which is not below a threshold of 0, but is below any positive one."""
    pool = [_obs(0, [0, 0, 0]), _obs(1, [0.1, 0, 0])]
    np.testing.assert_array_equal(ConsensusInitializer(attitude_threshold=0.0).agreement(pool), np.eye(2, dtype=bool))
    assert ConsensusInitializer(attitude_threshold=1e-12).agreement(pool).all()
    assert ConsensusInitializer(attitude_threshold=0.0, use_attitude=False).agreement(pool).all()
