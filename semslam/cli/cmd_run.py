"""``semslam run BAG|DATASET --db DB --out RUN``: the whole chain on a recorded dive, streamed from the bag (nothing
converted on disk): every scan recognised, SLAM in every mode (or one) in one pass, the run directory (trajectories
as TUM and KITTI, the map as JSON/CSV/PLY, run.mcap for Foxglove/RViz), the health verdict and the report. The
library call is :func:`semslam.run.dive.run_dive`."""

from __future__ import annotations

import argparse
from ..modes import BACKENDS

#: exit status of ``--strict`` when the run's verdict is bad (distinct from 1, an error)
EXIT_BAD_VERDICT = 3


def register(subparsers, common) -> None:
    from ._inputs import add_config_options

    p = subparsers.add_parser("run", parents=[common], help="detect + SLAM + report on a bag or a dataset directory",
                              description="Run the whole chain on a recorded dive (ROS 1/2 bag or dataset directory): "
                                          "recognition on every scan, SLAM in every mode (or one), the health "
                                          "verdict and the report.")
    p.add_argument("dive", metavar="BAG|DATASET")
    p.add_argument("--db", required=True, metavar="DB", help="view database (.npz), or 'builtin'")
    p.add_argument("--out", required=True, metavar="RUN", help="run directory to create (new, or an earlier run with "
                                                                "--overwrite)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier semslam run in --out")
    p.add_argument(
        "--vehicle",
        help="vehicle description (TOML, or 'girona500'); default: the mission's, or BAG.vehicle.toml beside the bag",
    )
    p.add_argument(
        "--topics",
        help="topic map of a bag (TOML); default: BAG.topics.toml beside the bag, else the bag's "
        "own evidence (a frame it cannot establish is an error, never a guess)",
    )
    p.add_argument("--msg-dir", action="append", default=[], metavar="DIR", help="message definitions (bags)")
    add_config_options(p)
    p.add_argument(
        "--survey",
        metavar="FILE",
        help="landmarks known a priori: a survey CSV or an earlier run's map.json in the same world frame",
    )
    p.add_argument("--mode", help="SLAM mode: dr, position, pose, pose+heading or all (default; or --config's)")
    p.add_argument("--seed", type=int, help="seed of recognition (default 0, or --config's)")
    p.add_argument("--backend", choices=BACKENDS,
                   help="SLAM estimator: the EKF (default), or a GTSAM factor graph: isam2 (online) or batch")
    p.add_argument("--no-report", action="store_true", help="skip report.html")
    p.add_argument("--strict", action="store_true",
                   help=f"exit with status {EXIT_BAD_VERDICT} when the run's health verdict is bad")
    p.add_argument("--up-from-attitude", action="store_true",
                   help="pose every scan's objects upright about the up direction of the vehicle's attitude at that "
                        "scan (classes whose database records their up: db build --fuse --up)")
    p.add_argument("--keep-unreliable", action="store_true",
                   help="hand the filter the detections whose pose is flagged unreliable too (border-cut parts, with "
                        "their wide covariance; or [run] keep_unreliable in --config)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .._outdir import staged_output_dir
    from ..run.config import write_resolved_config
    from ..run.dive import run_dive
    from ._inputs import load_database_arg, run_config_from_args
    from ._output import emit

    rc = run_config_from_args(args)  # --preset, --config, then the explicit options (semslam.run.config)
    modes, cfg, pcfg = rc.run.modes, rc.slam_config(), rc.pipeline_config()
    survey = None
    if args.survey:
        from ..slam.survey import read_survey

        survey = read_survey(args.survey)
    db = load_database_arg(args.db)  # before the dive is read: a missing database stops at once
    final = Path(args.out)
    with staged_output_dir(final, overwrite=args.overwrite,  # a foreign or earlier run is never mixed, nor an input
                           inputs=(args.dive, args.db, args.vehicle, args.topics, args.config, args.survey,
                                   *args.msg_dir)) as out:
        payload = run_dive(args.dive, out, db=db, modes=modes, topics=args.topics, vehicle=args.vehicle,
                           msg_dirs=args.msg_dir, config=cfg, pipeline_config=pcfg, backend=rc.run.backend,
                           seed=rc.run.seed, survey=survey, up_from_attitude=rc.run.up_from_attitude,
                           keep_unreliable=rc.run.keep_unreliable)
        write_resolved_config(rc, out)  # RUN/config.toml: every setting, the preset named
        report = None
        if not args.no_report:
            from ..report.build import build_report

            report = build_report(out)
    payload["out"] = str(final)
    payload["report"] = str(final / "report.html") if report else None
    emit(args, payload, lambda: _text(payload))
    if args.strict and payload["verdict"] == "bad":
        return EXIT_BAD_VERDICT
    return 0


def _text(payload: dict) -> str:
    s = payload["detection"]
    start = payload.get("start") or {}
    lines = [f"{s['n_scans']} scans, {s['n_kept']} detections kept for SLAM "
             f"(scan latency median {s['scan_latency_ms_median']:.1f} ms)",
             f"start: {start.get('frame', '?')} frame; " + "; ".join(f"{k}: {v}" for k, v in
                                                                     (start.get('sources') or {}).items())]
    for mode, m in payload["slam"].items():
        ate = f", ATE {m['ate_rmse_m']:.4f} m" if "ate_rmse_m" in m else ""
        h = payload["health"][mode]
        lines.append(f"{mode}: {m['n_landmarks']} landmarks{ate}; health {h['verdict'].upper()}")
        lines += [f"  {c['level'].upper()}: {c['check']}: {c['message']}" for c in h["checks"] if c["level"] != "ok"]
    lines.append(f"verdict: {payload['verdict'].upper()}")
    if payload.get("report"):
        lines.append(f"report: {payload['report']}")
    return "\n".join(lines)
