"""``semslam ros --db DB [--topics T.toml] [--vehicle V.toml] [--config C] [--preset P] [--mode pose]
[--prior-map MAP] [--out RUN]``: the ROS 1 node ``semslam`` (docs/ros1.md), a thin wrapper over
:func:`semslam.run.ros1.node.run_node`. Runs until Ctrl-C; then, with ``--out``, writes the run directory of
``semslam run``. No ROS master: one line, exit 1."""

from __future__ import annotations

import argparse


def register(subparsers, common) -> None:
    from ._inputs import add_config_options

    p = subparsers.add_parser("ros", parents=[common], help="run live as the ROS 1 node 'semslam' (until Ctrl-C)",
                              description="The ROS 1 node 'semslam': subscribes to the topic map's topics, recognises "
                                          "the scans and runs SLAM live (the runner of `semslam run`), publishes "
                                          "/semslam/odometry, /tf, /semslam/path, /semslam/landmarks, "
                                          "/semslam/detections and /diagnostics. See docs/ros1.md.")
    p.add_argument("--db", required=True, metavar="DB", help="view database (.npz), or 'builtin'")
    p.add_argument("--topics", metavar="T.toml", help="topic map (TOML; `semslam bag info BAG` suggests one); default: "
                                                      "semslam's own topics (/semslam/scans, /semslam/imu, ...)")
    p.add_argument("--vehicle", metavar="V.toml", default="girona500",
                   help="vehicle description (TOML, or 'girona500', the default)")
    add_config_options(p)
    p.add_argument("--mode", help="published SLAM mode: dr, position, pose (default) or pose+heading; 'all' runs "
                                  "every mode (pose published)")
    p.add_argument("--prior-map", metavar="MAP", help="landmarks known before the dive: an earlier run's map.json or "
                                                      "a survey CSV, in this dive's world frame")
    p.add_argument("--out", metavar="RUN", help="run directory written at Ctrl-C (new, or an earlier run with "
                                                "--overwrite)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier semslam run in --out")
    p.add_argument("--seed", type=int, help="seed of recognition (default 0, or --config's)")
    p.add_argument("--scan-queue", choices=("newest", "all"), default="newest",
                   help="newest (default): a scan waiting when a newer one comes is dropped, counted; all: every "
                        "scan recognised however late (replays)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..dataset import read_vehicle_toml
    from ..dataset.rosbag import read_topic_map
    from ..dataset.rosbag_write import SEMSLAM_TOPICS
    from ..dataset.vehicle import VehicleDescription
    from ..run.ros1.node import node_summary_line, run_node
    from ._inputs import load_database_arg, run_config_from_args
    from ._output import emit

    rc = run_config_from_args(args, default_modes=("pose",))
    modes = tuple(rc.run.modes)
    mode = "pose" if "pose" in modes else modes[-1]
    tmap = read_topic_map(args.topics) if args.topics else SEMSLAM_TOPICS
    vehicle = VehicleDescription.girona500() if args.vehicle == "girona500" else read_vehicle_toml(args.vehicle)
    db = load_database_arg(args.db) if args.db == "builtin" else args.db  # a file: loaded once the master answers
    summary = run_node(db, tmap, vehicle, mode=mode, modes=modes, out_dir=args.out, overwrite=args.overwrite,
                       config=rc.slam_config(), pipeline_config=rc.pipeline_config(), backend=rc.run.backend,
                       prior_map=args.prior_map, seed=rc.run.seed, keep_unreliable=rc.run.keep_unreliable,
                       up_from_attitude=rc.run.up_from_attitude, scan_queue=args.scan_queue,
                       resolved_config=rc if args.out else None)
    payload = {"stats": {k: v for k, v in summary.stats.items() if not k.endswith("latency_s")},
               "out": None if summary.out_dir is None else str(summary.out_dir), "run": summary.payload,
               "errors": summary.errors}
    emit(args, payload, lambda: node_summary_line(summary))
    return 0
