"""A SLAM run as a ROS 2 bag in mcap storage, for Foxglove Studio, RViz 2 and ``ros2 bag play``.

Everything crosses into ROS frames here, explicitly (REP-103/105, :mod:`semslam.io.ros.frames`): the world is ENU
(``frame_id``, default ``map``), the vehicle is FLU (``base_link``): ``p_enu = C_NED_ENU p_ned``,
``R_enu_flu = C_NED_ENU R_ned_frd C_FRD_FLU``. Object frames (landmarks, detections) keep their own axes: only
the world changes, ``R_enu_object = C_NED_ENU R_ned_object``, so a model drawn in the object frame stays right.

Topics (stamps: the result's seconds + ``time_origin_ns``; bag receive time = header stamp):

* ``/semslam/pose`` ``geometry_msgs/msg/PoseWithCovarianceStamped``, one per epoch. Covariance 6x6 row-major in
  ROS order (x y z rot_x rot_y rot_z): the position block is ``C_NED_ENU P C_NED_ENU^T``. The orientation is the
  AHRS input, not a filter state, so the result has no covariance for it: the rotation block is 0 (ROS has no
  "unknown" flag for this message; REP-145's -1 is for sensor_msgs/Imu) unless ``orientation_variance_rad2``
  (roll, pitch, yaw variances: the ROS angles differ only in sign and offset, so the variances carry over) is given.
* ``/tf`` ``tf2_msgs/msg/TFMessage``: ``frame_id -> base_link`` per epoch (the same pose).
* ``/semslam/path`` (and ``/semslam/path_smoothed`` when smoothed) ``nav_msgs/msg/Path``: the whole trajectory,
  one message at the last epoch.
* ``/semslam/landmarks`` ``visualization_msgs/msg/MarkerArray``, one at the last epoch: per landmark a SPHERE
  (ns ``landmarks``, id = landmark id) shaped as the 3-sigma ellipsoid of the position covariance (axes along its
  eigenvectors, diameters ``6 sqrt(eigenvalue)``, at least 1 mm), an ARROW (ns ``orientation``) along the
  object's x axis, and a TEXT_VIEW_FACING label (ns ``labels``) ``label #id`` 0.15 m above.
* ``/semslam/detections`` ``geometry_msgs/msg/PoseArray`` per scan with detections (with ``detections_by_scan``
  and ``T_vehicle_scanner``): ``T_world_vehicle(stamp) @ T_vehicle_scanner @ T_sensor_object`` in the world, the
  vehicle pose interpolated at each detection's stamp (linear position, slerp attitude, online trajectory);
  detections stamped outside the trajectory are left out. Labels are not carried (PoseArray has none).

Layout: rosbags writes a bag *directory* (``NAME/NAME.mcap`` + ``metadata.yaml``). A ``path`` ending in ``.mcap``
gets the single mcap file only (self-contained: schemas, channels and the rosbag2 metadata are inside; Foxglove and
``ros2 bag play run.mcap`` from Iron on read it); any other ``path`` gets the bag directory. Either way the bag is
written in a temporary sibling directory and renamed into place: an interrupted write leaves nothing.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from .._signals import remove_on_interrupt
from ..errors import InputError
from ..geometry import RigidTransform, quat_wxyz_from_rotation, rotation_from_quat_wxyz
from ..io.ros.frames import C_NED_ENU, quat_xyzw_from_R_world_ned_vehicle_frd, vectors_enu_from_ned
from .result_views import check_result, landmark_class_indices, trajectory_poses
from ..slam.results import SlamResult

__all__ = ["write_mcap", "TOPICS"]

TOPICS = {"pose": "/semslam/pose", "tf": "/tf", "path": "/semslam/path", "path_smoothed": "/semslam/path_smoothed",
          "landmarks": "/semslam/landmarks", "detections": "/semslam/detections"}
_PALETTE = [(0.12, 0.47, 0.71), (1.0, 0.5, 0.05), (0.17, 0.63, 0.17), (0.84, 0.15, 0.16), (0.58, 0.40, 0.74),
            (0.55, 0.34, 0.29), (0.89, 0.47, 0.76), (0.5, 0.5, 0.5), (0.74, 0.74, 0.13), (0.09, 0.75, 0.81)]


def _slerp_rotation(R0: np.ndarray, R1: np.ndarray, a: float) -> np.ndarray:
    q0, q1 = quat_wxyz_from_rotation(R0), quat_wxyz_from_rotation(R1)
    if q0 @ q1 < 0:
        q1 = -q1
    theta = float(np.arccos(np.clip(q0 @ q1, -1.0, 1.0)))
    q = q0 if theta < 1e-12 else (np.sin((1 - a) * theta) * q0 + np.sin(a * theta) * q1) / np.sin(theta)
    return rotation_from_quat_wxyz(q)


def _vehicle_pose_at(t: float, stamps: np.ndarray, pos: np.ndarray, R: np.ndarray) -> RigidTransform | None:
    """``T_world_vehicle`` (NED/FRD) at ``t``, interpolated; None outside the trajectory's span."""
    if not np.isfinite(t) or t < stamps[0] or t > stamps[-1]:
        return None
    k = min(int(np.searchsorted(stamps, t, side="right")) - 1, len(stamps) - 2)
    if k < 0:  # one epoch only, t equal to it
        return RigidTransform.from_rotation_translation(R[0], pos[0])
    dt = stamps[k + 1] - stamps[k]
    a = float(np.clip((t - stamps[k]) / dt, 0.0, 1.0)) if dt > 0 else 0.0
    return RigidTransform.from_rotation_translation(_slerp_rotation(R[k], R[k + 1], a),
                                                    (1 - a) * pos[k] + a * pos[k + 1])


