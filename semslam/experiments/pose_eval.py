"""Evaluation of object pose estimation on the simulator's own laser scans (not a public API: used by
``tests/pose/test_pose.py`` and ``benchmarks/pose_accuracy.py``).

The clusters are the ground-truth instance points of each object in each scan (segmentation is a
separate stage), voxelised like the pipeline. Each laser line is in the scanner frame at its own stamp;
the truth ``T_scanner_object`` is taken at the cluster's median line stamp:
``inverse(T_world_vehicle(t) @ T_vehicle_scanner) @ T_world_object``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..geometry import rpy_from_rotation, wrap_angle
from ..symmetry import Symmetry


@dataclass(frozen=True, eq=False)
class EvalCluster:
    """One object seen in one scan: cluster points (N, 3) in the scanner frame, true ``T_scanner_object``."""

    label: str
    points_scanner: np.ndarray
    T_scanner_object: np.ndarray
    symmetry: Symmetry
    scan_id: int = -1
    mission_seed: int = -1


def mission_clusters(mission, *, voxel_m: float = 0.005, min_points: int = 30) -> list[EvalCluster]:
    """Ground-truth object clusters of every scan of a simulated ``mission`` (see module docstring)."""
    from ..segmentation.voxel import voxel_downsample
    from ..simulation import builtin_objects
    from ..simulation.simulate import T_world_scanner_at

    objects = builtin_objects()
    out = []
    for rec in mission.scans:
        cloud = mission.load_scan(rec.scan_id)
        inst = np.asarray(cloud.fields["instance"])
        stamps = mission.point_stamps_s(rec, cloud)
        for k in np.unique(inst[inst >= 0]):
            obj = mission.objects[int(k)]
            if obj.label not in objects:
                continue
            sel = inst == k
            pts = voxel_downsample(cloud.points_xyz_m[sel], voxel_m) if voxel_m > 0 else cloud.points_xyz_m[sel]
            if len(pts) < min_points:
                continue
            t = float(np.median(stamps[sel]))
            T_ws = T_world_scanner_at(mission.truth, mission.vehicle.scanner.T_vehicle_scanner, t)
            T = (T_ws.inverse() @ obj.T_world_object).matrix
            out.append(EvalCluster(obj.label, pts, T, objects[obj.label].symmetry, rec.scan_id, mission.seed or 0))
    return out


def simulated_clusters(seeds=(0,), *, altitudes_m=(1.5,), loops: int = 1, voxel_m: float = 0.005,
                       min_points: int = 30) -> list[EvalCluster]:
    """Clusters of one-loop missions for every (seed, altitude) pair."""
    from ..simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset

    out = []
    for alt in altitudes_m:
        for s in seeds:
            cfg = SimulatorConfig(trajectory=TrajectoryConfig(loops=loops, altitude_m=float(alt)))
            out += mission_clusters(simulate_dataset(cfg, seed=int(s)), voxel_m=voxel_m, min_points=min_points)
    return out


def pose_errors(est, T_true: np.ndarray, symmetry: Symmetry) -> tuple[float, float, float]:
    """Rotation error modulo the symmetry (rad), translation error (m) and NEES of a PoseEstimate.

    NEES: the 6-vector (dx dy dz, d roll pitch yaw) against the truth canonicalised like the estimate
    (the symmetry group element closest to the estimate). For a continuous symmetry the rotation about
    the axis is unobservable: the error is taken to the closest equivalent truth (rotation about the
    axis removed) and the covariance's huge variance along it then contributes ~0.
    """
    Te = est.T_scanner_object.matrix
    Re, Rt = Te[:3, :3], T_true[:3, :3]
    rot = symmetry.rotation_error_rad(Re, Rt)
    R_eq = _closest_equivalent(Re, Rt, symmetry)
    e = np.concatenate([Te[:3, 3] - T_true[:3, 3], wrap_angle(rpy_from_rotation(Re) - rpy_from_rotation(R_eq))])
    try:
        nees = float(e @ np.linalg.solve(est.covariance_6x6, e))
    except np.linalg.LinAlgError:
        nees = float("inf")
    return rot, float(np.linalg.norm(e[:3])), nees


def error_vector(est, T_true: np.ndarray, symmetry: Symmetry) -> np.ndarray:
    """(dx dy dz, d roll pitch yaw) of the estimate against the closest equivalent truth (see :func:`pose_errors`)."""
    Te = est.T_scanner_object.matrix
    R_eq = _closest_equivalent(Te[:3, :3], T_true[:3, :3], symmetry)
    return np.concatenate(
        [Te[:3, 3] - T_true[:3, 3], wrap_angle(rpy_from_rotation(Te[:3, :3]) - rpy_from_rotation(R_eq))]
    )


def _closest_equivalent(Re: np.ndarray, Rt: np.ndarray, symmetry: Symmetry) -> np.ndarray:
    from ..symmetry import _axis_angle_matrices

    if symmetry.kind == "none":
        return Rt
    if symmetry.kind == "discrete":
        return symmetry.canonicalize(Rt, reference=Re)
    a = symmetry.axis_object
    angles = np.linspace(-np.pi, np.pi, 3601)
    cands = np.concatenate([Rt @ G @ _axis_angle_matrices(a, angles) for G in symmetry.finite_rotations()])
    tr = np.trace(np.einsum("ji,kjl->kil", Re, cands), axis1=1, axis2=2)
    return cands[int(np.argmax(tr))]


@dataclass
class EvalRow:
    label: str
    rot_rad: float
    trans_m: float
    nees: float
    reliable: bool
    ms: float
    n_points: int
    extras: dict = field(default_factory=dict)

    @property
    def success(self) -> bool:
        return self.rot_rad < np.radians(10) and self.trans_m < 0.01


def evaluate(clusters, models: dict, *, seed: int = 0, **kwargs) -> list[EvalRow]:
    """Run :func:`estimate_object_pose` on every cluster with ``models[label]`` (PoseModel)."""
    from ..pose.estimate import estimate_object_pose

    rows = []
    for i, c in enumerate(clusters):
        t0 = time.process_time()
        est = estimate_object_pose(c.points_scanner, models[c.label], symmetry=c.symmetry, seed=seed + i, **kwargs)
        ms = 1e3 * (time.process_time() - t0)  # CPU time of this process (the machine may be shared)
        r, t, n = pose_errors(est, c.T_scanner_object, c.symmetry)
        rows.append(EvalRow(c.label, r, t, n, est.reliable, ms, len(c.points_scanner),
                            {**est.extras, "fitness": est.fitness, "rmse_m": est.rmse_m, "visibility": est.visibility,
                             "score_margin": est.score_margin,
                             "error": error_vector(est, c.T_scanner_object, c.symmetry)}))
    return rows


def summary_table(rows: list[EvalRow], title: str = "") -> str:
    """Markdown table per class and overall."""
    lines = [f"**{title}**", "", "| class | n | med rot deg | med trans mm | success % | mean NEES | med NEES | "
             "wrong | wrong&flagged | right&flagged | med CPU ms |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    labels = sorted({r.label for r in rows}) + ["all"]
    for lab in labels:
        rs = [r for r in rows if lab in ("all", r.label)]
        if not rs:
            continue
        wrong = [not r.success for r in rs]
        flagged = [not r.reliable for r in rs]
        nees = np.array([r.nees for r in rs if r.success])
        lines.append(
            f"| {lab} | {len(rs)} | {np.degrees(np.median([r.rot_rad for r in rs])):.2f} | "
            f"{1e3 * np.median([r.trans_m for r in rs]):.2f} | {100 * np.mean([r.success for r in rs]):.1f} | "
            f"{np.mean(nees) if len(nees) else float('nan'):.2f} | "
            f"{np.median(nees) if len(nees) else float('nan'):.2f} | "
            f"{sum(wrong)} | {sum(w and f for w, f in zip(wrong, flagged))} | "
            f"{sum((not w) and f for w, f in zip(wrong, flagged))} | {np.median([r.ms for r in rs]):.1f} |"
        )
    return "\n".join(lines)
