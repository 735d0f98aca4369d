"""The ROS 1 node ``semslam``: live topics in, the SLAM estimate out (the only module that imports rospy; its topics,
the ROS messages it publishes and its diagnostics: :mod:`~semslam.run.ros1.node_topics`,
:mod:`~semslam.run.ros1.node_diagnostics`).

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

import os
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ...dataset.rosbag import TopicMap
from ...dataset.vehicle import VehicleDescription
from ...errors import BagError, SemslamError
from .bridge import RosUnavailableError, ensure_rospy
from .decode import LiveDecoder
from .live import LiveSlam
from .node_diagnostics import percentiles
from .node_topics import NodeTopics, check_advertised_types

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
    _check_node_inputs(topic_map, vehicle)
    decoder = LiveDecoder(topic_map, vehicle)
    survey, origin, origin_from = _prior_map(prior_map, topic_map)
    rospy, uri = _connect_to_master(decoder)  # fail fast, before the database is loaded
    database = _load_db(db)
    run_modes = (mode,) if modes is None else tuple(modes)
    recognizer = _warm_recognizer(database, topic_map, run_modes, pipeline_config, seed)
    blas_limit = _one_blas_thread()
    box: dict[str, NodeTopics] = {}
    live = LiveSlam(vehicle, recognizer, mode=mode, modes=run_modes, config=config, symmetries=database.symmetries(),
                    backend=backend, survey=survey, seed=seed, keep_unreliable=keep_unreliable,
                    up_from_attitude=up_from_attitude, geodetic_origin=origin, reorder_window_s=reorder_window_s,
                    max_hold_s=max_hold_s, scan_queue=scan_queue, **_forward_to_node(box))
    if origin_from is not None:
        live.geodetic_origin_from = origin_from
    live.warm_up()  # before subscribing: the filter's first start must not stall the odometry
    node = box["node"] = _open_node(rospy, live, decoder, node_name, map_frame=map_frame, base_frame=base_frame,
                                    path_period_s=path_period_s, silent_after_s=silent_after_s,
                                    keep_newest_scan=scan_queue == "newest")
    if ready is not None:
        ready.set()
    _spin(rospy, node, diagnostics_period_s)
    outcome, stats = _stop(node, live, blas_limit)
    written, payload = None, None
    if out_dir is not None and outcome is not None:
        dive = _live_dive(vehicle, topic_map, live, node, node_name, uri, survey)
        written, payload = _write_run(Path(out_dir), outcome, live, dive, overwrite, node, recognizer, seed,
                                      resolved_config)
    result = None if outcome is None else outcome.results.get(mode)
    return NodeSummary(outcome, result, stats, written, list(node.errors), payload)


def _check_node_inputs(topic_map: Any, vehicle: Any) -> None:
    if not isinstance(topic_map, TopicMap):
        raise SemslamError(f"The 'topic_map' argument of run_node must be a TopicMap. Got {type(topic_map).__name__}.")
    if not isinstance(vehicle, VehicleDescription):
        raise SemslamError(f"The 'vehicle' argument of run_node must be a VehicleDescription. Got "
                           f"{type(vehicle).__name__}.")


def _connect_to_master(decoder: LiveDecoder):
    """``(rospy, ROS_MASTER_URI)`` once a ROS master answers and no mapped topic is already advertised with a type
    its sensor does not accept (:class:`RosUnavailableError`, :class:`BagError`)."""
    ensure_rospy()
    import rosgraph
    import rospy

    uri = os.environ.get("ROS_MASTER_URI", "http://localhost:11311")
    if not rosgraph.is_master_online():
        raise RosUnavailableError(f"No ROS master answers at ROS_MASTER_URI={uri}: start roscore (or set "
                                  "ROS_MASTER_URI).")
    check_advertised_types(rosgraph, decoder)
    return rospy, uri


def _warm_recognizer(database: Any, topic_map: TopicMap, run_modes: tuple, pipeline_config: Any, seed: int):
    """The scan recognizer, warmed up (None without scans or when every mode is dead reckoning)."""
    from ...pipeline import ScanRecognizer

    recognizer = None
    if topic_map.scans is not None and any(m != "dr" for m in run_modes):
        recognizer = ScanRecognizer(database, pipeline_config, seed=seed)
        recognizer.warm_up()
    return recognizer


def _one_blas_thread():
    """One BLAS thread for the node's life (the filter's matrices are small; recognition and the filter share two
    cores with the vehicle's other processes), set once: never toggled while the other thread is inside BLAS.
    Returns the limiter (``restore_original_limits()`` at the end)."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


