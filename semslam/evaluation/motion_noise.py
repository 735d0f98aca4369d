"""How much the vehicle's body velocity changes when nothing measures it: the unaided process noise of the
filter's constant-velocity model, *measured* from DVL logs rather than assumed.

During a DVL outage the filter's velocity is a random walk: ``var(v(t + tau) - v(t)) = q tau`` per body axis. A
real vehicle's velocity changes in manoeuvres (launch and stop ramps, turns, speed changes) that the DVL catches
when it is there; unaided, the random walk must cover them. :func:`measure_unaided_motion` takes the increments
``v(t + tau) - v(t)`` of valid DVL samples at lags ``tau`` (default 1 to 10 s, the time scale on which an
unmodelled manoeuvre builds a position error), subtracts the DVL's own white noise and returns, per axis,

    ``sqrt(max_tau  quantile_p(dv^2) / tau)``   (m/s/sqrt(s), default ``p = 0.9``)

The upper quantile, not the mean: an outage is not a random draw over the dive (DVL lock is lost in descents
and manoeuvres near structures), and a cruise-dominated mean under-covers the manoeuvres (measured on the
simulator's missions: the mean gives (0.041, 0.022, 0.023) and a first-half outage NEES of 5.6, the 90th
percentile gives ANEES in band, see ``benchmarks/dvl_outage.py``). Also returned: the per-axis rms of the body
velocity, the spread to assume for a velocity not known at the start of a run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..dataset import DvlLog
from ..errors import SlamError


@dataclass(frozen=True)
class UnaidedMotion:
    """What :func:`measure_unaided_motion` measured (per body axis: surge, sway, heave)."""

    velocity_rw_mps_per_sqrt_s: tuple
    velocity_rms_mps: tuple
    n_increments: int
    lags_s: tuple

    def config_overrides(self) -> dict:
        """Settings for :meth:`semslam.slam.SlamConfig.updated`."""
        return {"unaided_velocity_rw_mps_per_sqrt_s": self.velocity_rw_mps_per_sqrt_s,
                "unknown_velocity_sigma_mps": self.velocity_rms_mps}


def measure_unaided_motion(dvl_logs: DvlLog | list[DvlLog], *, noise_sigma_mps: float = 0.0,
                           lags_s=(1.0, 2.0, 3.0, 5.0, 10.0), quantile: float = 0.9) -> UnaidedMotion:
    """Measure the unaided velocity random walk and the velocity spread from one or several DVL logs.

    Parameters
    ----------
    dvl_logs : DvlLog or list of DvlLog
        Body-frame DVL velocities (one dive or many). Invalid rows are left out; an increment is used only when
        both of its samples are valid and their stamps are ``tau`` apart within half a sample period.
    noise_sigma_mps : float
        The DVL's white noise (per axis): its share ``chi2_1(p) 2 sigma^2`` of the quantile is removed.
    lags_s : sequence of float
        The lags ``tau`` (s).
    quantile : float in (0, 1)
        Which quantile of the squared increments to cover (see the module docstring).
    """
    logs = [dvl_logs] if isinstance(dvl_logs, DvlLog) else list(dvl_logs)
    if not logs or not all(isinstance(d, DvlLog) for d in logs):
        raise SlamError(f"The 'dvl_logs' argument of measure_unaided_motion must be a DvlLog or a non-empty list "
                        f"of DvlLog. Got {type(dvl_logs).__name__} instead.")
    if not 0.0 < float(quantile) < 1.0:
        raise SlamError(
            f"The 'quantile' argument of measure_unaided_motion must be in (0, 1). Got {quantile!r} instead."
        )
    lags = tuple(float(x) for x in lags_s)
    if not lags or min(lags) <= 0:
        raise SlamError(f"The 'lags_s' argument of measure_unaided_motion must be positive lags (s). Got {lags_s!r} "
                        "instead.")
    incs: dict[float, list] = {tau: [] for tau in lags}
    vel = []
    for d in logs:
        t, v = d.stamp_s[d.valid], d.velocity_body_mps[d.valid]
        vel.append(v)
        if len(t) < 2:
            continue
        period = float(np.median(np.diff(t)))
        for tau in lags:
            j = np.searchsorted(t, t + tau)
            ok = j < len(t)
            i, j = np.flatnonzero(ok), j[ok]
            close = np.abs(t[j] - t[i] - tau) <= 0.5 * period
            incs[tau].append(v[j[close]] - v[i[close]])
    n = sum(len(a) for tau in lags for a in incs[tau])
    v_all = np.concatenate(vel) if vel else np.zeros((0, 3))
    if n == 0 or len(v_all) < 2:
        raise SlamError(f"measure_unaided_motion needs valid DVL samples at least {min(lags)} s apart; the "
                        f"{len(logs)} log(s) given have {len(v_all)} valid samples.")
    from scipy.stats import chi2  # lazily: scipy.stats costs ~1 s to import

    scale = float(chi2.ppf(quantile, 1))  # the white noise's share of the quantile (exact for Gaussian noise)
    q = np.zeros(3)
    for tau in lags:
        if incs[tau]:
            a = np.concatenate(incs[tau])
            if len(a):
                var = np.quantile(a * a, quantile, axis=0) - scale * 2.0 * float(noise_sigma_mps) ** 2
                q = np.maximum(q, np.maximum(var, 0.0) / tau)
    rms = np.sqrt(np.mean(v_all * v_all, axis=0))
    return UnaidedMotion(tuple(round(float(x), 4) for x in np.sqrt(q)), tuple(round(float(x), 4) for x in rms),
                         int(n), lags)
