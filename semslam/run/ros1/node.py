"""The ROS 1 node ``semslam``: live topics in, the SLAM estimate out (the only module that imports rospy).

Inputs: the topic map's topics, subscribed with ``rospy.AnyMsg`` and decoded from their serialized bytes by
:class:`~semslam.run.ros1.decode.LiveDecoder` (rosbags, the bag reader's decoders). Outputs (frames: REP-105,
``map`` ENU and ``base_link`` FLU; see :mod:`semslam.run.ros1.convert` and docs/ros1.md):

* ``/semslam/odometry`` ``nav_msgs/Odometry`` (pose and twist covariances): the filter's state predicted to each
  attitude sample as it arrives (low latency), and the TF ``map -> base_link`` on ``/tf``;
* ``/semslam/odometry/filtered``: the runner's estimate (behind the newest message by the reorder window, the
  runner's delay line and any hold behind a scan in recognition; what ``semslam run`` computes);
* ``/semslam/path`` ``nav_msgs/Path`` (a pose every ``path_period_s`` of message time);
* ``/semslam/landmarks`` ``visualization_msgs/MarkerArray`` (per landmark an ellipsoid and a text, updated in place);
* ``/semslam/detections`` ``semslam_msgs/DetectionArray`` (packaged definition, published raw: see
  :mod:`semslam.run.ros1.detections_msg`): every recognised scan's detections, poses in the scanner frame;
* ``/diagnostics`` ``diagnostic_msgs/DiagnosticArray``: the run's health verdict (:mod:`semslam.run.health`),
  message counts, drops, queue, latencies, silent topics.

All wiring to semslam's SLAM and recognition is in :class:`~semslam.run.ros1.live.LiveSlam`, which feeds the one
streaming runner (:class:`semslam.run.runner.Runner`) of ``semslam run``; at shutdown the run directory is written
by :func:`semslam.run.dive.write_outcome`, the same layout as ``semslam run``.
"""

from __future__ import annotations

import math
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...dataset.rosbag import TopicMap
from ...dataset.vehicle import VehicleDescription
from ...errors import BagError, SemslamError
from .bridge import RosUnavailableError, ensure_rospy
from .convert import landmark_markers, odometry_spec
from .decode import LiveDecoder
from .live import LiveSlam, live_health

__all__ = ["LiveDive", "NodeSummary", "run_node"]


@dataclass
class NodeSummary:
    """What a node run gives back: the runner's :class:`~semslam.run.runner.RunOutcome` (None if no attitude
    came), the published mode's result, counters, the run directory's payload and path."""

    outcome: Any
    result: Any
    stats: dict
    out_dir: Path | None = None
    errors: list[str] = field(default_factory=list)
    payload: dict | None = None


@dataclass
class LiveDive:
    """What :func:`semslam.run.dive.write_outcome` needs of a dive, for a live one: the vehicle, provenance
    (``metadata``: the source, the topic map, ``time_origin_ns``) and the world frame's geodetic origin."""

    vehicle: VehicleDescription
    metadata: dict
    geodetic_origin: Any = None
    kind: str = "ros1"


def _load_db(db: Any):
    from ...recognition import ViewDatabase, load_database

    if isinstance(db, ViewDatabase):
        return db
    if isinstance(db, (str, os.PathLike)):
        return load_database(db)
    raise SemslamError(f"The 'db' argument of run_node must be a database path (.npz) or a ViewDatabase. Got "
                       f"{type(db).__name__} instead.")


def _percentiles(values: list[float]) -> tuple[float, float]:
    if not values:
        return float("nan"), float("nan")
    a = np.asarray(values, dtype=float)
    return float(np.percentile(a, 50)), float(np.percentile(a, 90))


