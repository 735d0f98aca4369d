"""``semslam report RUN``: rebuild report.html from a run directory (demo, slam or recognize outputs)."""

from __future__ import annotations

import argparse


def register(sub, common) -> None:
    p = sub.add_parser("report", parents=[common], help="rebuild report.html from a run directory",
                       description="Rebuild figures/*.png and report.html from the files of a run directory written by "
                                   "`semslam demo`, `semslam slam` or `semslam evaluate`.")
    p.add_argument("run_dir", metavar="RUN", help="run directory")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..report.build import build_report
    from ._output import emit

    path = build_report(args.run_dir)
    emit(args, {"report": str(path)}, f"report: {path}")
    return 0
