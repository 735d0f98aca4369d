"""Any dataset as a ROS bag (ROS 1 ``.bag``, ROS 2 ``mcap`` or ``sqlite3``), the way a vehicle would have
recorded it: ``sensor_msgs/Imu`` (REP-103 ENU/FLU), a vendor DVL message ``semslam_msgs/msg/Dvl`` (velocity in the
instrument frame, per-beam ranges and validity, its definition written into the bag), ``sensor_msgs/FluidPressure``
and ``sensor_msgs/PointCloud2`` scans with a per-point ``t`` (float64 s from the scan's start). The topic map that
reads it back is :data:`SEMSLAM_TOPICS`. Stamps start at :data:`TIME_ORIGIN_NS` (a whole second).
"""

from __future__ import annotations

import heapq
import os
from pathlib import Path

import numpy as np

from .._outdir import check_output_dir, check_output_file, staged_output_dir, staged_output_file
from ..errors import DatasetError
from .dataset import Dataset
from .rosbag import TopicMap

FORMATS = ("ros1", "ros2-mcap", "ros2-sqlite3")
TIME_ORIGIN_NS = 1_700_000_000 * 1_000_000_000
DVL_TYPE = "semslam_msgs/msg/Dvl"
#: the vendor DVL message (written into every bag: readers need no .msg file)
DVL_MSG = """std_msgs/Header header
geometry_msgs/Vector3 velocity   # bottom velocity (m/s) in the instrument frame (FRD)
float64[4] beam_ranges_m         # slant range of each beam (m), NaN without a return
bool[4] beam_valid               # beam locked on the bottom
float64 figure_of_merit          # vendor quality figure (m/s)
"""
SEMSLAM_TOPICS = TopicMap(
    scans="/semslam/scans",
    attitude="/semslam/imu",
    dvl="/semslam/dvl",
    depth="/semslam/pressure",
    attitude_frame="enu",
    dvl_frame="frd",
)
_G = 9.80665


def topic_map_of(dataset: Dataset, *, scans: bool | None = None) -> TopicMap:
    """The topic map of the bag :func:`write_bag` writes for ``dataset``: :data:`SEMSLAM_TOPICS`, plus the GPS and
    USBL topics and the geodetic origin when the dataset has position fixes; no scans topic without scans (``scans``:
    whether the bag has scans, when they are given to :func:`write_bag` apart; default: the dataset's)."""
    from dataclasses import replace

    f = dataset.fixes
    has_scans = bool(dataset.scans) if scans is None else bool(scans)
    base = SEMSLAM_TOPICS if has_scans else replace(SEMSLAM_TOPICS, scans=None)  # the bag has no such topic
    if f is None:
        return base
    return replace(base, gps="/semslam/gps" if "gps" in f.source else None,
                   usbl="/semslam/usbl" if "usbl" in f.source else None,
                   origin=None if dataset.geodetic_origin is None else dataset.geodetic_origin.as_dict())


def _ns(t: float) -> int:
    return TIME_ORIGIN_NS + int(round(float(t) * 1e9))


