"""The ``semslam`` node's topics: its publishers and subscribers, the subscribers' callback and the dispatcher thread
that gives the decoded messages to :class:`~semslam.run.ros1.live.LiveSlam`, and the messages it publishes
(odometry, TF, path, landmark markers, detections; the diagnostics: :mod:`semslam.run.ros1.node_diagnostics`).
rospy is handed in by :func:`~semslam.run.ros1.node.run_node`; its message modules are imported here lazily."""

from __future__ import annotations

import math
import threading
import time

from ...errors import BagError
from .convert import landmark_markers, odometry_spec
from .decode import LiveDecoder
from .live import LiveSlam
from .node_diagnostics import node_diagnostics, publish_node_diagnostics

__all__ = ["NodeTopics", "check_advertised_types", "raw_message_class"]


class NodeTopics:
    """Publishers, subscribers and the diagnostics of one node run (rospy imported by
    :func:`~semslam.run.ros1.node.run_node`)."""

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

        self.pub_detections = rospy.Publisher("/semslam/detections", raw_message_class(*detection_array_spec()),
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
        """(level, message, key/values): OK (0) / WARN (1) / ERROR (2) (:func:`node_diagnostics`)."""
        return node_diagnostics(self)

    def publish_diagnostics(self) -> None:
        publish_node_diagnostics(self)

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


def check_advertised_types(rosgraph, decoder: LiveDecoder) -> None:
    """:class:`BagError` naming a mapped topic that someone already publishes with a type its sensor does not
    accept (the master's topic types)."""
    try:
        types = dict(rosgraph.Master("/semslam").getTopicTypes())
    except Exception:  # noqa: BLE001 - the master went away: run_node's loop notices
        return
    for topic in decoder.topics:
        if types.get(topic) not in (None, "*", ""):
            decoder.check_type(topic, types[topic])


def raw_message_class(ros_type: str, md5sum: str, full_text: str):
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
