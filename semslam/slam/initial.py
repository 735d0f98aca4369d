"""Where a run starts, from the vehicle's own data only (never from ground truth).

* **When**: the first attitude sample (the filter's input; earlier DVL and depth samples are ignored, counted).
* **Depth** (world z): the pressure sensor's sample nearest the start within ``start_window_s``, known to the
  sensor's noise; without one, 0 known to ``unknown_depth_sigma_m``.
* **North, east**: the dive's position fixes (GPS at the surface before the dive, USBL) in the world frame, which
  is then local NED about the dive's geodetic origin: the last usable fix at or before the start (at most
  ``max_fix_age_s`` old; the vehicle is taken to have dived straight down from it, so a fix taken far from the
  dive point must carry that in its covariance), else the first one within ``start_window_s`` after it, known to
  that fix's covariance. A dive whose first fix comes later starts unknown (``unknown_position_sigma_m``) and is
  placed by its fixes as they come. A dive without fixes starts at north = east = 0: a **local frame** at the
  start point (NED axes: north from the AHRS), known to ``initial_position_sigma_m``; evaluation against truth then
  aligns the estimate (yaw and translation) and says so.
* **Velocity**: the first valid DVL sample up to ``motion.unaided_after_s`` after the start (an earlier one if
  none), else unknown.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import SlamError
from .config import SlamConfig


@dataclass(frozen=True)
class InitialState:
    """The start of a run: stamp, position (NED) and its covariance, body velocity (None: unknown), the world
    frame's kind (``"world"``: fixes placed it; ``"local"``: the start point) and how each part was found."""

    start_stamp_s: float
    position_ned_m: np.ndarray
    position_cov_m2: np.ndarray
    velocity_body_mps: np.ndarray | None
    frame: str
    sources: dict = field(default_factory=dict)
    #: stamps of the depth sample and the fix the start was taken from: not fed again as updates (the same
    #: measurement twice would make the filter overconfident)
    used_stamps_s: dict = field(default_factory=dict)

    def uses(self, kind: str, stamp_s: float) -> bool:
        """Whether the message ``kind`` at ``stamp_s`` is the one the start was taken from."""
        return self.used_stamps_s.get(kind) == stamp_s

    def as_dict(self) -> dict:
        return {"start_stamp_s": self.start_stamp_s, "position_ned_m": self.position_ned_m.tolist(),
                "position_sigma_m": np.sqrt(np.diag(self.position_cov_m2)).tolist(),
                "velocity_body_mps": None if self.velocity_body_mps is None else self.velocity_body_mps.tolist(),
                "frame": self.frame, "sources": dict(self.sources)}


def initial_state(start_stamp_s: float, *, depth_stamps_s, depth_m, depth_noise_m: float, fix_stamps_s=(),
                  fix_positions_ne_m=(), fix_covariances_ne_m2=(), dvl_stamps_s=(), dvl_velocities_mps=(),
                  dvl_valid=(), config: SlamConfig | None = None) -> InitialState:
    """The start of a run from the first samples of the dive's logs (see the module docstring). Every array
    holds the samples near the start (or all of them); the fixes are the usable ones only."""
    cfg = SlamConfig() if config is None else config
    init = cfg.initialisation
    t0 = float(start_stamp_s)
    if not np.isfinite(t0):
        raise SlamError(f"The start stamp of a run must be finite. Got {start_stamp_s!r} instead.")
    src: dict = {}
    used: dict = {}
    p0, var = np.zeros(3), np.zeros((3, 3))
    # depth
    tz, z = np.asarray(depth_stamps_s, dtype=float), np.asarray(depth_m, dtype=float)
    near = np.flatnonzero(np.abs(tz - t0) <= init.start_window_s) if len(tz) else np.zeros(0, dtype=int)
    if len(near):
        k = int(near[np.argmin(np.abs(tz[near] - t0))])
        p0[2], var[2, 2] = float(z[k]), depth_noise_m ** 2
        used["depth"] = float(tz[k])
        src["depth"] = f"pressure sensor at {float(tz[k]):.3f} s"
    else:
        var[2, 2] = init.unknown_depth_sigma_m ** 2
        src["depth"] = f"unknown (no depth sample within {init.start_window_s:g} s of the start)"
    # north, east
    tf = np.asarray(fix_stamps_s, dtype=float).reshape(-1)
    pf = np.asarray(fix_positions_ne_m, dtype=float).reshape(-1, 2)
    cf = np.asarray(fix_covariances_ne_m2, dtype=float).reshape(-1, 2, 2)
    before = np.flatnonzero((tf <= t0) & (tf >= t0 - init.max_fix_age_s))
    after = np.flatnonzero((tf > t0) & (tf <= t0 + init.start_window_s))
    if len(before) or len(after):
        k = int(before[-1]) if len(before) else int(after[0])
        p0[0:2], var[0:2, 0:2] = pf[k], cf[k]
        used["fix"] = float(tf[k])
        frame = "world"
        src["horizontal"] = f"position fix at {float(tf[k]):.3f} s ({t0 - float(tf[k]):+.3f} s before the start)"
    elif len(tf):
        var[0, 0] = var[1, 1] = init.unknown_position_sigma_m ** 2
        frame = "world"
        src["horizontal"] = (f"unknown until the first position fix ({float(tf[0]):.3f} s); no fix within "
                             f"{init.max_fix_age_s:g} s before the start")
    else:
        var[0, 0] = var[1, 1] = init.initial_position_sigma_m ** 2
        frame = "local"
        src["horizontal"] = "local frame: north = east = 0 at the start point (no position fix)"
    # velocity
    td = np.asarray(dvl_stamps_s, dtype=float)
    ok = np.flatnonzero(np.asarray(dvl_valid, dtype=bool) & (td <= t0 + cfg.motion.unaided_after_s)) if len(td) \
        else np.zeros(0, dtype=int)
    v0 = np.asarray(dvl_velocities_mps, dtype=float).reshape(-1, 3)[ok[0]].copy() if len(ok) else None
    src["velocity"] = f"DVL at {float(td[ok[0]]):.3f} s" if len(ok) else "unknown (no valid DVL sample at the start)"
    return InitialState(t0, p0, var, v0, frame, src, used)


def initial_state_of(dataset, config: SlamConfig | None = None) -> InitialState:
    """:func:`initial_state` of a whole :class:`~semslam.dataset.Dataset` (its own logs; never its truth)."""
    if not len(dataset.attitude):
        raise SlamError("The dataset has no attitude samples: the filter needs the attitude as input.")
    f = dataset.fixes
    use = f.usable() if f is not None else None
    return initial_state(
        float(dataset.attitude.stamp_s[0]), depth_stamps_s=dataset.depth.stamp_s, depth_m=dataset.depth.depth_m,
        depth_noise_m=dataset.vehicle.depth.noise_m,
        fix_stamps_s=() if f is None else f.stamp_s[use], fix_positions_ne_m=() if f is None else f.position_ne_m[use],
        fix_covariances_ne_m2=() if f is None else f.covariance_ne_m2[use], dvl_stamps_s=dataset.dvl.stamp_s,
        dvl_velocities_mps=dataset.dvl.velocity_body_mps, dvl_valid=dataset.dvl.valid, config=config)
