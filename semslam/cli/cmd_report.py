"""``semslam report RUN|MC``: rebuild report.html from a run directory (demo, slam or recognize outputs), a
Monte-Carlo directory, or a folder of Monte Carlos of several backends (``MC/ekf``, ``MC/isam2``, ...: one figure of
the position error over time per backend and scenario)."""

from __future__ import annotations

import argparse


def register(sub, common) -> None:
    p = sub.add_parser(
        "report",
        parents=[common],
        help="rebuild report.html from a run or Monte-Carlo directory",
        description="Rebuild figures/*.png and report.html from the files of a run directory written by "
        "`semslam demo`, `semslam slam` or `semslam evaluate`, of a `semslam montecarlo --out` "
        "directory, or of a folder holding the Monte Carlos of several backends "
        "(MC/ekf, MC/isam2, MC/batch: the position error over time of each backend, one "
        "figure per scenario).",
    )
    p.add_argument("run_dir", metavar="RUN", help="run directory, Monte-Carlo directory or folder of Monte Carlos")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..report.build import build_report
    from ._output import emit

    path = build_report(args.run_dir)
    emit(args, {"report": str(path)}, f"report: {path}")
    return 0
