"""Evaluation of a SLAM run against ground truth: a pass over a finished :class:`SlamResult` and the
dataset's truth (vehicle trajectory, object poses). A run without ground truth is left as it is."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..dataset import Dataset
from ..geometry import rotation_from_rpy
from ..symmetry import Symmetry
from . import _ekf_kernels as kern
from .association import align_rotation
from .metrics import trajectory_metrics
from .results import LandmarkEstimate, SlamResult


def evaluate_landmark(lm: LandmarkEstimate, objects, symmetry: Symmetry) -> LandmarkEstimate:
    """``lm`` with its nearest true object of the same class, position and orientation errors and NEES."""
    objs = [o for o in objects if o.label == lm.label]
    if not objs:
        return lm
    pose, cov = lm.pose_xyzrpy, lm.covariance_6x6
    d = [np.linalg.norm(o.T_world_object.translation_m - pose[:3]) for o in objs]
    o = objs[int(np.argmin(d))]
    R_est = rotation_from_rpy(*pose[3:6])
    R_true = o.T_world_object.rotation
    if symmetry.kind == "continuous":
        a = symmetry.axis_object
        err = float(np.arccos(np.clip((R_est @ a) @ (R_true @ a), -1, 1)))
    else:
        err = float(np.linalg.norm(kern.so3_log(align_rotation(R_est, R_true, symmetry, np.zeros((0, 3))) @ R_true.T)))
    e_p = o.T_world_object.translation_m - pose[:3]
    nees_p = kern.mahalanobis2(e_p, cov[:3, :3])
    nees_q = float("nan")
    if symmetry.kind != "continuous":
        R_al = align_rotation(R_true, R_est, symmetry, np.zeros((0, 3)))  # the equivalent truth closest to the estimate
        e = np.concatenate([e_p, kern.world_rate_to_rpy(pose[3:6]) @ kern.so3_log(R_al @ R_est.T)])
        nees_q = kern.mahalanobis2(e, cov)
    return replace(lm, matched_object=o.name, position_error_m=float(min(d)), orientation_error_rad=err,
                   nees_position=nees_p, nees_pose=nees_q)


def evaluate_run(result: SlamResult, dataset: Dataset, symmetries: dict[str, Symmetry] | None = None) -> SlamResult:
    """``result`` with the truth trajectory at its epochs and the truth-based metrics: ATE and NEES (online and
    smoothed), landmark errors and NEES, updates of a landmark by another object's detections, objects mapped."""
    symmetries = symmetries or {}
    truth = dataset.truth
    stamps = result.stamps_s
    metrics = dict(result.metrics)
    truth_pos = truth.interpolate_position(stamps) if truth is not None else None
    if truth_pos is not None and len(stamps):
        metrics.update(trajectory_metrics(result.position_ned_m, truth_pos, result.position_cov_m2))
    landmarks = [evaluate_landmark(lm, dataset.objects, symmetries.get(lm.label, Symmetry())) for lm in result.landmarks]
    ups = [r for r in result.update_log if r["kind"] == "landmark" and r.get("accepted")]
    byname = {lm.landmark_id: lm.matched_object for lm in landmarks}
    metrics["wrong_object_updates"] = sum(bool(r.get("object_name")) and r["object_name"] != byname.get(r["landmark"])
                                          for r in ups)
    lp = np.array([lm.nees_position for lm in landmarks])
    lq = np.array([lm.nees_pose for lm in landmarks])
    metrics["landmark_nees_position"] = lp[np.isfinite(lp)].tolist()
    metrics["landmark_nees_pose"] = lq[np.isfinite(lq)].tolist()
    if landmarks and dataset.objects:
        pe = np.array([lm.position_error_m for lm in landmarks])
        oe = np.array([lm.orientation_error_rad for lm in landmarks])
        metrics["landmark_position_error_mean_m"] = float(np.nanmean(pe)) if np.isfinite(pe).any() else None
        metrics["landmark_position_error_max_m"] = float(np.nanmax(pe)) if np.isfinite(pe).any() else None
        metrics["landmark_orientation_error_mean_deg"] = float(np.degrees(np.nanmean(oe))) if np.isfinite(oe).any() else None
        metrics["n_objects_mapped"] = len({lm.matched_object for lm in landmarks if lm.matched_object})
    if "smoother" in metrics and result.smoothed_position_ned_m is not None and truth_pos is not None and len(stamps):
        metrics["smoother"] = dict(metrics["smoother"])
        metrics["smoother"].update(trajectory_metrics(result.smoothed_position_ned_m, truth_pos,
                                                      result.smoothed_position_cov_m2))
    return replace(result, truth_position_ned_m=truth_pos, landmarks=landmarks, metrics=metrics)
