"""A small analytic mission (no laser scans) for filter tests and Monte-Carlo runs.

A vehicle flies ``loops`` times around a square of side ``side_m`` at constant body velocity
``[speed, 0, 0]`` and constant depth, turning on the spot-free arcs of radius ``corner_radius_m``;
objects of four classes lie at the square's corners. Sensors: DVL (body velocity, white noise
``dvl_sigma_mps``, optional dropouts and outliers), AHRS (white noise, optional constant yaw bias),
depth (white noise). Everything is seeded.
"""

from __future__ import annotations

import math

import numpy as np

from .._validation import as_rng
from ..geometry import RigidTransform
from ..dataset import AttitudeLog, Dataset, DepthLog, DvlLog, ObjectTruth, VehicleDescription, VehicleTruth

LABELS = ("reducing_socket", "elbow", "reducing_tee", "ball_valve")


def square_dataset(*, seed=0, loops: int = 3, side_m: float = 4.0, speed_mps: float = 0.3, depth_m: float = 3.5,
                   corner_radius_m: float = 0.5, truth_rate_hz: float = 20.0, dvl_rate_hz: float = 5.0,
                   depth_rate_hz: float = 10.0, dvl_sigma_mps: float = 0.005, ahrs_sigma_rpy_rad=(0.0035, 0.0035, 0.0175),
                   depth_sigma_m: float = 0.02, yaw_bias_rad: float = 0.0, dvl_dropout_prob: float = 0.0,
                   dvl_outlier_prob: float = 0.0, dvl_outlier_std_mps: float = 0.2, object_depth_m: float = 5.0,
                   extra_objects: int = 0) -> Dataset:
    """The mission described in the module docstring. Stamps start at 0 s."""
    rng = as_rng(seed, caller="square_dataset")
    straight = side_m - 2 * corner_radius_m
    arc = 0.5 * math.pi * corner_radius_m
    loop_len = 4 * (straight + arc)
    duration = loops * loop_len / speed_mps
    t = np.arange(0.0, duration, 1.0 / truth_rate_hz)
    s = (t * speed_mps) % loop_len
    seg = np.floor(s / (straight + arc)).astype(int)
    u = s - seg * (straight + arc)
    yaw = np.where(u < straight, seg * math.pi / 2, seg * math.pi / 2 + (u - straight) / corner_radius_m)
    # integrate the exact path: heading derivative known, position from the closed-form arc/straight pieces
    corners = np.array([[0.0, 0.0], [side_m, 0.0], [side_m, side_m], [0.0, side_m]])
    start = corners + np.array([[corner_radius_m, 0.0], [0.0, corner_radius_m], [-corner_radius_m, 0.0], [0.0, -corner_radius_m]])
    h0 = seg * math.pi / 2
    d0 = np.stack([np.cos(h0), np.sin(h0)], -1)
    n0 = np.stack([-np.sin(h0), np.cos(h0)], -1)
    su = np.minimum(u, straight)
    xy = start[seg] + d0 * su[:, None]
    on_arc = u > straight
    ang = (u - straight) / corner_radius_m
    xy_arc = start[seg] + d0 * straight + corner_radius_m * (d0 * np.sin(ang)[:, None] + n0 * (1 - np.cos(ang))[:, None])
    xy = np.where(on_arc[:, None], xy_arc, xy)
    pos = np.column_stack([xy, np.full(len(t), depth_m)])
    rpy = np.column_stack([np.zeros(len(t)), np.zeros(len(t)), (yaw + math.pi) % (2 * math.pi) - math.pi])
    vel = np.tile([speed_mps, 0.0, 0.0], (len(t), 1))
    truth = VehicleTruth(t, pos, rpy, vel)

    td = np.arange(0.0, duration, 1.0 / dvl_rate_hz)
    vd = np.tile([speed_mps, 0.0, 0.0], (len(td), 1)) + rng.normal(0.0, dvl_sigma_mps, (len(td), 3))
    out = rng.random(len(td)) < dvl_outlier_prob
    vd[out] += rng.normal(0.0, dvl_outlier_std_mps, (int(out.sum()), 3))
    valid = rng.random(len(td)) >= dvl_dropout_prob
    vd[~valid] = np.nan
    ta = t
    ra = rpy + rng.normal(0.0, 1.0, rpy.shape) * np.asarray(ahrs_sigma_rpy_rad)
    ra[:, 2] = (ra[:, 2] + yaw_bias_rad + math.pi) % (2 * math.pi) - math.pi
    tz = np.arange(0.0, duration, 1.0 / depth_rate_hz)
    z = depth_m + rng.normal(0.0, depth_sigma_m, len(tz))
    objects = []
    for i, (c, label) in enumerate(zip(corners, LABELS)):
        objects.append(ObjectTruth(f"{label}_{i}", label, RigidTransform.from_xyz_rpy(
            [c[0], c[1], object_depth_m], [0.0, 0.0, rng.uniform(-math.pi, math.pi)])))
    for k in range(extra_objects):
        label = LABELS[k % 4]
        c = rng.uniform(0.0, side_m, 2)
        objects.append(ObjectTruth(f"{label}_x{k}", label, RigidTransform.from_xyz_rpy(
            [c[0], c[1], object_depth_m], [0.0, 0.0, rng.uniform(-math.pi, math.pi)])))
    T_vs = RigidTransform.from_xyz_rpy([0.6, 0.0, 0.3], [0.0, 0.0, 0.0])
    vehicle = VehicleDescription.from_dict({
        "name": "synthetic-square",
        "scanner": {"matrix": T_vs.matrix.tolist(), "max_range_m": 4.0, "min_range_m": 0.3,
                    "fov_rad": math.radians(70.0), "rate_hz": 2.0},
        "dvl": {"noise_abs_mps": dvl_sigma_mps, "noise_rel": 0.0, "scale_factor_sigma": 0.0,
                "misalignment_sigma_rad": 0.0, "bias_sigma_mps": 0.0, "degraded_bias_sigma_mps": 0.0},
        "attitude": {"noise_rpy_rad": list(ahrs_sigma_rpy_rad)},
        "depth": {"noise_m": depth_sigma_m}})
    meta = {"synthetic": {"ahrs_yaw_bias_rad": yaw_bias_rad}}
    return Dataset(vehicle, DvlLog(td, vd, valid), AttitudeLog(ta, ra), DepthLog(tz, z), truth, objects, [], meta,
                   seed=seed if isinstance(seed, int) else None)
