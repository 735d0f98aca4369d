"""DVL outages (issue 18, item 3): the unaided motion is measured, the filter switches to it when the DVL is out,
the start velocity is never taken from the future, and a long outage leaves the filter honest."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from semslam.dataset import DvlLog, VehicleDescription
from semslam.errors import ConfigError, SlamError
from semslam.experiments.outage import OUTAGE_SCENARIOS, outage_table, run_outage_montecarlo, with_dvl_outage
from semslam.simulation.synthetic import square_dataset
from semslam.simulation.truth_slam import run_truth_slam
from semslam.slam import SlamConfig, SlamSession
from semslam.evaluation.motion_noise import measure_unaided_motion


def _random_walk_log(q_sigma, seconds=4000.0, rate_hz=5.0, seed=0, noise=0.0):
    rng = np.random.default_rng(seed)
    n = int(seconds * rate_hz)
    t = np.arange(n) / rate_hz
    v = np.cumsum(rng.normal(0.0, 1.0, (n, 3)) * np.asarray(q_sigma) * math.sqrt(1.0 / rate_hz), axis=0)
    v += rng.normal(0.0, noise, (n, 3))
    return DvlLog(t, v, np.ones(n, bool))


@pytest.mark.parametrize("quantile", [0.5, 0.9])
def test_measure_recovers_a_gaussian_random_walk(quantile):
    """Oracle: for a Gaussian random walk of density q, dv^2 / tau is q times a chi-square(1), whose quantile p is
    scipy's. Catches a wrong lag (samples vs seconds), a missing square root or a quantile over the wrong axis."""
    q = np.array([0.05, 0.02, 0.01])
    m = measure_unaided_motion(_random_walk_log(q, seed=1), lags_s=(2.0,), quantile=quantile)
    expected = q * math.sqrt(chi2.ppf(quantile, 1))
    np.testing.assert_allclose(m.velocity_rw_mps_per_sqrt_s, expected, rtol=0.05)


def test_measure_removes_the_dvl_white_noise_and_skips_invalid_rows():
    """The DVL's own noise (2 sigma^2 per increment) is not motion; invalid rows (NaN) are left out."""
    q = np.array([0.03, 0.03, 0.03])
    log = _random_walk_log(q, seed=2, noise=0.02)
    valid = log.valid.copy()
    valid[::7] = False
    v = log.velocity_body_mps.copy()
    v[~valid] = np.nan
    log = DvlLog(log.stamp_s, v, valid)
    raw = measure_unaided_motion(log, lags_s=(1.0,), quantile=0.5)
    clean = measure_unaided_motion(log, noise_sigma_mps=0.02, lags_s=(1.0,), quantile=0.5)
    expected = q * math.sqrt(chi2.ppf(0.5, 1))
    assert np.all(np.asarray(raw.velocity_rw_mps_per_sqrt_s) > 1.2 * expected)  # noise inflates it
    np.testing.assert_allclose(clean.velocity_rw_mps_per_sqrt_s, expected, rtol=0.12)
    assert np.isfinite(clean.velocity_rms_mps).all()


def test_measure_bad_inputs():
    with pytest.raises(SlamError, match="'dvl_logs' argument of measure_unaided_motion must be a DvlLog"):
        measure_unaided_motion([])
    with pytest.raises(SlamError, match="'quantile'.*in \\(0, 1\\). Got 1.5"):
        measure_unaided_motion(_random_walk_log([0.01] * 3, seconds=10), quantile=1.5)
    short = DvlLog(np.array([0.0, 0.2]), np.zeros((2, 3)), np.ones(2, bool))
    with pytest.raises(SlamError, match="needs valid DVL samples at least 1.0 s apart.*2 valid samples"):
        measure_unaided_motion(short)


def test_config_rejects_a_bad_unaided_noise():
    with pytest.raises(ConfigError, match="'unaided_velocity_rw_mps_per_sqrt_s' field of MotionConfig.*Got"):
        SlamConfig().updated(unaided_velocity_rw_mps_per_sqrt_s=(0.1, -1.0, 0.1))
    with pytest.raises(ConfigError, match="'unaided_after_s' field of MotionConfig must be > 0"):
        SlamConfig().updated(unaided_after_s=0.0)


def _session(**kw):
    cfg = SlamConfig().updated(propagate_attitude_noise=False, dvl_calibration=False, smooth=False,
                               velocity_rw_mps_per_sqrt_s=0.01, unaided_velocity_rw_mps_per_sqrt_s=(0.1, 0.05, 0.02))
    s = SlamSession(VehicleDescription.girona500(), mode="dr", config=cfg, start_stamp_s=0.0, **kw)
    return s, cfg


def _velocity_cov_after_outage(seconds):
    s, cfg = _session()
    for k in range(0, 101):
        s.add_attitude(k * 0.1, (0.0, 0.0, 0.0))
    s.add_dvl(0.0, (0.3, 0.0, 0.0))
    s.add_dvl(seconds, (np.nan, np.nan, np.nan), valid=False)  # a dropout: the filter predicts up to it, no update
    s._drain(False)
    return s.ekf.velocity_cov, cfg


