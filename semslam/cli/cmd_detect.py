"""``semslam detect MISSION --db DB --out detections.jsonl``: every scan of a dataset through the recognition
pipeline (:func:`semslam.pipeline.mission.detect_mission`), one detection per JSON line, ready for
``semslam slam MISSION --detections detections.jsonl``."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    from ._inputs import add_config_options

    p = subparsers.add_parser(
        "detect", parents=[common], help="recognise and localise objects in every scan of a dataset",
        description="Run the recognition pipeline on every scan of a mission directory and write the detections "
                    "(JSON lines, each stamped with its own points' acquisition time) for `semslam slam --detections`. "
                    "The resolved pipeline configuration is written beside them (OUT.config.json).")
    p.add_argument("mission", metavar="MISSION", help="mission directory")
    p.add_argument("--db", required=True, metavar="DB", help="view database (.npz), or 'builtin'")
    p.add_argument("--out", required=True, metavar="FILE.jsonl", help="detections to write (atomically)")
    add_config_options(p, "the pipeline")  # OUT.config.json and a bare PipelineConfig table are read too
    p.add_argument("--vehicle", help="vehicle description (TOML) replacing the dataset's; 'girona500' for the defaults")
    p.add_argument("--seed", type=int, help="seed of the run (scan k uses seed * 100003 + k; default 0, or --config's)")
    p.add_argument("--keep-unreliable", action="store_true", help="keep detections whose pose is flagged unreliable")
    p.add_argument("--up-from-attitude", action="store_true",
                   help="pose every scan's objects upright about the up direction of the vehicle's attitude at that "
                        "scan (classes whose database records their up: db build --fuse --up)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--overwrite", action="store_true", help="replace FILE.jsonl and FILE.jsonl.config.json if they exist")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from .._atomic import atomic_write_text
    from .._outdir import check_output_file, staged_output_file
    from ..errors import InputError
    from ..pipeline import ScanRecognizer
    from ..pipeline.mission import detect_mission
    from ..recognition import load_database
    from ..io.detections import write_detections_jsonl
    from ._inputs import load_dataset, run_config_from_args
    from ._output import emit, to_jsonable

    out = Path(args.out)
    config_out = out.with_name(out.name + ".config.json")
    inputs = (args.mission, args.db, args.config, args.vehicle)
    for path in (out, config_out):  # before the work (semslam._outdir)
        check_output_file(path, overwrite=args.overwrite, inputs=inputs)
    dataset = load_dataset(args.mission, args.vehicle)
    if not dataset.scans:
        raise InputError(f"The dataset {args.mission!r} has no scans to recognise objects in.")
    rc = run_config_from_args(args)  # --preset, --config, then the explicit options (semslam.run.config)
    config, run_opts = rc.pipeline_config(), rc.run
    if args.db == "builtin":
        from ..simulation.builtin_db import builtin_database

        db = builtin_database(seed=0)
    else:
        db = load_database(args.db)
    recognizer = ScanRecognizer(db, config, seed=run_opts.seed)
    recognizer.warm_up()
    progress = not args.no_progress and not getattr(args, "json", False)
    found = detect_mission(dataset, recognizer, seed=run_opts.seed, keep_unreliable=run_opts.keep_unreliable,
                           progress=progress, up_from_attitude=run_opts.up_from_attitude)
    with staged_output_file(out, overwrite=args.overwrite, inputs=inputs) as tmp:
        write_detections_jsonl(tmp, found.detections_by_scan)
    resolved = {"preset": rc.preset, "pipeline": config.to_dict(), "seed": run_opts.seed, "db": str(args.db),
                "keep_unreliable": run_opts.keep_unreliable, "up_from_attitude": run_opts.up_from_attitude,
                "mission": str(args.mission)}
    with staged_output_file(config_out, overwrite=args.overwrite, inputs=inputs) as tmp:
        atomic_write_text(tmp, json.dumps(to_jsonable(resolved), indent=2) + "\n")
    summary = found.summary()
    payload = {"out": str(out), "summary": summary, "scans": found.scans}

    def text() -> str:
        return (f"{summary['n_scans']} scans, {summary['n_clusters']} clusters, {summary['n_detections']} detections "
                f"({summary['n_kept']} kept for SLAM); scan latency median {summary['scan_latency_ms_median']:.1f} ms, "
                f"p90 {summary['scan_latency_ms_p90']:.1f} ms\nwritten to {out}")

    emit(args, payload, text)
    return 0