def _check_target(path: Any) -> tuple[Path, bool]:
    out = Path(path)
    single = out.suffix.lower() == ".mcap"
    if single and out.is_dir():
        raise InputError(f"The 'path' argument of write_mcap must be a file path (it ends in .mcap). "
                         f"Got the directory '{out}' instead.")
    if not single and out.exists() and not (out.is_dir() and ((out / "metadata.yaml").exists()
                                                                or not any(out.iterdir()))):
        raise InputError(f"The 'path' argument of write_mcap must be a .mcap file, a new directory or a ROS 2 bag "
                         f"directory to replace. Got '{out}' (an existing {'directory' if out.is_dir() else 'file'} "
                         f"that is not a bag) instead.")
    return out, single


def write_mcap(result: SlamResult, path: str | os.PathLike, *, frame_id: str = "map",
               child_frame_id: str = "base_link", detections_by_scan: Mapping[int, Sequence[Any]] | None = None,
               T_vehicle_scanner: RigidTransform | None = None, smoothed: bool = True, time_origin_ns: int = 0,
               orientation_variance_rad2: Any = None) -> Path:
    """Write ``result`` as a ROS 2 mcap bag (see the module doc for topics, frames, covariance and layout).

    ``time_origin_ns``: the ROS time of the result's t = 0 (for a dataset read from a bag, its
    ``metadata["source"]["time_origin_ns"]``). ``smoothed``: also ``/semslam/path_smoothed`` when the result has
    a smoothed trajectory. Returns the written path. Needs ``rosbags`` (imported here).
    """
    from rosbags.rosbag2 import StoragePlugin, Writer

    from ..io.ros._encode import default_typestore, ros_header

    out, single = _check_target(path)
    var, stamps, pos_ned, R_ned = _checked_inputs(result, detections_by_scan, T_vehicle_scanner, time_origin_ns,
                                                  orientation_variance_rad2)
    ts = default_typestore()
    T = ts.types
    ns = lambda t: int(time_origin_ns) + int(round(float(t) * 1e9))  # noqa: E731
    hdr = lambda t: ros_header(ts, ns(t), frame_id)  # noqa: E731
    pt = lambda p: T["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]), z=float(p[2]))  # noqa: E731
    vec = lambda p: T["geometry_msgs/msg/Vector3"](x=float(p[0]), y=float(p[1]), z=float(p[2]))  # noqa: E731
    qmsg = lambda q: T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]),  # noqa: E731
                                                       w=float(q[3]))

    def pose_msg(p_ned: np.ndarray, R_world_ned: np.ndarray, vehicle: bool) -> Any:
        if vehicle:  # FRD body -> FLU body (REP-103)
            q = quat_xyzw_from_R_world_ned_vehicle_frd(R_world_ned)
        else:  # an object's own frame: only the world changes
            w, x, y, z = quat_wxyz_from_rotation(C_NED_ENU @ R_world_ned)
            q = (x, y, z, w)
        return T["geometry_msgs/msg/Pose"](position=pt(vectors_enu_from_ned(p_ned)), orientation=qmsg(q))

    msgs: list[tuple[int, int, str, str, Any]] = []  # (ns, order, topic, type, message)
    cov = np.zeros((len(stamps), 6, 6))
    cov[:, :3, :3] = C_NED_ENU @ np.asarray(result.position_cov_m2, dtype=np.float64) @ C_NED_ENU.T
    cov[:, 3:, 3:] = np.diag(var)
    poses = [pose_msg(p, r, True) for p, r in zip(pos_ned, R_ned)]
    for k, t in enumerate(stamps):
        msgs.append((ns(t), 0, TOPICS["pose"], "geometry_msgs/msg/PoseWithCovarianceStamped",
                     T["geometry_msgs/msg/PoseWithCovarianceStamped"](header=hdr(t), pose=T[
                         "geometry_msgs/msg/PoseWithCovariance"](pose=poses[k], covariance=cov[k].reshape(-1)))))
        tf = T["geometry_msgs/msg/TransformStamped"](header=hdr(t), child_frame_id=child_frame_id, transform=T[
            "geometry_msgs/msg/Transform"](translation=vec(vectors_enu_from_ned(pos_ned[k])),
                                           rotation=poses[k].orientation))
        msgs.append((ns(t), 1, TOPICS["tf"], "tf2_msgs/msg/TFMessage", T["tf2_msgs/msg/TFMessage"](transforms=[tf])))

    def path_msg(pose_list: list) -> Any:
        return T["nav_msgs/msg/Path"](header=hdr(stamps[-1]), poses=[
            T["geometry_msgs/msg/PoseStamped"](header=hdr(t), pose=p) for t, p in zip(stamps, pose_list)])

    t_end = ns(stamps[-1])
    msgs.append((t_end, 2, TOPICS["path"], "nav_msgs/msg/Path", path_msg(poses)))
    if smoothed and result.smoothed_position_ned_m is not None:
        sm = [pose_msg(p, r, True) for p, r in zip(np.asarray(result.smoothed_position_ned_m), R_ned)]
        msgs.append((t_end, 3, TOPICS["path_smoothed"], "nav_msgs/msg/Path", path_msg(sm)))
    msgs.append((t_end, 4, TOPICS["landmarks"], "visualization_msgs/msg/MarkerArray",
                 T["visualization_msgs/msg/MarkerArray"](markers=_landmark_markers(result, ts, hdr(stamps[-1]), pt,
                                                                                   vec, qmsg, pose_msg))))
    if detections_by_scan is not None:
        msgs += _detection_messages(detections_by_scan, T_vehicle_scanner, stamps, pos_ned, R_ned, ts, ns, hdr,
                                    pose_msg)
    msgs.sort(key=lambda m: (m[0], m[1]))
    return _write_bag(out, single, msgs, ts, Writer, StoragePlugin)