def test_unaided_noise_is_used_only_while_the_dvl_is_out():
    """Analytic: with the attitude fixed and no DVL after t = 0, the body-velocity variance grows by
    q_aided * unaided_after_s + q_unaided * (t - unaided_after_s). Catches a filter that ignores the outage
    (aided noise all the way) or switches at the wrong time."""
    P0, cfg = _velocity_cov_after_outage(0.0)
    P10, _ = _velocity_cov_after_outage(10.0)
    q_a, q_u = 0.01 ** 2, np.array([0.1, 0.05, 0.02]) ** 2
    after = cfg.motion.unaided_after_s
    np.testing.assert_allclose(np.diag(P10 - P0), q_a * after + q_u * (10.0 - after), rtol=0.02)
    P_short, _ = _velocity_cov_after_outage(0.5 * after)  # a gap shorter than unaided_after_s: aided noise only
    np.testing.assert_allclose(np.diag(P_short - P0), q_a * 0.5 * after, rtol=0.02)


def test_an_unknown_start_velocity_gets_the_measured_spread():
    """SlamSession(initial_velocity_body_mps=None): zero mean, the configured velocity spread as covariance."""
    s, cfg = _session(initial_velocity_body_mps=None)
    s.add_attitude(0.0, (0.0, 0.0, 0.0))
    s.add_attitude(0.01, (0.0, 0.0, 0.0))
    s._drain(False)
    s._start(0.0) if s.ekf is None else None
    np.testing.assert_allclose(s.ekf.velocity_body_mps, 0.0)
    np.testing.assert_allclose(np.sqrt(np.diag(s.ekf.velocity_cov)), cfg.motion.unknown_velocity_sigma_mps, rtol=0.05)


def test_the_start_velocity_is_not_taken_from_the_future():
    """A mission whose DVL starts valid only at mid-dive: before the fix, the filter started with that mid-dive
    velocity (known to 5 cm/s) - information from the future, and a NEES of 28 after a first-half outage."""
    m = with_dvl_outage(square_dataset(seed=3, loops=2), 0.0, 0.5)
    r = run_truth_slam(m, mode="dr", seed=3)
    np.testing.assert_allclose(r.velocity_body_mps[0], 0.0, atol=1e-9)
    assert np.sqrt(r.velocity_cov[0, 0, 0]) == pytest.approx(SlamConfig().motion.unknown_velocity_sigma_mps[0], rel=0.05)


def test_with_dvl_outage_marks_only_the_span():
    m = square_dataset(seed=1, loops=1)
    o = with_dvl_outage(m, 0.25, 0.5)
    t = m.dvl.stamp_s
    span = (t >= t[0] + 0.25 * (t[-1] - t[0])) & (t <= t[0] + 0.5 * (t[-1] - t[0]))
    assert not o.dvl.valid[span].any()
    np.testing.assert_array_equal(o.dvl.valid[~span], m.dvl.valid[~span])
    assert set(OUTAGE_SCENARIOS) >= {"first_half", "middle", "last_third", "whole"}
    with pytest.raises(SlamError, match="0 <= start_fraction <= end_fraction <= 1. Got 0.6 and 0.2"):
        with_dvl_outage(m, 0.6, 0.2)


@pytest.mark.slow
@pytest.mark.parametrize("scenario, mode", [("first_half", "pose"), ("whole", "pose+heading")])
def test_a_long_outage_leaves_the_filter_honest(scenario, mode):
    """Regression of the hostile report: a DVL outage over the first half of the dive made 'pose' overconfident
    (NEES 24-30, final error 0.489 m against a stated 3-sigma of 0.294 m); with no DVL at all 'pose+heading' had
    a NEES of 130. Now the ANEES of 3 runs stays under the upper 99.9 % bound of 3 chi-square(3) means, and no
    run is worse than dead reckoning beyond its own 1-sigma."""
    rows = run_outage_montecarlo(3, scenarios=(scenario,), modes=(mode,), seed=1, loops=2)
    (row,) = rows
    assert row.anees_mean < chi2.ppf(0.999, 9) / 3, outage_table(rows)
    assert row.worse_than_dr_beyond_sigma == 0
    assert row.ate_mean_m < row.dr_ate_mean_m


def test_pose_heading_flies_missions_with_a_yaw_bias_drawn_from_its_prior():
    """A consistency test needs the truth drawn from the filter's model: pose+heading models an AHRS yaw bias
    N(0, yaw_bias_sigma_rad^2), so its missions carry one (and its dead-reckoning reference flies the same biased
    missions); the other modes fly the unbiased ones. Catches pose+heading judged on unbiased missions (pessimistic
    by construction: ANEES 2.0-2.1 after a mid- or late-dive outage) or a DR reference from the other missions."""
    kw = dict(scenarios=("middle",), modes=("pose", "pose+heading"), seed=3, loops=1)
    with_bias = {r.mode: r for r in run_outage_montecarlo(1, **kw)}
    without = {r.mode: r for r in run_outage_montecarlo(1, heading_bias_from_prior=False, **kw)}
    assert with_bias["pose+heading"].yaw_bias_from_prior and not with_bias["pose"].yaw_bias_from_prior
    assert not without["pose+heading"].yaw_bias_from_prior
    assert without["pose+heading"].dr_ate_mean_m == without["pose"].dr_ate_mean_m  # one mission for all
    assert with_bias["pose+heading"].dr_ate_mean_m != with_bias["pose"].dr_ate_mean_m  # DR on the biased mission
    assert with_bias["pose"].ate_mean_m == without["pose"].ate_mean_m  # the unbiased modes are untouched
    assert with_bias["pose+heading"].ate_mean_m != without["pose+heading"].ate_mean_m
    assert "from the prior" in outage_table(list(with_bias.values()))
