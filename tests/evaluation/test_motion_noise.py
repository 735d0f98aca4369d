"""The unaided-motion measurement (``semslam/evaluation/motion_noise.py``): closed form on two samples, options,
defaults, the pairing of increments, short logs."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.dataset import DvlLog
from semslam.errors import SlamError
from semslam.evaluation.motion_noise import measure_unaided_motion


def test_two_valid_samples_are_enough_and_give_the_closed_form():
    """Catches ``<= 2`` for ``< 2`` in the "enough samples" check: two valid samples 1 s apart give one increment
    at lag 1 s, and the random walk is ``|v1 - v0| / sqrt(1 s)`` per axis (the quantile of a single value is that
    value), the rms the root mean square of the two velocities."""
    log = DvlLog(np.array([0.0, 1.0]), np.array([[0.5, 0.1, 0.0], [0.8, -0.3, 0.02]]), np.ones(2, bool))
    out = measure_unaided_motion(log, lags_s=(1.0,))
    assert out.n_increments == 1
    np.testing.assert_allclose(out.velocity_rw_mps_per_sqrt_s, [0.3, 0.4, 0.02], atol=5e-5)
    np.testing.assert_allclose(out.velocity_rms_mps, np.sqrt([(0.25 + 0.64) / 2, (0.01 + 0.09) / 2, 0.0002]),
                               atol=5e-5)


def test_quantile_one_is_rejected_and_options_are_keyword_only():
    """Catches an interval check that lets ``quantile = 1`` through (the quantile must be in the open interval
    (0, 1): the maximum is not a quantile to cover) and a signature that lets the options be positional."""
    log = DvlLog(np.arange(5.0), np.zeros((5, 3)), np.ones(5, bool))
    with pytest.raises(SlamError, match=r"'quantile'.*\(0, 1\).*1\.0"):
        measure_unaided_motion(log, quantile=1.0)
    with pytest.raises(TypeError):
        measure_unaided_motion(log, 0.01)
    assert measure_unaided_motion(dvl_logs=log, quantile=0.999).n_increments > 0


def test_default_lags_and_quantile():
    """Catches changed default lags (documented 1 to 10 s: 1, 2, 3, 5, 10 s) or quantile (0.9): a velocity ramp of
    0.01 m/s per s sampled at 1 Hz has increments ``0.01 tau`` at every lag, so the walk is
    ``max_tau 0.01 sqrt(tau)`` = 0.01 sqrt(10) on the surge axis, from every one of the five lags."""
    t = np.arange(0.0, 60.0)
    v = np.zeros((60, 3))
    v[:, 0] = 0.01 * t
    out = measure_unaided_motion(DvlLog(t, v, np.ones(60, bool)))
    assert out.lags_s == (1.0, 2.0, 3.0, 5.0, 10.0)
    assert out.n_increments == sum(60 - tau for tau in (1, 2, 3, 5, 10))
    assert out.velocity_rw_mps_per_sqrt_s[0] == pytest.approx(round(0.01 * np.sqrt(10.0), 4))


def _step_log_with_a_hole():
    """Velocity 0 for 10 s, no DVL for 2.375 s, then 1 m/s surge: stamps exact in binary (0.25 s period)."""
    t = np.r_[np.arange(40) * 0.25, 12.125 + np.arange(40) * 0.25]
    v = np.zeros((80, 3))
    v[40:, 0] = 1.0
    return DvlLog(t, v, np.ones(80, bool))


def test_increments_are_paired_within_half_a_period_of_the_lag():
    """Catches the lag tolerance ``0.5 / period`` for ``0.5 * period`` (2 s instead of 0.125 s here): pairs across a
    2.4 s gap in the log would count as 1 s increments and turn a velocity step into a random walk. At a 1 s lag
    each 10 s stretch of 40 samples has 36 pairs and none spans the gap."""
    m = measure_unaided_motion(_step_log_with_a_hole(), lags_s=(1.0,), quantile=0.999)
    assert m.n_increments == 72
    assert m.velocity_rw_mps_per_sqrt_s == (0.0, 0.0, 0.0)


def test_a_log_too_short_to_measure_does_not_end_the_measurement():
    """Catches ``break`` for ``continue`` after a log with fewer than 2 valid samples: the logs after it were
    ignored (here: all of them, so the call failed)."""
    short = DvlLog(np.array([0.0]), np.zeros((1, 3)), np.ones(1, bool))
    log = _step_log_with_a_hole()
    both = measure_unaided_motion([short, log], lags_s=(1.0,), quantile=0.999)
    alone = measure_unaided_motion(log, lags_s=(1.0,), quantile=0.999)
    assert both.n_increments == alone.n_increments == 72
    assert both.velocity_rw_mps_per_sqrt_s == alone.velocity_rw_mps_per_sqrt_s
