"""``semslam batch DIVES... --db DB --out RUNS``: ``semslam run`` on many dives (bags or dataset directories) as Dask
tasks, one run directory per dive, then RUNS/summary.csv, summary.md, index.html (see
:mod:`semslam.batch.dives`). Default engine: a local cluster of one worker process per core (``--workers``);
``--scheduler ADDRESS``: an existing Dask cluster whose workers see the same files."""

from __future__ import annotations

import argparse
from pathlib import Path
from ..modes import BACKENDS



def register(subparsers, common) -> None:
    from ._inputs import add_config_options
    from ._scheduler_tls import add_tls_options

    p = subparsers.add_parser("batch", parents=[common], help="detect + SLAM + report on many dives, on Dask",
                              description="Run the whole chain (`semslam run`) on many dives (ROS bags or mission "
                                          "directories) in parallel: one run directory per dive in RUNS, a summary "
                                          "table (summary.csv, summary.md) and index.html linking each report. "
                                          "Dives whose run directory is complete are skipped unless --overwrite. "
                                          "Exit status 1 when any dive failed (its error is in the summary).")
    p.add_argument("dives", nargs="+", metavar="DIVE", help="ROS 1/2 bag or dataset directory")
    p.add_argument("--db", required=True, metavar="DB", help="view database (.npz), or 'builtin'")
    p.add_argument("--out", required=True, metavar="RUNS", help="directory of the run directories and the summary")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="address of a running Dask scheduler: tls://host:8786 with --tls-* certificates, or "
                        "tcp://host:8786 (unauthenticated: trusted networks only); default: a local cluster")
    add_tls_options(p)
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="worker processes of the local cluster (default: one per core; 1: serial, in this process; "
                        "ignored with --scheduler)")
    p.add_argument("--overwrite", action="store_true", help="re-process dives whose run directory is complete")
    p.add_argument("--mode", help="SLAM mode: dr, position, pose, pose+heading or all (default; or --config's)")
    p.add_argument("--seed", type=int, help="seed of recognition and SLAM, every dive (default 0, or --config's)")
    p.add_argument("--vehicle", help="vehicle description (TOML) of every dive")
    p.add_argument("--topics", help="topic map of the bags (TOML)")
    p.add_argument("--msg-dir", action="append", default=[], metavar="DIR", help="message definitions (bags)")
    p.add_argument("--backend", choices=BACKENDS, help="SLAM estimator (as `semslam run`; default ekf)")
    add_config_options(p)
    p.add_argument("--no-report", action="store_true", help="skip each dive's report.html")
    p.set_defaults(func=run)


def process_dive(dive: Path, out: Path, options: dict) -> None:
    """One dive, as ``semslam run DIVE --out OUT`` does it (a Dask task: runs on a worker): the same library call,
    :func:`semslam.run.dive.run_dive`."""
    from ..run.config import RunConfig, write_resolved_config
    from ..run.dive import run_dive
    from ._inputs import load_database_arg

    rc = RunConfig.from_dict(options.get("config", {}), source="the batch's configuration")  # --config/--preset
    run_dive(dive, out, db=load_database_arg(options["db"]), modes=tuple(options["modes"]),
             topics=options.get("topics"), vehicle=options.get("vehicle"), msg_dirs=options.get("msg_dir", ()),
             backend=options.get("backend", "ekf"), seed=options.get("seed", 0), config=rc.slam_config(),
             pipeline_config=rc.pipeline_config(), up_from_attitude=rc.run.up_from_attitude,
             keep_unreliable=rc.run.keep_unreliable)
    write_resolved_config(rc, out)  # RUN/config.toml
    if not options.get("no_report"):
        from ..report.build import build_report

        build_report(out)


def run(args: argparse.Namespace) -> int:
    from ..batch.engine import scheduler_tls

    with scheduler_tls(args.scheduler, getattr(args, "tls_ca_file", None), getattr(args, "tls_cert", None),
                       getattr(args, "tls_key", None)):
        return _run_batch(args)


def _run_batch(args: argparse.Namespace) -> int:
    import sys

    from ..errors import InputError
    from ..batch.engine import check_jobs
    from ..batch.dives import INDEX, SUMMARY_MD, run_batch, table_rows, markdown
    from ._inputs import run_config_from_args
    from ._output import emit

    rc = run_config_from_args(args)  # --preset, --config, then the explicit options (semslam.run.config)
    modes = rc.run.modes
    for d in args.dives:
        if not Path(d).exists():
            raise InputError(f"The dive {d!r} does not exist: give ROS bags or dataset directories.")
    if args.db != "builtin" and not Path(args.db).is_file():
        raise InputError(f"The '--db' option must name a view database file (.npz) or 'builtin'. Got {args.db!r}, "
                         "which is not a file.")
    jobs = check_jobs(args.workers, "--workers") if args.workers is not None else None
    if jobs is None and not args.scheduler:
        from ..batch.engine import machine_workers

        jobs = machine_workers()
    options = {"db": str(Path(args.db).resolve()) if args.db != "builtin" else "builtin", "modes": list(modes),
               "seed": rc.run.seed, "vehicle": args.vehicle and str(Path(args.vehicle).resolve()),
               "topics": args.topics and str(Path(args.topics).resolve()),
               "msg_dir": [str(Path(d).resolve()) for d in args.msg_dir], "no_report": args.no_report,
               "backend": rc.run.backend, "config": rc.resolved_dict()}
    quiet = getattr(args, "json", False)
    total = len(args.dives)
    count = [0]

    def on_dive(i: int, row: dict) -> None:
        count[0] += 1
        if not quiet:
            what = ("ok (complete before: skipped)" if row.get("action") == "skipped" else row["status"]
                    if row["status"] == "ok" else f"FAILED: {row['error']}")
            print(f"[{count[0]}/{total}] {row['dive']}: {what}", file=sys.stderr)

    res = run_batch([str(Path(d).resolve()) for d in args.dives], Path(args.out).resolve(), process_dive,
                    options=options, overwrite=args.overwrite, scheduler=args.scheduler, jobs=jobs or 1,
                    on_dive=on_dive)
    payload = {"out": str(res.out), "n_dives": len(res.rows), "n_failed": res.n_failed, "dives": res.rows,
               "summary": str(res.out / SUMMARY_MD), "index": str(res.out / INDEX)}
    emit(args, payload, lambda: markdown(*table_rows(res.rows)) + f"\n\nindex: {res.out / INDEX}")
    if res.n_failed:
        print(f"semslam: error: {res.n_failed} of {len(res.rows)} dives failed (errors in {res.out / SUMMARY_MD})",
              file=sys.stderr)
        return 1
    return 0
