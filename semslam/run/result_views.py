"""A :class:`~semslam.slam.SlamResult` seen by the exporters: its poses in a chosen world frame (NED, or ENU with
a FLU body), its landmark classes as indices, and the argument checks every exporter shares
(:mod:`semslam.run.export` and :mod:`semslam.run.export_mcap` both read it)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, SlamError
from ..geometry import rotations_from_rpy
from ..io.ros.frames import R_world_enu_vehicle_flu_from_R_world_ned_vehicle_frd, vectors_enu_from_ned
from ..slam.results import SlamResult

#: the world frames a trajectory is written in
FRAMES = ("ned", "enu")


def check_result(result: Any, caller: str, *, need_attitude: bool) -> SlamResult:
    if not isinstance(result, SlamResult):
        raise InputError(f"The 'result' argument of {caller} must be a semslam.slam.SlamResult. "
                         f"Got {type(result).__name__} instead.")
    if need_attitude:
        att = result.attitude_rpy_rad
        if att is None or np.shape(att) != (len(result.stamps_s), 3):
            raise SlamError(f"The 'result' argument of {caller} must have an attitude (attitude_rpy_rad, (K, 3)): "
                            f"this format stores orientations. Got {'none' if att is None else np.shape(att)} "
                            f"instead (a result from an older semslam: run the SLAM again).")
    return result


def check_file_path(path: Any, caller: str, name: str = "path") -> Path:
    try:
        out = Path(path)
    except TypeError:
        raise InputError(f"The {name!r} argument of {caller} must be a file path. Got {path!r:.60} instead.") from None
    if out.is_dir():
        raise InputError(f"The {name!r} argument of {caller} must be a file path. Got the directory '{out}' instead.")
    return out


def check_frame(frame: Any, caller: str) -> str:
    if frame not in FRAMES:
        raise InputError(f"The 'frame' argument of {caller} must be one of {FRAMES}. Got {frame!r} instead.")
    return frame


def trajectory_poses(result: SlamResult, *, smoothed: bool = False, frame: str = "ned",
                     caller: str = "trajectory_poses") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(stamps_s (K,), positions (K, 3), rotations (K, 3, 3))`` of ``T_world_vehicle`` in ``frame``:
    ``"ned"`` (world NED, body FRD) or ``"enu"`` (world ENU, body FLU: ``R_enu_flu = C_NED_ENU R C_FRD_FLU``)."""
    check_result(result, caller, need_attitude=True)
    check_frame(frame, caller)
    if smoothed and result.smoothed_position_ned_m is None:
        raise SlamError(f"The 'smoothed' argument of {caller} asks for the smoothed trajectory, and the result has "
                        f"none. Got smoothed=True instead (pass smoothed=False, or run the smoother).")
    pos = np.asarray(result.smoothed_position_ned_m if smoothed else result.position_ned_m, dtype=np.float64)
    R = rotations_from_rpy(np.asarray(result.attitude_rpy_rad, dtype=np.float64))
    if frame == "enu":
        pos = vectors_enu_from_ned(pos).reshape(-1, 3)
        R = np.array([R_world_enu_vehicle_flu_from_R_world_ned_vehicle_frd(r) for r in R]).reshape(-1, 3, 3)
    return np.asarray(result.stamps_s, dtype=np.float64), pos, R


def landmark_class_indices(result: SlamResult) -> dict[str, int]:
    """Class index of each label of the map: the sorted labels numbered from 0 (the PLY's ``class_index``)."""
    return {label: i for i, label in enumerate(sorted({lm.label for lm in result.landmarks}))}
