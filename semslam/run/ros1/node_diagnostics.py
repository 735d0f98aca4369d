"""The ``semslam`` node's ``/diagnostics``: the run's health verdict (:mod:`semslam.run.health`), message counts,
drops, queue, latencies and silent topics (imports rospy's message modules only when publishing)."""

from __future__ import annotations

import time

import numpy as np

from .live_health import live_health

__all__ = ["node_diagnostics", "percentiles", "publish_node_diagnostics"]


def percentiles(values: list[float]) -> tuple[float, float]:
    """The 50th and 90th percentiles of ``values`` (NaN, NaN when empty)."""
    if not values:
        return float("nan"), float("nan")
    a = np.asarray(values, dtype=float)
    return float(np.percentile(a, 50)), float(np.percentile(a, 90))


def node_diagnostics(node) -> tuple[int, str, dict]:
    """The node's diagnostics: (level, message, key/values): OK (0) / WARN (1) / ERROR (2)."""
    live = node.live
    now = time.monotonic()
    with live.lock:
        st = dict(live.stats)
        q = live.queue_state()
        late = live.dropped_late
        started = live.session is not None
        verdict = live_health(live) if started else None
    silent = [t for t in node.decoder.topics
              if now - node.last_msg_wall.get(t, node.started_wall) > node.silent_after_s]
    p50, p90 = percentiles(st["scan_latency_s"])
    n50, n90 = percentiles(node.nav_latency_s)
    kv = {"started": started, "messages": st["messages"], "dropped_late": late,
          "scans_recognised": st["scans_recognised"],
          "scans_dropped": st["scans_dropped"] + node.scans_dropped_inbox,
          "scans_late": st["scans_late"], "detections_late": late.get("detections", 0),
          "tracked_from_scan_after": st["tracked_from_scan_after"],
          "recognition_errors": st["recognition_errors"], "navigation_errors": st["navigation_errors"],
          "scan_latency_p50_ms": 1e3 * p50, "scan_latency_p90_ms": 1e3 * p90,
          "navigation_latency_p50_ms": 1e3 * n50, "navigation_latency_p90_ms": 1e3 * n90,
          **q, "silent_topics": silent, "decode_errors": len(node.errors),
          "verdict": verdict.level if verdict is not None else "not started",
          "health": verdict.as_dict()["checks"] if verdict is not None else []}
    if node.fatal:
        return 2, node.fatal[-1], kv
    problems = []
    if verdict is not None and verdict.level == "bad":
        return 2, "; ".join(verdict.lines()), kv
    if verdict is not None:
        problems += verdict.lines()
    if silent:
        problems.append(f"no message for {node.silent_after_s:g} s on {', '.join(silent)}")
    nav_late = sum(v for k, v in late.items() if k not in ("scan", "detections"))
    if nav_late or st["navigation_errors"]:
        problems.append(f"{nav_late + st['navigation_errors']} navigation message(s) dropped")
    if st["recognition_errors"]:
        problems.append(f"{st['recognition_errors']} scan(s) failed recognition")
    if problems:
        return 1, "; ".join(problems), kv
    return 0, "OK", kv


def publish_node_diagnostics(node) -> None:
    """The diagnostics on ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``)."""
    import json

    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    level, text, kv = node_diagnostics(node)
    arr = DiagnosticArray()
    arr.header.stamp = node.rospy.get_rostime()
    status = DiagnosticStatus(level=level, name="semslam: SLAM", message=text, hardware_id="semslam")
    status.values = [KeyValue(key=k, value=v if isinstance(v, str) else json.dumps(v)) for k, v in kv.items()]
    arr.status = [status]
    try:
        node.pub_diag.publish(arr)
    except node.rospy.ROSException:
        pass
