"""The compressed filter's active / passive split (``semslam/slam/compressed.py``).

Each test states the bug it catches; expected values come from the class's documented contract or a dense
recomputation, never from the code under test."""

from __future__ import annotations

import numpy as np

from semslam.slam.ekf import SemanticEkf


def _filter_with_landmarks(n_landmarks=3, seed=0):
    rng = np.random.default_rng(seed)
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6) * 0.1)
    for _ in range(n_landmarks):
        G = np.zeros((6, 6))
        G[0:3, 0:3] = np.eye(3)
        ekf.add_landmark(np.r_[rng.uniform(-5, 5, 3), 0.0, 0.0, 0.1], G, np.eye(6) * 0.01, label="valve",
                         stamp_s=0.0)
    return ekf


def test_active_index_is_minus_one_for_passive_states():
    """Catches a wrong "passive" sentinel in the active-set map (e.g. -2 instead of the documented -1):
    ``active_index`` of a passive state must be exactly -1, and an active one its position in ``xa``."""
    ekf = _filter_with_landmarks()
    ekf.set_active_landmarks([1])
    off0, off1 = ekf.landmarks[0].offset, ekf.landmarks[1].offset
    assert [ekf.active_index(off0 + k) for k in range(6)] == [-1] * 6
    assert [ekf.active_index(off1 + k) for k in range(6)] == list(range(6, 12))
    assert [ekf.active_index(k) for k in range(6)] == list(range(6))
    assert not ekf.is_active(0) and ekf.is_active(1)
    np.testing.assert_array_equal(ekf.active_indices, np.r_[np.arange(6), off1 + np.arange(6)])


def test_is_active_index_of_the_first_state():
    """Catches ``is_active_index`` testing ``loc > 0`` (or ``>= 1``): global index 0 (north position, always
    active at position 0 of the active block) must read as active; a passive landmark state as passive."""
    ekf = _filter_with_landmarks()
    ekf.set_active_landmarks([2])
    assert ekf.is_active_index(0)
    assert all(ekf.is_active_index(k) for k in range(6))
    assert not ekf.is_active_index(ekf.landmarks[0].offset)
    assert ekf.is_active_index(ekf.landmarks[2].offset)


def test_mixed_active_passive_views_equal_the_flushed_dense_state():
    """Catches a wrong split of a mixed request into active and passive indices in ``cov``/``mean`` (``loc > 0``
    or ``loc <= 0`` puts the vehicle's first state, at active position 0, on the passive side and reads its
    stale ``P``): the block of (vehicle, passive landmark) must equal the same block of the flushed ``P``, after
    predictions (which make the passive-state formula wrong for an active state)."""
    ekf = _filter_with_landmarks(seed=4)
    ekf.set_active_landmarks([1])
    rng = np.random.default_rng(5)
    off1 = ekf.landmarks[1].offset
    for _ in range(5):   # predictions and updates on the vehicle and the active landmark: the passive ones move
        ekf.predict(0.5, np.eye(3), velocity_rw=0.1)   # by correlation (a prediction keeps the pure-update
        idx = np.r_[np.arange(3), off1 + np.arange(3)]   # identity P_AA = P_AA0 - P_AA0 psi P_AA0 from holding)
        ekf.update(idx, np.hstack([np.eye(3), -np.eye(3)]), rng.normal(size=3) * 0.05, np.eye(3) * 0.02)
    assert ekf.compressed
    off0 = ekf.landmarks[0].offset
    req = np.r_[0, 1, 2, off0, off0 + 1, off0 + 2, off1]
    C = ekf.cov(req)
    m = ekf.mean(req)
    x, P = ekf.full_state()       # flushes: the exact dense state
    np.testing.assert_allclose(C, P[np.ix_(req, req)], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(m, x[req], rtol=1e-12, atol=1e-14)
