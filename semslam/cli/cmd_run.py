"""``semslam run BAG|MISSION --db DB --out RUN``: the whole chain on a recorded dive: (a bag converted to
RUN/mission,) every scan recognised (RUN/detections.jsonl), SLAM in every mode (RUN/slam/<mode>/, with the
trajectories as TUM and KITTI, the map as JSON/CSV/PLY and run.mcap for Foxglove/RViz), the report."""

from __future__ import annotations

import argparse


def register(subparsers, common) -> None:
    p = subparsers.add_parser("run", parents=[common], help="detect + SLAM + report on a bag or a mission directory",
                              description="Run the whole chain on a recorded dive (ROS 1/2 bag or mission directory): "
                                          "recognition on every scan, SLAM in every mode (or one), and the report.")
    p.add_argument("dive", metavar="BAG|MISSION")
    p.add_argument("--db", required=True, metavar="DB", help="view database (.npz), or 'builtin'")
    p.add_argument("--out", required=True, metavar="RUN", help="run directory to create (new, or an earlier run with "
                                                                "--overwrite)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier semslam run in --out")
    p.add_argument("--vehicle", help="vehicle description (TOML); for a mission it replaces the dataset's")
    p.add_argument("--topics", help="topic map of a bag (TOML; default: `semslam bag info`'s suggestion)")
    p.add_argument("--msg-dir", action="append", default=[], metavar="DIR", help="message definitions (bags)")
    p.add_argument("--mode", default="all", help="SLAM mode: dr, position, pose, pose+heading or all (default)")
    p.add_argument("--seed", type=int, default=0, help="seed of recognition and SLAM (default 0)")
    p.add_argument("--backend", choices=("ekf", "isam2", "batch"), default="ekf",
                   help="SLAM estimator: the EKF (default), or a GTSAM factor graph: isam2 (online) or batch")
    p.add_argument("--no-report", action="store_true", help="skip report.html")
    p.add_argument("--up-from-attitude", action="store_true",
                   help="pose every scan's objects upright about the up direction of the vehicle's attitude at that "
                        "scan (classes whose database records their up: db build --fuse --up)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .._outdir import staged_output_dir
    from ..errors import InputError
    from ..slam import MODES
    from ._output import emit

    modes = MODES if args.mode == "all" else (args.mode,)
    if any(m not in MODES for m in modes):
        raise InputError(f"The '--mode' option must be one of {MODES} or 'all'. Got {args.mode!r} instead.")
    final = Path(args.out)
    with staged_output_dir(final, overwrite=args.overwrite) as out:  # a foreign or earlier directory is never mixed
        payload, text = _run(args, out, modes)
    payload["out"] = str(final)
    if payload["report"]:
        payload["report"] = str(final / "report.html")
    emit(args, payload, text)
    return 0


def _run(args: argparse.Namespace, out, modes):
    from pathlib import Path

    from ..dataset import read_mission, read_vehicle_toml
    from ..pipeline import ScanRecognizer, detect_mission
    from ..recognition import load_database
    from ..slam import SlamConfig, run_slam, write_detections_jsonl, write_run
    from ..slam.export import export_run
    from ..slam.rundir import DETECTIONS, mode_dir

    src = Path(args.dive)
    progress = not getattr(args, "json", False)
    if (src / "mission.json").is_file():
        dataset = read_mission(src)
        if args.vehicle:
            from dataclasses import replace

            dataset = replace(dataset, vehicle=read_vehicle_toml(args.vehicle))
    else:
        from ..dataset.rosbag import export_bag, read_topic_map

        export_bag(src, out / "mission", topic_map=read_topic_map(args.topics) if args.topics else None,
                   vehicle=read_vehicle_toml(args.vehicle) if args.vehicle else None, msg_dirs=args.msg_dir,
                   progress=progress)
        dataset = read_mission(out / "mission")
    if args.db == "builtin":
        from ..simulation.builtin_db import builtin_database

        db = builtin_database(seed=0)
    else:
        db = load_database(args.db)
    recognizer = ScanRecognizer(db, seed=args.seed)
    recognizer.warm_up()
    found = detect_mission(dataset, recognizer, seed=args.seed, progress=progress,
                           up_from_attitude=args.up_from_attitude)
    write_detections_jsonl(out / DETECTIONS, found.detections_by_scan)
    metrics = {}
    for mode in modes:
        res = run_slam(dataset, found.detections_by_scan, mode=mode, config=SlamConfig(), seed=args.seed,
                       symmetries=db.symmetries(), backend=args.backend)
        write_run(res, mode_dir(out, mode))
        origin = (dataset.metadata.get("source") or {}).get("time_origin_ns", 0)
        export_run(res, mode_dir(out, mode), detections_by_scan=found.detections_by_scan or None,
                   T_vehicle_scanner=dataset.T_vehicle_scanner if found.detections_by_scan else None,
                   time_origin_ns=int(origin or 0))
        metrics[mode] = res.metrics
    report = None
    if not args.no_report:
        from ..report.build import build_report

        report = build_report(out)
    payload = {"detection": found.summary(), "slam": metrics, "report": str(report) if report else None}

    def text() -> str:
        s = found.summary()
        lines = [f"{s['n_scans']} scans, {s['n_kept']} detections kept for SLAM "
                 f"(scan latency median {s['scan_latency_ms_median']:.1f} ms)"]
        for mode, m in metrics.items():
            ate = f", ATE {m['ate_rmse_m']:.4f} m" if "ate_rmse_m" in m else ""
            lines.append(f"{mode}: {m['n_landmarks']} landmarks{ate}")
        if report:
            lines.append(f"report: {payload['report']}")
        return "\n".join(lines)

    return payload, text
