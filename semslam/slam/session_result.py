"""The end of a :class:`~semslam.slam.session.SlamSession`: its landmarks, the run's metrics tallied from the update
log, and the :class:`~semslam.slam.results.SlamResult` assembled from the recorded history and the smoother."""

from __future__ import annotations

import numpy as np

from ..errors import SlamError
from .consistency import nis_summary
from .results import LandmarkEstimate, SlamResult

__all__ = ["joint_landmark_cov", "landmark_estimates", "log_metrics", "slam_result"]


def landmark_estimates(ekf) -> list[LandmarkEstimate]:
    """The filter's landmarks as :class:`LandmarkEstimate` (pose, covariance, sightings)."""
    return [LandmarkEstimate(j, lm.label, ekf.landmark_pose(j), ekf.landmark_cov(j), lm.first_seen_s,
                             lm.last_seen_s, lm.n_updates, name=lm.name) for j, lm in enumerate(ekf.landmarks)]


def joint_landmark_cov(ekf) -> np.ndarray | None:
    """The landmarks' joint covariance (6L, 6L), symmetrised (None without landmarks)."""
    if not ekf.landmarks:
        return None
    idx = np.concatenate([lm.offset + np.arange(6) for lm in ekf.landmarks])
    C = ekf.cov(idx)
    return 0.5 * (C + C.T)


def log_metrics(mode: str, stamps: np.ndarray, landmarks: list, log: list[dict], before_start: int,
                implausible: dict) -> dict:
    """The run's metrics: NIS per kind of update, landmark updates, gate rejections and the messages skipped, from
    the update ``log`` (``before_start``, ``implausible``: the session's counts of the samples it ignored)."""
    metrics: dict = {"mode": mode, "n_landmarks": len(landmarks),
                     "duration_s": float(stamps[-1] - stamps[0]) if len(stamps) else 0.0}
    nis: dict = {}
    for r in log:
        if r.get("accepted") and "nis" in r and np.isfinite(r["nis"]):
            key = r["kind"] if r["kind"] != "landmark" else f"landmark_{r['test']}_{r['dof']}dof"
            nis.setdefault(key, ([], r["dof"]))[0].append(r["nis"])
    metrics["nis"] = nis_summary(nis)
    ups = [r for r in log if r["kind"] == "landmark" and r.get("accepted")]
    metrics["landmark_updates"] = {"pose": sum(r["test"] == "pose" for r in ups),
                                   "position": sum(r["test"] == "position" for r in ups),
                                   "rejected": sum(r["kind"] == "landmark" and not r.get("accepted") for r in log)}
    metrics["cross_class_updates"] = sum(r["label"] != r["landmark_label"] for r in ups)
    metrics["dvl_rejected"] = sum(r["kind"] == "dvl" and not r["accepted"] for r in log)
    metrics["dvl_degraded"] = sum(r["kind"] == "dvl" and r.get("reason") == "degraded" for r in log)
    metrics["dvl_maneuver_resets"] = sum(r["kind"] == "dvl" and r.get("reason") == "maneuver" for r in log)
    metrics["dvl_dropouts"] = sum(r["kind"] == "dvl_dropout" for r in log)
    metrics["depth_rejected"] = sum(r["kind"] == "depth" and not r["accepted"] for r in log)
    metrics["depth_updates"] = sum(r["kind"] == "depth" for r in log)
    metrics["dvl_updates"] = sum(r["kind"] == "dvl" for r in log)
    metrics["fix_updates"] = sum(r["kind"] == "fix" for r in log)
    metrics["fix_rejected"] = sum(r["kind"] == "fix" and not r["accepted"] for r in log)
    metrics["fix_unusable"] = sum(r["kind"] == "fix_unusable" for r in log)
    metrics["skipped_beyond_attitude"] = sum(r["kind"].endswith("_beyond_attitude") for r in log)
    metrics["skipped_before_start"] = before_start
    metrics["skipped_implausible"] = dict(implausible)
    return metrics


def slam_result(mode: str, cfg, ekf, H: dict, log: list[dict], before_start: int, implausible: dict) -> SlamResult:
    """The run's :class:`SlamResult`: the history ``H`` recorded at every epoch, the landmarks, the metrics and the
    RTS-smoothed trajectory (when the filter kept a recorder)."""
    ekf.flush()
    stamps = np.asarray(H["t"])
    landmarks = landmark_estimates(ekf)
    metrics = log_metrics(mode, stamps, landmarks, log, before_start, implausible)
    sm = None
    if ekf.recorder is not None:
        sm = ekf.recorder.smooth(ekf)
        metrics["smoother"] = {"status": ekf.recorder.status}
        if sm is not None and len(sm.x) != len(stamps):  # pragma: no cover - guarded by construction
            raise SlamError("internal error: smoothed epochs do not match the history")
    return SlamResult(mode, stamps, np.asarray(H["p"]).reshape(-1, 3), np.asarray(H["Pp"]).reshape(-1, 3, 3),
                      np.asarray(H["v"]).reshape(-1, 3), np.asarray(H["Pv"]).reshape(-1, 3, 3), np.asarray(H["b"]),
                      None, landmarks, log, metrics, cfg,
                      np.asarray(H["c"]).reshape(-1, 8) if ekf.dvl_calibration else None,
                      np.asarray(H["bv"]) if ekf.yaw_bias else None,
                      None if sm is None else sm.x[:, 0:3].copy(),
                      None if sm is None else sm.P[:, 0:3, 0:3].copy(),
                      None if sm is None else sm.x[:, 3:6].copy(), np.asarray(H["rpy"]).reshape(-1, 3),
                      joint_landmark_cov(ekf))
