"""Evaluation of a SLAM run against ground truth: a pass over a finished :class:`SlamResult` and the
dataset's truth (vehicle trajectory, object poses), after the run. A run without ground truth is left as it is.

Frames. A run whose start came from position fixes lives in the world frame: its errors are taken as they are
(the fix's error is in them), and ``launch_error_m`` says how far the start was off. A run without fixes lives in a
local frame whose north/east origin is the start point: the truth is expressed in that frame by the one
translation that puts the true start at the estimated one (the frame's definition, so the NEES stays a test of the
covariance); ``metrics["evaluation_frame"]`` says which. Every run also gets ``ate_4dof_rmse_m``: the ATE after the
best yaw + translation alignment (as evo's ``-a`` restricted to the 4 degrees of freedom a vehicle with an AHRS and a
depth sensor cannot observe).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..dataset import Dataset, ObjectTruth
from ..geometry import RigidTransform
from ..geometry import rotation_from_rpy
from ..symmetry import Symmetry
from ..slam import _ekf_kernels as kern
from ..slam.association import align_rotation
from .metrics import trajectory_metrics
from ..slam.results import LandmarkEstimate, SlamResult


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
        err = symmetry.rotation_error_rad(R_est, R_true)
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
    objects = list(dataset.objects)
    if truth_pos is not None and len(stamps):
        frame = (metrics.get("start") or {}).get("frame", "world")
        offset = np.zeros(3)
        if frame == "local":
            offset[0:2] = truth_pos[0, 0:2] - result.position_ned_m[0, 0:2]
            truth_pos = truth_pos - offset
            objects = [ObjectTruth(o.name, o.label, RigidTransform.from_rotation_translation(
                o.T_world_object.rotation, o.T_world_object.translation_m - offset), o.in_database) for o in objects]
            metrics["evaluation_frame"] = {
                "frame": "local",
                "alignment": "translation putting the true start at the estimated start (the local frame's origin)",
                "offset_ned_m": offset.tolist(),
            }
        else:
            metrics["evaluation_frame"] = {"frame": "world", "alignment": "none"}
        metrics.update(trajectory_metrics(result.position_ned_m, truth_pos, result.position_cov_m2))
        metrics["launch_error_m"] = float(np.linalg.norm(result.position_ned_m[0] - truth_pos[0]))
        metrics["ate_4dof_rmse_m"] = ate_4dof(result.position_ned_m, truth_pos)
    landmarks = [evaluate_landmark(lm, objects, symmetries.get(lm.label, Symmetry())) for lm in result.landmarks]
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
        metrics["landmark_orientation_error_mean_deg"] = (
            float(np.degrees(np.nanmean(oe))) if np.isfinite(oe).any() else None
        )
        metrics["n_objects_mapped"] = len({lm.matched_object for lm in landmarks if lm.matched_object})
    if "smoother" in metrics and result.smoothed_position_ned_m is not None and truth_pos is not None and len(stamps):
        metrics["smoother"] = dict(metrics["smoother"])
        metrics["smoother"].update(trajectory_metrics(result.smoothed_position_ned_m, truth_pos,
                                                      result.smoothed_position_cov_m2))
        metrics["smoother"]["ate_4dof_rmse_m"] = ate_4dof(result.smoothed_position_ned_m, truth_pos)
    return replace(result, truth_position_ned_m=truth_pos, landmarks=landmarks, metrics=metrics)


def align_4dof(est_m: np.ndarray, truth_m: np.ndarray) -> tuple[float, np.ndarray]:
    """The yaw (rad, about the world z) and translation (m) that best map ``est_m`` (K, 3) onto ``truth_m`` in the
    least-squares sense: ``truth ~ Rz(yaw) est + t`` (closed form: a 2-D Procrustes on the horizontal components)."""
    est, tru = np.asarray(est_m, dtype=float), np.asarray(truth_m, dtype=float)
    me, mt = est.mean(axis=0), tru.mean(axis=0)
    a, b = est[:, :2] - me[:2], tru[:, :2] - mt[:2]
    yaw = float(
        np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    )
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return yaw, mt - R @ me


def ate_4dof(est_m: np.ndarray, truth_m: np.ndarray) -> float:
    """ATE RMSE (m) after :func:`align_4dof`."""
    yaw, t = align_4dof(est_m, truth_m)
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    d = np.asarray(est_m, dtype=float) @ R.T + t - np.asarray(truth_m, dtype=float)
    return float(np.sqrt(np.mean(np.sum(d * d, axis=1))))


def evaluate_results(results: dict, reference: Dataset | None, symmetries: dict[str, Symmetry] | None = None) -> dict:
    """``{mode: SlamResult}`` evaluated against ``reference`` (a dataset holding ground truth), after the run; left as
    they are without one."""
    if reference is None:
        return dict(results)
    return {mode: evaluate_run(r, reference, symmetries) for mode, r in results.items()}


def load_reference(source) -> Dataset | None:
    """The ground truth of a dive's source for evaluation after a run: a :class:`Dataset` with truth or object
    poses, a dataset directory with ``ground_truth/``; None for a bag or a dive without truth."""
    import os
    from pathlib import Path

    if isinstance(source, Dataset):
        ds = source
    else:
        path = Path(os.fspath(source))
        if not (path / "mission.json").is_file():
            return None
        from ..dataset import read_dataset

        ds = read_dataset(path)
    return ds if ds.truth is not None or ds.objects else None
