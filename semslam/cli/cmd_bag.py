"""``semslam bag info BAG`` (topics, types, counts, rates and a suggested topic map) and ``semslam bag export BAG
--out DATASET`` (a ROS 1 / ROS 2 bag into a dataset directory, streamed: bounded memory)."""

from __future__ import annotations

import argparse


def register(subparsers, common) -> None:
    p = subparsers.add_parser("bag", parents=[common], help="inspect a ROS bag, or convert it to a dataset directory",
                              description="ROS 1 (.bag) and ROS 2 (sqlite3, mcap) bags, read without a ROS install.")
    sub = p.add_subparsers(dest="bag_command", metavar="ACTION")
    info = sub.add_parser("info", parents=[common], help="topics, types, counts, rates; a suggested topic map")
    info.add_argument("bag", metavar="BAG")
    info.add_argument("--msg-dir", action="append", default=[], metavar="DIR",
                      help="directory of PKG/msg/NAME.msg definitions for types the bag does not embed; repeatable")
    info.set_defaults(func=run_info)
    exp = sub.add_parser("export", parents=[common], help="convert a bag to a dataset directory")
    exp.add_argument("bag", metavar="BAG")
    exp.add_argument("--out", required=True, metavar="DATASET", help="dataset directory to create")
    exp.add_argument("--topics", help="topic map (TOML; default: `semslam bag info`'s suggestion)")
    exp.add_argument("--vehicle", help="vehicle description (TOML; default: the Girona 500-class defaults)")
    exp.add_argument("--msg-dir", action="append", default=[], metavar="DIR", help="as for `bag info`")
    exp.add_argument("--overwrite", action="store_true", help="replace DATASET if semslam wrote it")
    exp.set_defaults(func=run_export)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def run_info(args: argparse.Namespace) -> int:
    from ..dataset.rosbag import suggest_topic_map
    from ..io.ros import open_bag
    from ._output import emit

    with open_bag(args.bag, msg_dirs=args.msg_dir) as bag:
        recs = bag.topics()
        suggestion = suggest_topic_map(bag)
    payload = {"bag": args.bag, "topics": [{"topic": r.topic, "type": r.msgtype, "count": r.count,
                                            "rate_hz": r.rate_hz} for r in recs],
               "suggested_topic_map": suggestion.to_toml()}

    def text() -> str:
        lines = [f"{'topic':<32}{'type':<48}{'count':>8}{'rate (Hz)':>11}"]
        for r in recs:
            rate = f"{r.rate_hz:.2f}" if r.rate_hz else "-"
            lines.append(f"{r.topic:<32}{r.msgtype:<48}{r.count:>8}{rate:>11}")
        return "\n".join(lines) + "\n\nsuggested topic map (save as topics.toml and edit):\n" + suggestion.to_toml()

    emit(args, payload, text)
    return 0


def run_export(args: argparse.Namespace) -> int:
    from .._outdir import check_output_dir
    from ..dataset import read_vehicle_toml
    from ..dataset.rosbag import export_bag, read_topic_map
    from ._output import emit

    # before the work: only an earlier mission semslam wrote is replaced, never an input (semslam._outdir)
    check_output_dir(args.out, overwrite=args.overwrite, kind="mission",
                     inputs=(args.bag, args.topics, args.vehicle, *args.msg_dir))
    tmap = read_topic_map(args.topics) if args.topics else None
    vehicle = read_vehicle_toml(args.vehicle) if args.vehicle else None
    out = export_bag(args.bag, args.out, topic_map=tmap, vehicle=vehicle, msg_dirs=args.msg_dir,
                     overwrite=args.overwrite, progress=not getattr(args, "json", False))
    from ..dataset import read_dataset

    ds = read_dataset(out)
    payload = {"directory": str(out), "n_scans": len(ds.scans), "n_attitude": len(ds.attitude),
               "n_dvl": len(ds.dvl), "n_depth": len(ds.depth), "duration_s": ds.duration_s}
    emit(
        args,
        payload,
        lambda: (
            f"wrote {out}: {ds.duration_s:.1f} s, {len(ds.scans)} scans, attitude {len(ds.attitude)}"
            f" / DVL {len(ds.dvl)} / depth {len(ds.depth)} samples"
        ),
    )
    return 0