def _messages(ds: Dataset, store, T, scans=None):
    """``(stamp_ns, topic, msgtype, message)`` of every log sample and scan, in time order (a generator: the scans
    are encoded one at a time, from ``scans`` -- ``(record, cloud)`` in time order -- or the dataset's own)."""
    from ..geometry import rotation_from_rpy
    from ..io.ros import quat_xyzw_from_R_world_ned_vehicle_frd
    from ..io.ros._encode import encode_pointcloud2, ros_header

    out = []
    vec = lambda v: T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))  # noqa: E731
    for t, rpy in zip(ds.attitude.stamp_s, ds.attitude.rpy_rad):
        q = quat_xyzw_from_R_world_ned_vehicle_frd(rotation_from_rpy(*rpy))  # REP-103: ENU world, FLU body
        msg = T["sensor_msgs/msg/Imu"](
            header=ros_header(store, _ns(t), "base_link"),
            orientation=T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
            orientation_covariance=np.diag(np.asarray(ds.vehicle.attitude.noise_rpy_rad) ** 2).reshape(-1),
            angular_velocity=vec((0, 0, 0)), angular_velocity_covariance=np.r_[-1.0, np.zeros(8)],
            linear_acceleration=vec((0, 0, 0)), linear_acceleration_covariance=np.r_[-1.0, np.zeros(8)])
        out.append((_ns(t), 0, "/semslam/imu", "sensor_msgs/msg/Imu", msg))
    d = ds.dvl
    nb = len(ds.vehicle.dvl.beam_azimuth_rad)
    for k, t in enumerate(d.stamp_s):
        r = d.beam_range_m[k] if d.beam_range_m is not None else np.full(nb, np.nan)
        if len(r) != 4:
            raise DatasetError(f"semslam's vendor DVL message has 4 beams. Got {len(r)} beam ranges instead.")
        valid = np.isfinite(r) & bool(d.valid[k])
        if d.valid[k] and not valid.any():
            valid[:] = True  # a valid velocity without range data: mark the beams locked, ranges unknown
        msg = T[DVL_TYPE](header=ros_header(store, _ns(t), "dvl"), velocity=vec(d.velocity_body_mps[k]),
                          beam_ranges_m=np.asarray(r, dtype=np.float64), beam_valid=valid,
                          figure_of_merit=float(ds.vehicle.dvl.noise_abs_mps))
        out.append((_ns(t), 1, "/semslam/dvl", DVL_TYPE, msg))
    dep = ds.vehicle.depth
    for t, z in zip(ds.depth.stamp_s, ds.depth.depth_m):
        p = dep.atmospheric_pressure_pa + dep.water_density_kg_m3 * _G * float(z)
        msg = T["sensor_msgs/msg/FluidPressure"](header=ros_header(store, _ns(t), "pressure"), fluid_pressure=p,
                                                 variance=(dep.water_density_kg_m3 * _G * dep.noise_m) ** 2)
        out.append((_ns(t), 2, "/semslam/pressure", "sensor_msgs/msg/FluidPressure", msg))
    out += _fix_messages(ds, store, T)

    def scan_messages():
        for rec, cloud in (((r, ds.load_scan(r.scan_id)) for r in ds.scans) if scans is None else scans):
            stamps = ds.point_stamps_s(rec, cloud)
            start_ns = _ns(rec.start_stamp_s)
            offs = (stamps - (start_ns - TIME_ORIGIN_NS) / 1e9) if stamps is not None else np.zeros(cloud.n_points)
            msg = encode_pointcloud2(cloud.points_xyz_m, intensity=cloud.intensity, time_offset_s=offs,
                                     time_field="t", time_encoding="float64_s", frame_id="scanner", stamp_ns=start_ns,
                                     typestore=store)
            # recorded when a driver publishes it, after its last point (the header keeps the first point's stamp,
            # as Velodyne / Ouster drivers do): a replay delivers the scan when a live vehicle would
            yield _ns(rec.end_stamp_s), 3, "/semslam/scans", "sensor_msgs/msg/PointCloud2", msg
    # the scanner's mounting as a vehicle's URDF publishes it: base_link (FLU) -> scanner, once, on /tf_static
    from ..geometry import RigidTransform, quat_wxyz_from_rotation
    from ..io.ros import C_FRD_FLU

    T_flu = RigidTransform.from_rotation_translation(C_FRD_FLU.T, (0.0, 0.0, 0.0)) @ ds.vehicle.T_vehicle_scanner
    w, x, y, z = (float(v) for v in quat_wxyz_from_rotation(T_flu.rotation))
    t0 = _ns(min([float(ds.attitude.stamp_s[0])] if len(ds.attitude) else [0.0]))
    tr = T_flu.translation_m
    tf = T["geometry_msgs/msg/TransformStamped"](
        header=ros_header(store, t0, "base_link"), child_frame_id="scanner",
        transform=T["geometry_msgs/msg/Transform"](translation=vec(tr),
                                                   rotation=T["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)))
    out.append((t0, -1, "/tf_static", "tf2_msgs/msg/TFMessage", T["tf2_msgs/msg/TFMessage"](transforms=[tf])))
    out.sort(key=lambda m: (m[0], m[1]))
    merged = heapq.merge(out, scan_messages(), key=lambda m: (m[0], m[1]))  # stable: the order of one sort
    return ((ns, topic, mt, msg) for ns, _, topic, mt, msg in merged)


def _fix_messages(ds: Dataset, store, T) -> list:
    """Position fixes as ``sensor_msgs/NavSatFix`` (covariance ENU, REP-103), GPS on /semslam/gps, USBL on
    /semslam/usbl, geodetic about the dataset's origin."""
    from ..geodesy import GeodeticOrigin
    from ..io.ros._encode import ros_header

    f = ds.fixes
    if f is None or not len(f):
        return []
    geo = ds.geodetic_origin or GeodeticOrigin(0.0, 0.0, 0.0)
    out = []
    llh = geo.geodetic_deg_from_ned(np.c_[f.position_ne_m, np.zeros(len(f))])
    for k, t in enumerate(f.stamp_s):
        c = f.covariance_ne_m2[k]
        enu = np.array([[c[1, 1], c[1, 0], 0.0], [c[0, 1], c[0, 0], 0.0], [0.0, 0.0, max(c[0, 0], c[1, 1])]])
        src = f.source[k]
        msg = T["sensor_msgs/msg/NavSatFix"](
            header=ros_header(store, _ns(t), src), status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
            latitude=float(llh[k, 0]), longitude=float(llh[k, 1]), altitude=float(llh[k, 2]),
            position_covariance=enu.reshape(-1), position_covariance_type=3)
        out.append((_ns(t), 2, f"/semslam/{src}", "sensor_msgs/msg/NavSatFix", msg))
    return out


def write_bag(dataset: Dataset, path: str | os.PathLike, fmt: str = "ros2-mcap", *, overwrite: bool = False,
              scans=None) -> Path:
    """Write ``dataset`` as a bag (see the module docstring); atomic (a staging sibling, renamed at the end). An
    existing bag is replaced only with ``overwrite``; a bag directory (ROS 2) only when semslam's ownership marker
    proves it wrote it (:mod:`semslam._outdir`). Scans are encoded and written one at a time: from ``scans``
    (``(record, cloud)`` in time order, e.g. :func:`semslam.simulation.simulate_scans` for a dive too long to hold
    in memory) when given, else the dataset's own."""
    from rosbags.typesys import get_types_from_msg

    from ..io.ros._encode import default_typestore

    if fmt not in FORMATS:
        raise DatasetError(f"The 'fmt' argument of write_bag must be one of {FORMATS}. Got {fmt!r} instead.")
    out = Path(path)
    ros1 = fmt == "ros1"
    # only with overwrite, and a bag directory only when semslam's marker proves it wrote it (semslam._outdir)
    if (out.exists() or out.is_symlink()) and not overwrite:
        raise DatasetError(f"The bag {str(out)!r} exists: choose another path, or overwrite it.")
    inputs = (dataset.directory,)
    (check_output_file(out, overwrite=overwrite, option="path", inputs=inputs) if ros1 else
     check_output_dir(out, overwrite=overwrite, kind="bag", option="path", inputs=inputs))
    store = default_typestore(ros1=ros1)
    store.register(get_types_from_msg(DVL_MSG, DVL_TYPE))
    if "tf2_msgs/msg/TFMessage" not in store.types:  # rosbags' ROS 1 Noetic store lacks it
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    msgs = _messages(dataset, store, store.types, scans)
    if ros1:
        from rosbags.rosbag1 import Writer

        with staged_output_file(out, overwrite=overwrite, option="path", inputs=inputs) as tmp, Writer(tmp) as writer:
            conns = {}
            for ns, topic, mt, msg in msgs:
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, mt, typestore=store)
                writer.write(conns[topic], ns, store.serialize_ros1(msg, mt))
        return out
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = StoragePlugin.MCAP if fmt == "ros2-mcap" else StoragePlugin.SQLITE3
    with staged_output_dir(out, overwrite=overwrite, kind="bag", option="path", inputs=inputs) as stage:
        inner = stage / out.name  # rosbags names the storage file after its directory: NAME.mcap / NAME.db3
        with Writer(inner, version=9, storage_plugin=plugin) as writer:
            conns = {}
            for ns, topic, mt, msg in msgs:
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, mt, typestore=store)
                writer.write(conns[topic], ns, store.serialize_cdr(msg, mt))
        for f in list(inner.iterdir()):
            os.replace(f, stage / f.name)
        inner.rmdir()
    return out