class _Node:
    """Publishers, subscribers and the diagnostics of one node run (rospy imported by :func:`run_node`)."""

    def __init__(self, rospy, live: LiveSlam, decoder: LiveDecoder, *, map_frame: str, base_frame: str,
                 path_period_s: float, silent_after_s: float, keep_newest_scan: bool = True) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import Odometry, Path as PathMsg
        from tf2_msgs.msg import TFMessage
        from visualization_msgs.msg import MarkerArray

        self.rospy, self.live, self.decoder = rospy, live, decoder
        self.map_frame, self.base_frame = map_frame, base_frame
        self.path_period_s, self.silent_after_s = path_period_s, silent_after_s
        self.pub_odom = rospy.Publisher("/semslam/odometry", Odometry, queue_size=50)
        self.pub_filtered = rospy.Publisher("/semslam/odometry/filtered", Odometry, queue_size=50)
        self._arrival_wall: float | None = None
        self.pub_tf = rospy.Publisher("/tf", TFMessage, queue_size=50)
        self.pub_path = rospy.Publisher("/semslam/path", PathMsg, queue_size=2, latch=True)
        self.pub_markers = rospy.Publisher("/semslam/landmarks", MarkerArray, queue_size=5, latch=True)
        self.pub_diag = rospy.Publisher("/diagnostics", DiagnosticArray, queue_size=5)
        from .detections_msg import detection_array_spec

        self.pub_detections = rospy.Publisher("/semslam/detections", _raw_message_class(*detection_array_spec()),
                                              queue_size=10)
        self.scan_frame = "scanner"
        self._detections_seq = 0
        from .detections_msg import detection_array_bytes

        detection_array_bytes(0, "", 0, [])  # builds rosbags' message classes now, not on the first scan
        self.origin_ns: int | None = None
        self.fatal: list[str] = []
        self.errors: list[str] = []
        self.last_msg_wall: dict[str, float] = {}
        self.started_wall = time.monotonic()
        self.path = PathMsg()
        self.path.header.frame_id = map_frame
        self._last_path_s = -math.inf
        self.nav_latency_s: list[float] = []
        self._landmarks_sig: tuple = ()
        self._inbox: list = []
        self.keep_newest_scan = keep_newest_scan
        self.scans_dropped_inbox = 0
        self._inbox_cond = threading.Condition()
        self._stopping = False
        self._dispatcher = threading.Thread(target=self._dispatch, name="semslam-dispatch", daemon=True)
        self._dispatcher.start()
        # rospy's own queues: a few scans (each may be megabytes), many navigation messages
        self.subs = [rospy.Subscriber(t, rospy.AnyMsg, self._callback, callback_args=t,
                                      queue_size=4 if decoder.kinds[t] == "scans" else 1000, buff_size=1 << 26)
                     for t in decoder.topics]

    # -- input
    def _callback(self, msg, topic: str) -> None:
        wall = time.monotonic()
        self.last_msg_wall[topic] = wall
        hdr = getattr(msg, "_connection_header", None) or {}
        try:
            now = self.rospy.get_rostime()
            dec = self.decoder.decode(topic, hdr.get("type", ""), msg._buff, md5sum=hdr.get("md5sum", ""),
                                      definition=hdr.get("message_definition", ""),
                                      receive_ns=int(now.secs) * 1_000_000_000 + int(now.nsecs))
        except BagError as err:
            if "must have type" in str(err) or "not a ROS 1 Noetic type" in str(err):
                self.fatal.append(str(err))
                self.rospy.signal_shutdown(str(err))
            elif len(self.errors) < 100:
                self.errors.append(str(err))
            return
        if dec is None:
            return
        # the callback never waits for the filter's lock (held while a scan's detections and the navigation held
        # behind it are fed): the dispatcher thread gives the messages to LiveSlam in arrival order
        with self._inbox_cond:
            if self.origin_ns is None:  # the whole second before the first message, as the bag reader takes it
                self.origin_ns = dec.stamp_ns - dec.stamp_ns % 1_000_000_000
            if dec.kind == "scan" and getattr(dec.payload, "frame_id", ""):
                self.scan_frame = dec.payload.frame_id
            if dec.kind == "scan" and self.keep_newest_scan:
                # bounded memory when the filter falls behind: at most one scan waits here (the newest), as in
                # the recognition queue; the older one is dropped and counted
                waiting = [i for i, m in enumerate(self._inbox) if m[1] == "scan"]
                for i in reversed(waiting):
                    del self._inbox[i]
                    self.scans_dropped_inbox += 1
            self._inbox.append(((dec.stamp_ns - self.origin_ns) / 1e9, dec.kind, dec.payload, wall))
            self._inbox_cond.notify()

    def _dispatch(self) -> None:
        while True:
            with self._inbox_cond:
                self._inbox_cond.wait_for(lambda: self._inbox or self._stopping)
                if not self._inbox:
                    return
                batch, self._inbox = self._inbox, []
            for t, kind, payload, wall in batch:
                self._arrival_wall = wall
                try:
                    self.live.add(t, kind, payload, wall)
                except Exception as err:  # noqa: BLE001 - one bad message must not leave the node deaf: counted
                    if len(self.errors) < 100:
                        self.errors.append(f"{kind} at {t:.3f} s: {type(err).__name__}: {err}")

    def stop_dispatch(self) -> None:
        """Give LiveSlam what the callbacks queued, then stop the dispatcher."""
        with self._inbox_cond:
            self._stopping = True
            self._inbox_cond.notify()
        self._dispatcher.join(60.0)

    # -- output
    def _stamp(self, t_s: float):
        ns = int(self.origin_ns or 0) + int(round(t_s * 1e9))
        return self.rospy.Time(ns // 1_000_000_000, ns % 1_000_000_000)

    def _odometry_msg(self, o):
        from nav_msgs.msg import Odometry

        m = Odometry()
        m.header.stamp, m.header.frame_id, m.child_frame_id = self._stamp(o.stamp_s), self.map_frame, self.base_frame
        p, q = m.pose.pose.position, m.pose.pose.orientation
        p.x, p.y, p.z = (float(v) for v in o.position_enu_m)
        q.x, q.y, q.z, q.w = (float(v) for v in o.quat_xyzw)
        m.pose.covariance = [float(v) for v in o.pose_covariance_6x6.reshape(-1)]
        lin = m.twist.twist.linear
        lin.x, lin.y, lin.z = (float(v) for v in o.velocity_flu_mps)
        m.twist.covariance = [float(v) for v in o.twist_covariance_6x6.reshape(-1)]
        return m

    def on_detections(self, job, result, latency_s: float) -> None:
        """A recognised scan's detections (all of them, reliable or not): /semslam/detections (worker thread)."""
        from .detections_msg import detection_array_bytes

        ns = int(self.origin_ns or 0) + int(round(job.end_s * 1e9))
        self._detections_seq += 1
        raw = detection_array_bytes(ns, self.scan_frame, job.scan_id, result.detections, seq=self._detections_seq)
        try:
            self.pub_detections.publish(self.pub_detections.data_class(raw))
        except self.rospy.ROSException:  # shutting down
            pass

    def on_estimate(self, live: LiveSlam) -> None:
        """The runner's estimate (lags the newest message by the reorder window, the runner's delay line and any hold
        behind a scan in recognition): /semslam/odometry/filtered."""
        s = live.session
        if s is None or s.ekf is None:
            return
        rpy, att_cov = live.attitude_now()
        ekf = s.ekf
        o = odometry_spec(s.t, ekf.position_ned_m, ekf.position_cov_m2, rpy, att_cov, ekf.velocity_body_mps,
                          ekf.velocity_cov)
        try:
            self.pub_filtered.publish(self._odometry_msg(o))
        except self.rospy.ROSException:  # shutting down
            pass

    def on_prediction(self, live: LiveSlam, pr) -> None:
        """The filter's state predicted to the newest attitude sample: /semslam/odometry, /tf, /semslam/path."""
        from geometry_msgs.msg import PoseStamped, TransformStamped
        from tf2_msgs.msg import TFMessage

        o = odometry_spec(pr.stamp_s, pr.position_ned_m, pr.position_cov_m2, pr.rpy_rad, pr.attitude_cov_world_rad2,
                          pr.velocity_body_mps, pr.velocity_cov)
        m = self._odometry_msg(o)
        tf = TransformStamped()
        tf.header.stamp, tf.header.frame_id, tf.child_frame_id = m.header.stamp, self.map_frame, self.base_frame
        p, q = m.pose.pose.position, m.pose.pose.orientation
        tr, rot = tf.transform.translation, tf.transform.rotation
        tr.x, tr.y, tr.z = p.x, p.y, p.z
        rot.x, rot.y, rot.z, rot.w = q.x, q.y, q.z, q.w
        try:
            self.pub_odom.publish(m)
            self.pub_tf.publish(TFMessage(transforms=[tf]))
            if self._arrival_wall is not None:
                self.nav_latency_s.append(time.monotonic() - self._arrival_wall)
                if len(self.nav_latency_s) > 2000:
                    del self.nav_latency_s[:1000]
            if o.stamp_s - self._last_path_s >= self.path_period_s:
                self._last_path_s = o.stamp_s
                ps = PoseStamped()
                ps.header = m.header
                ps.pose = m.pose.pose
                self.path.poses.append(ps)
                if len(self.path.poses) > 20000:  # bounded: every other pose of the older half
                    self.path.poses = self.path.poses[:10000:2] + self.path.poses[10000:]
                self.path.header.stamp = m.header.stamp
                self.pub_path.publish(self.path)
        except self.rospy.ROSException:  # shutting down
            pass

    def publish_landmarks(self, force: bool = False) -> None:
        from visualization_msgs.msg import Marker, MarkerArray

        est = self.live.estimate()
        if est is None:
            return
        specs = landmark_markers(est.landmarks)
        sig = tuple((lm.landmark_id, lm.n_updates) for lm in est.landmarks)
        if sig == self._landmarks_sig and not force:
            return
        self._landmarks_sig = sig
        stamp = self._stamp(est.stamp_s)
        arr = MarkerArray()
        for sp in specs:
            mk = Marker()
            mk.header.stamp, mk.header.frame_id = stamp, self.map_frame
            mk.ns, mk.id, mk.type, mk.action, mk.text = sp.ns, sp.id, sp.type, sp.action, sp.text
            mk.pose.position.x, mk.pose.position.y, mk.pose.position.z = (float(v) for v in sp.position_enu_m)
            q = mk.pose.orientation
            q.x, q.y, q.z, q.w = (float(v) for v in sp.quat_xyzw)
            mk.scale.x, mk.scale.y, mk.scale.z = (float(v) for v in sp.scale)
            mk.color.r, mk.color.g, mk.color.b, mk.color.a = sp.rgba
            arr.markers.append(mk)
        try:
            self.pub_markers.publish(arr)
        except self.rospy.ROSException:
            pass

    def diagnostics(self) -> tuple[int, str, dict]:
        """(level, message, key/values): OK (0) / WARN (1) / ERROR (2)."""
        live = self.live
        now = time.monotonic()
        with live.lock:
            st = dict(live.stats)
            q = live.queue_state()
            late = live.dropped_late
            started = live.session is not None
            verdict = live_health(live) if started else None
        silent = [t for t in self.decoder.topics
                  if now - self.last_msg_wall.get(t, self.started_wall) > self.silent_after_s]
        p50, p90 = _percentiles(st["scan_latency_s"])
        n50, n90 = _percentiles(self.nav_latency_s)
        kv = {"started": started, "messages": st["messages"], "dropped_late": late,
              "scans_recognised": st["scans_recognised"],
              "scans_dropped": st["scans_dropped"] + self.scans_dropped_inbox,
              "scans_late": st["scans_late"], "detections_late": late.get("detections", 0),
              "recognition_errors": st["recognition_errors"], "navigation_errors": st["navigation_errors"],
              "scan_latency_p50_ms": 1e3 * p50, "scan_latency_p90_ms": 1e3 * p90,
              "navigation_latency_p50_ms": 1e3 * n50, "navigation_latency_p90_ms": 1e3 * n90,
              **q, "silent_topics": silent, "decode_errors": len(self.errors),
              "verdict": verdict.level if verdict is not None else "not started",
              "health": verdict.as_dict()["checks"] if verdict is not None else []}
        if self.fatal:
            return 2, self.fatal[-1], kv
        problems = []
        if verdict is not None and verdict.level == "bad":
            return 2, "; ".join(verdict.lines()), kv
        if verdict is not None:
            problems += verdict.lines()
        if silent:
            problems.append(f"no message for {self.silent_after_s:g} s on {', '.join(silent)}")
        nav_late = sum(v for k, v in late.items() if k not in ("scan", "detections"))
        if nav_late or st["navigation_errors"]:
            problems.append(f"{nav_late + st['navigation_errors']} navigation message(s) dropped")
        if st["recognition_errors"]:
            problems.append(f"{st['recognition_errors']} scan(s) failed recognition")
        if problems:
            return 1, "; ".join(problems), kv
        return 0, "OK", kv

    def publish_diagnostics(self) -> None:
        import json

        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        level, text, kv = self.diagnostics()
        arr = DiagnosticArray()
        arr.header.stamp = self.rospy.get_rostime()
        status = DiagnosticStatus(level=level, name="semslam: SLAM", message=text, hardware_id="semslam")
        status.values = [KeyValue(key=k, value=v if isinstance(v, str) else json.dumps(v)) for k, v in kv.items()]
        arr.status = [status]
        try:
            self.pub_diag.publish(arr)
        except self.rospy.ROSException:
            pass

    def check_topic_types(self) -> None:
        """A mapped topic already advertised by someone with a type the topic map's sensor does not accept:
        fatal, naming the topic (before any message comes)."""
        try:
            published = dict(self.rospy.get_published_topics())
        except Exception:  # noqa: BLE001 - the master is going away: the main loop notices
            return
        for topic in self.decoder.topics:
            if topic in published and published[topic] not in ("*", ""):
                try:
                    self.decoder.check_type(topic, published[topic])
                except BagError as err:
                    if "must have type" in str(err):
                        self.fatal.append(str(err))
                        self.rospy.signal_shutdown(str(err))


def _check_advertised_types(rosgraph, decoder: LiveDecoder) -> None:
    """:class:`BagError` naming a mapped topic that someone already publishes with a type its sensor does not
    accept (the master's topic types)."""
    try:
        types = dict(rosgraph.Master("/semslam").getTopicTypes())
    except Exception:  # noqa: BLE001 - the master went away: run_node's loop notices
        return
    for topic in decoder.topics:
        if types.get(topic) not in (None, "*", ""):
            decoder.check_type(topic, types[topic])


def run_node(db: Any, topic_map: TopicMap, vehicle: VehicleDescription, *, mode: str = "pose", modes=None,
             out_dir: str | os.PathLike | None = None, overwrite: bool = False, config: Any = None,
             pipeline_config: Any = None, backend: str = "ekf", prior_map: Any = None, seed: int = 0,
             keep_unreliable: bool = False, up_from_attitude: bool = False, node_name: str = "semslam",
             map_frame: str = "map", base_frame: str = "base_link", reorder_window_s: float = 0.5,
             max_hold_s: float = 5.0, silent_after_s: float = 5.0, diagnostics_period_s: float = 1.0,
             path_period_s: float = 0.5, scan_queue: str = "newest", resolved_config: Any = None,
             ready: threading.Event | None = None) -> NodeSummary:
    """Run the ``semslam`` node until rospy shuts down (SIGINT, ``rosnode kill``); then finish the runner and,
    with ``out_dir``, write the run directory as ``semslam run`` does (:func:`semslam.run.dive.write_outcome`:
    run.json, detections.jsonl, slam/<mode>/ with trajectories, map, run.mcap; plus ros_node.json, the node's
    counters and wall-clock latencies).

    Parameters
    ----------
    db : path or ViewDatabase
        The view database (``semslam db build``).
    topic_map : TopicMap
        Which topic is which sensor (scans, attitude, DVL, depth, gps/usbl fixes), their frames and the world
        frame's geodetic ``[origin]`` (else a prior map's, else the first usable fix), as for bags.
    vehicle : VehicleDescription
        Mounting and noise figures (``T_vehicle_scanner`` included).
    mode : {"dr", "position", "pose", "pose+heading"}
        The published mode. ``modes``: every mode run in the one pass (default ``(mode,)``).
    out_dir : path, optional
        Run directory written at shutdown (built beside and swapped in; ``overwrite`` replaces an earlier run).
    config, pipeline_config, backend, seed, keep_unreliable, up_from_attitude
        As ``semslam run`` (:class:`~semslam.run.runner.Runner`).
    prior_map : Survey or path, optional
        Landmarks known before the dive: an earlier run's ``map.json`` or a survey CSV
        (:func:`semslam.slam.survey.read_survey`), in the world frame of this dive.
    reorder_window_s, max_hold_s : float, scan_queue : {"newest", "all"}
        See :class:`~semslam.run.ros1.live.LiveSlam`.
    silent_after_s : float
        A mapped topic without a message for this long (wall time) is reported in the diagnostics.
    resolved_config : RunConfig, optional
        Written to ``RUN/config.toml`` (the CLI's resolved settings).
    ready : threading.Event, optional
        Set once subscribed and publishing (tests, benchmarks).

    Raises
    ------
    RosUnavailableError
        rospy is not installed, or no ROS master answers at ``ROS_MASTER_URI``.
    BagError
        A mapped topic has a type its sensor does not accept, naming the topic: at once when the master already
        knows the topic's type, else when its first message comes (then after shutdown).
    """
    if not isinstance(topic_map, TopicMap):
        raise SemslamError(f"The 'topic_map' argument of run_node must be a TopicMap. Got {type(topic_map).__name__}.")
    if not isinstance(vehicle, VehicleDescription):
        raise SemslamError(f"The 'vehicle' argument of run_node must be a VehicleDescription. Got "
                           f"{type(vehicle).__name__}.")
    decoder = LiveDecoder(topic_map, vehicle)
    survey, origin, origin_from = _prior_map(prior_map, topic_map)
    ensure_rospy()
    import rosgraph
    import rospy

    uri = os.environ.get("ROS_MASTER_URI", "http://localhost:11311")
    if not rosgraph.is_master_online():
        raise RosUnavailableError(f"No ROS master answers at ROS_MASTER_URI={uri}: start roscore (or set "
                                  "ROS_MASTER_URI).")
    _check_advertised_types(rosgraph, decoder)  # fail fast, before the database is loaded
    from ...pipeline import ScanRecognizer

    database = _load_db(db)
    run_modes = (mode,) if modes is None else tuple(modes)
    recognizer = None
    if topic_map.scans is not None and any(m != "dr" for m in run_modes):
        recognizer = ScanRecognizer(database, pipeline_config, seed=seed)
        recognizer.warm_up()
    from threadpoolctl import threadpool_limits

    # one BLAS thread for the node's life (the filter's matrices are small; recognition and the filter share two
    # cores with the vehicle's other processes), set once: never toggled while the other thread is inside BLAS
    blas_limit = threadpool_limits(limits=1, user_api="blas")
    box: dict[str, _Node] = {}
    live = LiveSlam(vehicle, recognizer, mode=mode, modes=run_modes, config=config, symmetries=database.symmetries(),
                    backend=backend, survey=survey, seed=seed, keep_unreliable=keep_unreliable,
                    up_from_attitude=up_from_attitude, geodetic_origin=origin,
                    reorder_window_s=reorder_window_s, max_hold_s=max_hold_s, scan_queue=scan_queue,
                    on_estimate=lambda lv: box["node"].on_estimate(lv) if "node" in box else None,
                    on_prediction=lambda lv, pr: box["node"].on_prediction(lv, pr) if "node" in box else None,
                    on_detections=lambda job, res, lat: box["node"].on_detections(job, res, lat)
                    if "node" in box else None)
    if origin_from is not None:
        live.geodetic_origin_from = origin_from
    live.warm_up()  # before subscribing: the filter's first start must not stall the odometry
    main_thread = threading.current_thread() is threading.main_thread()
    rospy.init_node(node_name, anonymous=False, disable_signals=not main_thread)
    node = _Node(rospy, live, decoder, map_frame=map_frame, base_frame=base_frame, path_period_s=path_period_s,
                 silent_after_s=silent_after_s, keep_newest_scan=scan_queue == "newest")
    box["node"] = node
    if ready is not None:
        ready.set()
    next_diag = time.monotonic()
    try:
        while not rospy.is_shutdown():
            time.sleep(0.05)
            if time.monotonic() >= next_diag:
                next_diag += diagnostics_period_s
                node.check_topic_types()
                node.publish_landmarks()
                node.publish_diagnostics()
    except KeyboardInterrupt:  # disable_signals: the caller's Ctrl-C
        rospy.signal_shutdown("KeyboardInterrupt")
    for sub in node.subs:
        sub.unregister()
    node.stop_dispatch()
    outcome = live.close()
    blas_limit.restore_original_limits()
    live.stats["scans_dropped"] += node.scans_dropped_inbox
    stats = dict(live.stats, dropped_late=live.dropped_late, navigation_latency_s=list(node.nav_latency_s))
    if node.fatal:
        raise BagError(node.fatal[0])
    written, payload = None, None
    if out_dir is not None and outcome is not None:
        geo = live.geodetic_origin
        meta = {"source": {"kind": "ros1", "node": node_name, "master": uri, "topics": "given", "vehicle": "given",
                           "prior_map": None if survey is None else survey.source},
                "topics": topic_map.to_toml(), "time_origin_ns": int(node.origin_ns or 0)}
        if geo is not None:
            meta["geodetic_origin_from"] = live.geodetic_origin_from
        dive = LiveDive(vehicle, meta, geo)
        written, payload = _write_run(Path(out_dir), outcome, live, dive, overwrite, node, recognizer, seed,
                                      resolved_config)
    result = None if outcome is None else outcome.results.get(mode)
    return NodeSummary(outcome, result, stats, written, list(node.errors), payload)


def _prior_map(prior_map: Any, topic_map: TopicMap):
    """``(survey, geodetic origin, where it came from)``: the topic map's ``[origin]``, else the prior map's (a map
    placed about a geodetic origin defines the world frame), checked against each other."""
    from ...geodesy import GeodeticOrigin

    origin = GeodeticOrigin.from_dict(topic_map.origin) if topic_map.origin is not None else None
    origin_from = "the topic map" if origin is not None else None
    if prior_map is None:
        return None, origin, origin_from
    from ...slam.survey import Survey, check_survey_frame, read_survey

    survey = prior_map if isinstance(prior_map, Survey) else read_survey(prior_map)
    if origin is None and survey.geodetic_origin is not None:
        origin = GeodeticOrigin.from_dict(survey.geodetic_origin)
        origin_from = f"the prior map {survey.source}"
    check_survey_frame(survey, origin)
    return survey, origin, origin_from


def _write_run(out: Path, outcome: Any, live: LiveSlam, dive: LiveDive, overwrite: bool, node: "_Node",
               recognizer: Any, seed: int, resolved_config: Any) -> tuple[Path, dict]:
    """The run directory of ``semslam run`` (:func:`semslam.run.dive.write_outcome`; no mission copy: the scans
    were not stored) plus ``ros_node.json``: the node's counters and wall-clock latencies (kept out of run.json,
    whose content must not depend on the machine)."""
    import json

    from ..._outdir import staged_output_dir
    from ..dive import write_outcome

    with staged_output_dir(out, overwrite=overwrite) as tmp:
        payload = write_outcome(outcome, tmp, dive=dive, pipeline_config=None if recognizer is None else
                                recognizer.config, seed=seed)
        if resolved_config is not None:
            from ..config import write_resolved_config

            write_resolved_config(resolved_config, tmp)
        stats = {k: v for k, v in live.stats.items() if k != "scan_latency_s"}
        s50, s90 = _percentiles(live.stats["scan_latency_s"])
        n50, n90 = _percentiles(node.nav_latency_s)
        latency = {"scan_to_detections_p50_ms": 1e3 * s50, "scan_to_detections_p90_ms": 1e3 * s90,
                   "navigation_to_odometry_p50_ms": 1e3 * n50, "navigation_to_odometry_p90_ms": 1e3 * n90}
        (tmp / "ros_node.json").write_text(json.dumps({"stats": stats, "dropped_late": live.dropped_late,
                                                       "latency": latency,
                                                       "time_origin_ns": int(node.origin_ns or 0)},
                                                      indent=1, default=str))
    return out, payload


def _raw_message_class(ros_type: str, md5sum: str, full_text: str):
    """A rospy message class whose instances carry bytes already serialized (rosbags) for ``ros_type``: what a
    publisher of a type without genmsg-generated Python classes hands rospy."""
    import genpy

    class RawMessage(genpy.Message):
        __slots__ = ["_buff"]
        _type, _md5sum, _full_text, _has_header = ros_type, md5sum, full_text, False
        _slot_types: list = []

        def __init__(self, buff: bytes = b"") -> None:
            self._buff = buff

        def serialize(self, buff) -> None:
            buff.write(self._buff)

        def deserialize(self, data):
            self._buff = bytes(data)
            return self

    return RawMessage


def main(argv: list[str] | None = None) -> int:
    """``python -m semslam.run.ros1.node --db DB --topics T.toml --vehicle V.toml [--mode pose] [--out RUN]
    [--prior-map MAP]``: the node without the CLI (tests, benchmarks; users run ``semslam ros``)."""
    import argparse
    import sys

    from ...dataset import read_vehicle_toml
    from ...dataset.rosbag import read_topic_map

    p = argparse.ArgumentParser(prog="python -m semslam.run.ros1.node")
    p.add_argument("--db", required=True)
    p.add_argument("--topics", required=True)
    p.add_argument("--vehicle", required=True)
    p.add_argument("--mode", default="pose")
    p.add_argument("--out")
    p.add_argument("--prior-map")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-hold", type=float, default=5.0)
    p.add_argument("--window", type=float, default=0.5)
    p.add_argument("--scan-queue", choices=("newest", "all"), default="newest")
    args = p.parse_args(argv)
    try:
        summary = run_node(args.db, read_topic_map(args.topics), read_vehicle_toml(args.vehicle), mode=args.mode,
                           out_dir=args.out, overwrite=args.overwrite, seed=args.seed, max_hold_s=args.max_hold,
                           reorder_window_s=args.window, scan_queue=args.scan_queue, prior_map=args.prior_map)
    except SemslamError as err:
        print(f"semslam: error: {' '.join(str(err).split())}", file=sys.stderr)
        return 1
    print(node_summary_line(summary))
    return 0


def node_summary_line(summary: NodeSummary) -> str:
    st = summary.stats
    verdict = (summary.payload or {}).get("verdict")
    return (f"semslam node: {st['scans_recognised']} scans recognised, {st['scans_dropped']} dropped, "
            f"{st['scans_late']} late" + (f"; verdict {verdict.upper()}" if verdict else "")
            + (f"; run written to {summary.out_dir}" if summary.out_dir else ""))


if __name__ == "__main__":
    raise SystemExit(main())
