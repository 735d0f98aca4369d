"""``semslam simulate``: simulate a mission and write its directory (see docs/dataset-format.md)."""

from __future__ import annotations

import argparse


def register(subparsers, common) -> None:
    p = subparsers.add_parser(
        "simulate", parents=[common],
        help="simulate a mission (tank, four fittings, vehicle, DVL/AHRS/depth, laser scans) into a directory",
        description="Simulate a Girona 500-like mission over the four PVC fittings in a CIRS-like tank and "
                    "write it as a dataset directory (mission.json, sensor CSVs, scans/*.pcd, ground_truth/).",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="dataset directory (or bag) to create")
    p.add_argument("--format", choices=("mission", "ros1", "ros2-mcap", "ros2-sqlite3"), default="mission",
                   help="a dataset directory (default, with ground truth), or a ROS bag as a vehicle would record it "
                        "(no ground truth; OUT.vehicle.toml and OUT.topics.toml are written beside it)")
    p.add_argument("--seed", type=int, default=0, help="random seed (same seed -> identical files; default 0)")
    p.add_argument("--loops", type=int, default=None, help="loops around the objects (default 3; 1 with --quick)")
    p.add_argument("--scan-rate", type=float, default=None, metavar="HZ",
                   help="laser scan rate: one scan lasts 1/HZ s (default 3)")
    p.add_argument("--scan-interval", type=float, default=None, metavar="S",
                   help="time between scan starts (default 0.5 s, at least 1/HZ)")
    p.add_argument("--clutter", action="store_true", help="add rocks and pipe offcuts that are not in the database")
    p.add_argument("--gps", type=int, default=0, metavar="N",
                   help="record N surface GPS fixes before the dive (metres of error, stated covariance; default 0: "
                        "the indoor tank has no GPS)")
    p.add_argument("--usbl-rate", type=float, default=0.0, metavar="HZ", help="record USBL fixes during the dive")
    p.add_argument("--no-scans", action="store_true", help="navigation and ground truth only (fast)")
    p.add_argument("--quick", action="store_true", help="small and fast: 1 loop, ~10k-point scans")
    p.add_argument("--overwrite", action="store_true",
                   help="replace DIR (and the bag's companion files) if semslam wrote it")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import dataclasses
    from pathlib import Path

    from .._outdir import check_output_dir, check_output_file, staged_output_file
    from ..errors import DatasetError
    from ..simulation import SimulatorConfig, simulate_dataset
    from ..dataset import write_dataset
    from ..simulation.simulate import DEFAULT_SCAN_INTERVAL_S
    from ._output import emit

    # before the work: what semslam may replace (semslam._outdir); the bag's companions are files like the bag
    companions = (f"{args.out}.vehicle.toml", f"{args.out}.topics.toml") if args.format != "mission" else ()
    if args.format == "ros1":
        check_output_file(args.out, overwrite=args.overwrite)
        if not args.out.endswith(".bag"):
            raise DatasetError(f"A ROS 1 bag's name must end in .bag. Got {args.out!r} instead.")
    else:
        check_output_dir(args.out, overwrite=args.overwrite, kind="bag" if companions else "mission")
    for c in companions:
        check_output_file(c, overwrite=args.overwrite)
    if Path(args.out).exists() and not args.overwrite:
        raise DatasetError(f"The output directory {args.out!r} already exists. Use --overwrite to replace it.")
    cfg = SimulatorConfig.quick() if args.quick else SimulatorConfig()
    if args.loops is not None:
        cfg = cfg.replace(trajectory=dataclasses.replace(cfg.trajectory, loops=args.loops))
    if args.scan_rate is not None:
        cfg = cfg.replace(scanner=dataclasses.replace(cfg.scanner, scan_rate_hz=args.scan_rate))
    if args.clutter:
        cfg = cfg.replace(world=dataclasses.replace(cfg.world, clutter=True))
    if args.gps or args.usbl_rate:
        cfg = cfg.replace(fixes=dataclasses.replace(cfg.fixes, gps_count=args.gps, usbl_rate_hz=args.usbl_rate))
    interval = args.scan_interval
    if interval is None:
        interval = (
            max(DEFAULT_SCAN_INTERVAL_S, 1.0 / cfg.scanner.scan_rate_hz)
            if cfg.scanner.scan_rate_hz > 0
            else DEFAULT_SCAN_INTERVAL_S
        )
    mission = simulate_dataset(cfg, seed=args.seed, with_scans=not args.no_scans, scan_interval_s=interval,
                               progress=not getattr(args, "json", False))
    if args.format == "mission":
        out = write_dataset(mission, args.out, overwrite=args.overwrite)
    else:
        from .._atomic import atomic_write_text
        from ..dataset import write_vehicle_toml
        from ..dataset.rosbag_write import topic_map_of, write_bag

        out = write_bag(mission, args.out, args.format, overwrite=args.overwrite)
        with staged_output_file(companions[0], overwrite=args.overwrite) as tmp:
            write_vehicle_toml(mission.vehicle, tmp)
        with staged_output_file(companions[1], overwrite=args.overwrite) as tmp:
            atomic_write_text(tmp, topic_map_of(mission).to_toml())
    n_points = sum(s.n_points for s in mission.scans)
    payload = {
        "directory": str(out),
        "format": args.format,
        "seed": args.seed,
        "duration_s": mission.duration_s,
        "n_scans": len(mission.scans),
        "n_points": n_points,
        "n_objects": len(mission.objects),
        "n_dvl": len(mission.dvl.stamp_s),
        "n_ahrs": len(mission.attitude.stamp_s),
        "n_depth": len(mission.depth.stamp_s),
    }
    emit(
        args,
        payload,
        lambda: (
            f"wrote {out}: {mission.duration_s:.1f} s, {len(mission.scans)} scans ({n_points} points), "
            f"{len(mission.objects)} objects, DVL {payload['n_dvl']} / AHRS {payload['n_ahrs']} / depth "
            f"{payload['n_depth']} samples"
        ),
    )
    return 0
