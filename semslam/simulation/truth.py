"""Ground truth of simulated scans, for evaluating the recognition and pose pipeline.

Simulated scans carry two per-point fields: ``instance`` (index into ``mission.objects``; -1 tank, -2
backscatter outlier) and ``line`` (laser line index: each line is taken in the scanner frame at its own
stamp). From them a cluster gets its true object, and a detection its true pose at its own stamp.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..cloud import PointCloud
from ..detection import Detection
from ..errors import DatasetError
from ..geometry import RigidTransform
from ..symmetry import Symmetry
from ..dataset import Dataset, ScanRecord
from .simulate import T_world_scanner_at

BACKGROUND = "background"


def true_T_scanner_object(mission: Dataset, object_index: int, stamp_s: float) -> RigidTransform:
    """The true pose of ``mission.objects[object_index]`` in the scanner frame at ``stamp_s``."""
    if mission.truth is None:
        raise DatasetError("the mission has no ground truth")
    T_world_scanner = T_world_scanner_at(mission.truth, mission.vehicle.scanner.T_vehicle_scanner, stamp_s)
    return T_world_scanner.inverse() @ mission.objects[object_index].T_world_object


@dataclass(frozen=True)
class ClusterTruth:
    """The object a cluster mostly belongs to (``object_index`` -1 and label ``background`` for tank,
    outliers and clutter) and the share of its points that belong to it."""

    object_index: int
    label: str
    purity: float


def cluster_truth(mission: Dataset, cloud: PointCloud, point_indices: np.ndarray) -> ClusterTruth:
    """Majority ground-truth object of the scan points ``point_indices``."""
    if "instance" not in cloud.fields:
        raise DatasetError("the scan has no 'instance' field: it was not simulated by semslam")
    inst = np.asarray(cloud.fields["instance"])[np.asarray(point_indices, dtype=np.int64)]
    if inst.size == 0:
        return ClusterTruth(-1, BACKGROUND, 0.0)
    values, counts = np.unique(inst, return_counts=True)
    best = int(values[np.argmax(counts)])
    purity = float(counts.max() / inst.size)
    if best < 0 or not mission.objects[best].in_database:
        return ClusterTruth(best if best >= 0 else -1, BACKGROUND, purity)
    return ClusterTruth(best, mission.objects[best].label, purity)


@dataclass(frozen=True)
class PoseError:
    """Error of one detection's pose against the truth: rotation (modulo the symmetry), translation, NEES."""

    rotation_error_rad: float
    translation_error_m: float
    nees: float
    dof: int


def pose_error(det: Detection, T_true: RigidTransform, symmetry: Symmetry) -> PoseError:
    """Pose error of ``det`` against ``T_true`` (both ``T_scanner_object``), modulo ``symmetry``.

    The NEES uses the error vector [dx dy dz droll dpitch dyaw] after moving the true orientation to the
    symmetry-equivalent one closest to the estimate; for a continuous symmetry the rotation rows are left out
    (their variance is deliberately huge) and the NEES has 3 degrees of freedom.
    """
    from ..geometry import rpy_from_rotation, wrap_angle

    R_est = det.T_sensor_object.rotation
    R_true = T_true.rotation
    rot_err = float(symmetry.rotation_error_rad(R_est, R_true)) if symmetry.kind != "none" else \
        float(np.arccos(np.clip((np.trace(R_est.T @ R_true) - 1) / 2, -1, 1)))
    dt = det.T_sensor_object.translation_m - T_true.translation_m
    if symmetry.kind == "continuous":
        cov = det.covariance_6x6[:3, :3]
        e = dt
        dof = 3
    else:
        if symmetry.kind == "discrete":
            candidates = [R_true @ G for G in symmetry.group_rotations()]
            R_true = min(candidates, key=lambda R: np.arccos(np.clip((np.trace(R_est.T @ R) - 1) / 2, -1, 1)))
        drpy = wrap_angle(rpy_from_rotation(R_est) - rpy_from_rotation(R_true))
        e = np.concatenate([dt, drpy])
        cov = det.covariance_6x6
        dof = 6
    try:
        nees = float(e @ np.linalg.solve(cov, e))
    except np.linalg.LinAlgError:
        nees = float("inf")
    return PoseError(rot_err, float(np.linalg.norm(dt)), nees, dof)