def _forward_to_node(box: dict) -> dict:
    """LiveSlam's callbacks, forwarded to the node's topics (``box["node"]``) once they exist."""
    return dict(on_estimate=lambda lv: box["node"].on_estimate(lv) if "node" in box else None,
                on_prediction=lambda lv, pr: box["node"].on_prediction(lv, pr) if "node" in box else None,
                on_detections=lambda job, res, lat: box["node"].on_detections(job, res, lat)
                if "node" in box else None)


def _open_node(rospy, live: LiveSlam, decoder: LiveDecoder, node_name: str, **topics_kw) -> NodeTopics:
    """``rospy.init_node`` (signals handled by rospy only on the main thread), then the node's topics."""
    main_thread = threading.current_thread() is threading.main_thread()
    if main_thread:
        # rospy's SIGINT handler shuts the node down (its normal end: the run is then written) and calls the handler
        # it replaced. That one must not take the Ctrl-C for an interrupt of the work: the `semslam` command's own
        # handler would refuse to commit the run directory (semslam._signals). Python's default raises a
        # KeyboardInterrupt, which rospy filters out.
        signal.signal(signal.SIGINT, signal.default_int_handler)
    rospy.init_node(node_name, anonymous=False, disable_signals=not main_thread)
    return NodeTopics(rospy, live, decoder, **topics_kw)


def _spin(rospy, node: NodeTopics, diagnostics_period_s: float) -> None:
    """Until rospy shuts down: every ``diagnostics_period_s`` the advertised types checked, the landmarks and the
    diagnostics published."""
    next_diag = time.monotonic()
    try:
        while not rospy.is_shutdown():
            time.sleep(0.05)
            node.live.poll()  # scans that waited too long for the navigation after their end
            if time.monotonic() >= next_diag:
                next_diag += diagnostics_period_s
                node.check_topic_types()
                node.publish_landmarks()
                node.publish_diagnostics()
    except KeyboardInterrupt:  # disable_signals: the caller's Ctrl-C
        rospy.signal_shutdown("KeyboardInterrupt")


def _stop(node: NodeTopics, live: LiveSlam, blas_limit) -> tuple[Any, dict]:
    """Unsubscribe, give LiveSlam what is queued, finish the runner: ``(outcome, stats)``; :class:`BagError` when a
    mapped topic had a type its sensor does not accept."""
    for sub in node.subs:
        sub.unregister()
    node.stop_dispatch()
    outcome = live.close()
    blas_limit.restore_original_limits()
    live.stats["scans_dropped"] += node.scans_dropped_inbox
    stats = dict(live.stats, dropped_late=live.dropped_late, navigation_latency_s=list(node.nav_latency_s))
    if node.fatal:
        raise BagError(node.fatal[0])
    return outcome, stats


def _live_dive(vehicle: VehicleDescription, topic_map: TopicMap, live: LiveSlam, node: NodeTopics, node_name: str,
               uri: str, survey: Any) -> LiveDive:
    """The dive's provenance for the run directory (:class:`LiveDive`)."""
    geo = live.geodetic_origin
    meta = {"source": {"kind": "ros1", "node": node_name, "master": uri, "topics": "given", "vehicle": "given",
                       "prior_map": None if survey is None else survey.source},
            "topics": topic_map.to_toml(), "time_origin_ns": int(node.origin_ns or 0)}
    if geo is not None:
        meta["geodetic_origin_from"] = live.geodetic_origin_from
    return LiveDive(vehicle, meta, geo)


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


def _write_run(out: Path, outcome: Any, live: LiveSlam, dive: LiveDive, overwrite: bool, node: NodeTopics,
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
        s50, s90 = percentiles(live.stats["scan_latency_s"])
        n50, n90 = percentiles(node.nav_latency_s)
        latency = {"scan_to_detections_p50_ms": 1e3 * s50, "scan_to_detections_p90_ms": 1e3 * s90,
                   "navigation_to_odometry_p50_ms": 1e3 * n50, "navigation_to_odometry_p90_ms": 1e3 * n90}
        (tmp / "ros_node.json").write_text(json.dumps({"stats": stats, "dropped_late": live.dropped_late,
                                                       "latency": latency,
                                                       "time_origin_ns": int(node.origin_ns or 0)},
                                                      indent=1, default=str))
    return out, payload


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
    p.add_argument("--silent-after", type=float, default=5.0, help="seconds without a message before a mapped "
                   "topic is called silent in /diagnostics")
    args = p.parse_args(argv)
    try:
        summary = run_node(args.db, read_topic_map(args.topics), read_vehicle_toml(args.vehicle), mode=args.mode,
                           out_dir=args.out, overwrite=args.overwrite, seed=args.seed, max_hold_s=args.max_hold,
                           reorder_window_s=args.window, scan_queue=args.scan_queue, prior_map=args.prior_map,
                           silent_after_s=args.silent_after)
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
