"""The health verdict of a live run (the ``semslam`` node's diagnostics): the published mode's session as it is now,
its update log tallied incrementally (:func:`live_health`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["LiveResult", "LogTally", "live_health"]


@dataclass
class LiveResult:
    """The part of a :class:`~semslam.slam.SlamResult` :func:`semslam.run.health.health_verdict` reads, from a
    session still running."""

    mode: str
    metrics: dict
    landmarks: list
    position_cov_m2: np.ndarray


@dataclass
class LogTally:
    """The running tally of a session's update log (:func:`live_health`)."""

    n: int = 0
    counts: dict = field(default_factory=dict)
    nis: dict = field(default_factory=dict)  # kind -> [sum, n, dof]


def live_health(live):
    """The health verdict (:func:`semslam.run.health.health_verdict`) of the published mode's session as it is now:
    its update log tallied incrementally (gates, NIS, landmark updates), its landmarks and covariance, the runner's
    counts and the reorder window's drops. Call with ``live.lock`` held; None before the start."""
    from ...slam.consistency import chi2_band
    from ..health import health_verdict

    s = live.session
    if s is None or s.ekf is None:
        return None
    tally = live.health_tally
    c = tally.counts
    for r in s.log[tally.n:]:
        kind, ok = r.get("kind", ""), bool(r.get("accepted"))
        key = kind if not kind.endswith("_beyond_attitude") else "beyond_attitude"
        c[key] = c.get(key, 0) + 1
        if not ok:
            c[key + "_rejected"] = c.get(key + "_rejected", 0) + 1
        if kind == "landmark" and ok:
            c["landmark_" + str(r.get("test"))] = c.get("landmark_" + str(r.get("test")), 0) + 1
        if ok and "nis" in r and np.isfinite(r["nis"]):
            k = kind if kind != "landmark" else f"landmark_{r['test']}_{r['dof']}dof"
            acc = tally.nis.setdefault(k, [0.0, 0, int(r["dof"])])
            acc[0] += float(r["nis"])
            acc[1] += 1
    tally.n = len(s.log)
    metrics = {"dvl_updates": c.get("dvl", 0), "dvl_rejected": c.get("dvl_rejected", 0),
               "depth_updates": c.get("depth", 0), "depth_rejected": c.get("depth_rejected", 0),
               "fix_updates": c.get("fix", 0), "fix_rejected": c.get("fix_rejected", 0),
               "fix_unusable": c.get("fix_unusable", 0), "skipped_beyond_attitude": c.get("beyond_attitude", 0),
               "landmark_updates": {"pose": c.get("landmark_pose", 0), "position": c.get("landmark_position", 0)},
               "nis": {k: {"n": n, "dof": dof, "mean": tot / n, "band": list(chi2_band(dof, n))}
                       for k, (tot, n, dof) in tally.nis.items() if n}}
    est = s.estimate()
    counts = dict(live.runner.counts, late_dropped=live.dropped_late)
    return health_verdict(LiveResult(live.mode, metrics, est.landmarks, est.position_cov_m2[None]), counts=counts)
