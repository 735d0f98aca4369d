"""``semslam detect BAG|DATASET --db DB --out detections.jsonl``: every scan of a dive (a ROS bag, streamed, or a
dataset directory) through the recognition pipeline on the runner of ``semslam run``
(:func:`semslam.run.dive.detect_dive`), one detection per JSON line, ready for
``semslam slam DATASET --detections detections.jsonl``."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    from ._inputs import add_config_options

    p = subparsers.add_parser(
        "detect", parents=[common], help="recognise and localise objects in every scan of a dive",
        description="Run the recognition pipeline on every scan of a dive (ROS 1/2 bag or dataset directory) and write "
                    "the detections "
                    "(JSON lines, each stamped with its own points' acquisition time) for `semslam slam --detections`. "
                    "The resolved pipeline configuration is written beside them (OUT.config.json).")
    p.add_argument("dataset", metavar="BAG|DATASET", help="ROS 1/2 bag or dataset directory (or synthetic:SEED)")
    p.add_argument("--db", required=True, metavar="DB", help="view database (.npz), or 'builtin'")
    p.add_argument("--out", required=True, metavar="FILE.jsonl", help="detections to write (atomically)")
    add_config_options(p, "the pipeline")  # OUT.config.json and a bare PipelineConfig table are read too
    p.add_argument("--vehicle", help="vehicle description (TOML) replacing the dive's; 'girona500' for the defaults; "
                                     "default: the mission's, or BAG.vehicle.toml beside the bag")
    p.add_argument(
        "--topics",
        help="topic map of a bag (TOML); default: BAG.topics.toml beside the bag, else the bag's "
        "own evidence (a frame it cannot establish is an error, never a guess)",
    )
    p.add_argument("--msg-dir", action="append", default=[], metavar="DIR", help="message definitions (bags)")
    p.add_argument("--seed", type=int, help="seed of the run (scan k uses seed * 100003 + k; default 0, or --config's)")
    p.add_argument("--keep-unreliable", action="store_true", help="keep detections whose pose is flagged unreliable")
    p.add_argument("--up-from-attitude", action="store_true",
                   help="pose every scan's objects upright about the up direction of the vehicle's attitude at that "
                        "scan (classes whose database records their up: db build --fuse --up)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--overwrite", action="store_true", help="replace FILE.jsonl and FILE.jsonl.config.json if they exist"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from .._atomic import atomic_write_text
    from .._outdir import check_output_file, staged_output_file
    from ..io.detections import write_detections_jsonl
    from ..run.dive import detect_dive
    from ._inputs import load_database_arg, run_config_from_args
    from ._output import emit, to_jsonable

    out = Path(args.out)
    config_out = out.with_name(out.name + ".config.json")
    inputs = (args.dataset, args.db, args.config, args.vehicle, args.topics, *args.msg_dir)
    for path in (out, config_out):  # before the work (semslam._outdir)
        check_output_file(path, overwrite=args.overwrite, inputs=inputs)
    rc = run_config_from_args(args)  # --preset, --config, then the explicit options (semslam.run.config)
    config, run_opts = rc.pipeline_config(), rc.run
    db = load_database_arg(args.db)  # before the dive is read: a missing database stops at once
    found = detect_dive(_source(args.dataset), db=db, topics=args.topics, vehicle=args.vehicle, msg_dirs=args.msg_dir,
                        pipeline_config=config, seed=run_opts.seed, keep_unreliable=run_opts.keep_unreliable,
                        up_from_attitude=run_opts.up_from_attitude,
                        progress=not args.no_progress and not getattr(args, "json", False))
    with staged_output_file(out, overwrite=args.overwrite, inputs=inputs) as tmp:
        write_detections_jsonl(tmp, found.detections_by_scan)
    resolved = {"preset": rc.preset, "pipeline": config.to_dict(), "seed": run_opts.seed, "db": str(args.db),
                "keep_unreliable": run_opts.keep_unreliable, "up_from_attitude": run_opts.up_from_attitude,
                "dataset": str(args.dataset)}
    with staged_output_file(config_out, overwrite=args.overwrite, inputs=inputs) as tmp:
        atomic_write_text(tmp, json.dumps(to_jsonable(resolved), indent=2) + "\n")
    summary = found.detection_summary()
    payload = {"out": str(out), "summary": summary, "scans": found.scans}

    def text() -> str:
        return (f"{summary['n_scans']} scans, {summary['n_clusters']} clusters, {summary['n_detections']} detections "
                f"({summary['n_kept']} kept for SLAM); scan latency median {summary['scan_latency_ms_median']:.1f} ms, "
                f"p90 {summary['scan_latency_ms_p90']:.1f} ms\nwritten to {out}")

    emit(args, payload, text)
    return 0


def _source(spec: str):
    """A bag or dataset directory as given; ``synthetic:SEED`` (the analytic square mission) as a dataset."""
    if spec.startswith("synthetic:"):
        from ._inputs import load_dataset

        return load_dataset(spec)
    return spec