def _checked_inputs(result: SlamResult, detections_by_scan, T_vehicle_scanner, time_origin_ns: int,
                    orientation_variance_rad2: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`write_mcap`'s arguments checked: ``(orientation variances (3,), stamps, positions NED, rotations)``."""
    check_result(result, "write_mcap", need_attitude=True)
    if (detections_by_scan is None) != (T_vehicle_scanner is None):
        raise InputError("The 'T_vehicle_scanner' argument of write_mcap must be given with 'detections_by_scan' "
                         "(and only with it). Got only one of the two instead.")
    if T_vehicle_scanner is not None and not isinstance(T_vehicle_scanner, RigidTransform):
        raise InputError(f"The 'T_vehicle_scanner' argument of write_mcap must be a RigidTransform. "
                         f"Got {type(T_vehicle_scanner).__name__} instead.")
    var = np.zeros(3) if orientation_variance_rad2 is None else np.asarray(orientation_variance_rad2, dtype=float)
    if var.shape != (3,) or not np.all(np.isfinite(var)) or np.any(var < 0):
        raise InputError(f"The 'orientation_variance_rad2' argument of write_mcap must be 3 finite variances >= 0 "
                         f"(roll, pitch, yaw). Got {orientation_variance_rad2!r:.60} instead.")
    stamps, pos_ned, R_ned = trajectory_poses(result, frame="ned", caller="write_mcap")
    if len(stamps) == 0:
        raise InputError("The 'result' argument of write_mcap must have at least one epoch. Got none instead.")
    if int(time_origin_ns) + round(float(stamps.min()) * 1e9) < 0:
        raise InputError(f"The 'time_origin_ns' argument of write_mcap must make every stamp >= 0 ns. "
                         f"Got {time_origin_ns} with a first stamp of {stamps.min()} s instead.")
    return var, stamps, pos_ned, R_ned


def _detection_messages(detections_by_scan, T_vehicle_scanner: RigidTransform, stamps, pos_ned, R_ned, ts: Any,
                        ns, hdr, pose_msg) -> list:
    """One ``PoseArray`` per scan with the world poses of its detections (placed with the trajectory)."""
    T = ts.types
    msgs = []
    for scan_id in sorted(detections_by_scan):
        placed = []
        for det in detections_by_scan[scan_id]:
            T_wv = _vehicle_pose_at(float(det.stamp_s), stamps, pos_ned, R_ned)
            if T_wv is not None:
                T_wo = T_wv @ T_vehicle_scanner @ det.T_sensor_object
                placed.append((float(det.stamp_s), pose_msg(T_wo.translation_m, T_wo.rotation, False)))
        if placed:
            t0 = min(t for t, _ in placed)
            msgs.append((ns(t0), 5, TOPICS["detections"], "geometry_msgs/msg/PoseArray",
                         T["geometry_msgs/msg/PoseArray"](header=hdr(t0), poses=[p for _, p in placed])))
    return msgs


def _landmark_markers(result: SlamResult, ts: Any, header: Any, pt, vec, qmsg, pose_msg) -> list:
    T = ts.types
    Marker = T["visualization_msgs/msg/Marker"]
    classes = landmark_class_indices(result)
    markers = []

    def marker(ns_: str, id_: int, type_: int, pose: Any, scale: Any, rgba: tuple, text: str = "") -> Any:
        return Marker(header=header, ns=ns_, id=int(id_), type=type_, action=Marker.ADD, pose=pose, scale=vec(scale),
                      color=T["std_msgs/msg/ColorRGBA"](r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
                      lifetime=T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0), frame_locked=False, points=[],
                      colors=[], texture_resource="", texture=T["sensor_msgs/msg/CompressedImage"](
                          header=header, format="", data=np.zeros(0, dtype=np.uint8)), uv_coordinates=[], text=text,
                      mesh_resource="", mesh_file=T["visualization_msgs/msg/MeshFile"](
                          filename="", data=np.zeros(0, dtype=np.uint8)), mesh_use_embedded_materials=False)

    for lm in result.landmarks:
        pose = np.asarray(lm.pose_xyzrpy, dtype=np.float64)
        rgb = _PALETTE[classes[lm.label] % len(_PALETTE)]
        P_enu = C_NED_ENU @ np.asarray(lm.covariance_6x6, dtype=np.float64)[:3, :3] @ C_NED_ENU.T
        eigval, eigvec = np.linalg.eigh(0.5 * (P_enu + P_enu.T))
        if np.linalg.det(eigvec) < 0:
            eigvec[:, 2] = -eigvec[:, 2]
        w, x, y, z = quat_wxyz_from_rotation(eigvec)
        p_enu = vectors_enu_from_ned(pose[:3])
        ellipsoid = T["geometry_msgs/msg/Pose"](position=pt(p_enu), orientation=qmsg((x, y, z, w)))
        markers.append(marker("landmarks", lm.landmark_id, Marker.SPHERE, ellipsoid,
                              np.maximum(6.0 * np.sqrt(np.clip(eigval, 0.0, None)), 1e-3), (*rgb, 0.6)))
        R_obj = RigidTransform.from_xyz_rpy(pose[:3], pose[3:]).rotation
        markers.append(marker("orientation", lm.landmark_id, Marker.ARROW, pose_msg(pose[:3], R_obj, False),
                              (0.2, 0.02, 0.02), (*rgb, 1.0)))
        label = T["geometry_msgs/msg/Pose"](position=pt(p_enu + [0.0, 0.0, 0.15]), orientation=qmsg((0, 0, 0, 1)))
        markers.append(marker("labels", lm.landmark_id, Marker.TEXT_VIEW_FACING, label, (0.0, 0.0, 0.1),
                              (1.0, 1.0, 1.0, 1.0), f"{lm.label} #{lm.landmark_id}"))
    return markers


def _write_bag(out: Path, single: bool, msgs: list, ts: Any, Writer: Any, StoragePlugin: Any) -> Path:
    """Write ``msgs`` into a temporary sibling directory, then rename the bag (or its mcap file) to ``out``."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmpdir = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    remove_on_interrupt(tmpdir)
    try:
        bag = tmpdir / (out.stem if single else out.name)
        with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            conns: dict[str, Any] = {}
            for stamp_ns, _, topic, msgtype, msg in msgs:
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
                writer.write(conns[topic], stamp_ns, ts.serialize_cdr(msg, msgtype))
        for f in bag.iterdir():
            with open(f, "rb") as fh:
                os.fsync(fh.fileno())
        if single:
            os.replace(bag / f"{bag.name}.mcap", out)
        else:
            if out.exists():
                os.replace(out, tmpdir / "previous")
            os.replace(bag, out)
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)
    return out
