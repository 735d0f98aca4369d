"""``semslam demo``: the whole mission in one command (see :mod:`semslam.demo`)."""

from __future__ import annotations

import argparse


def register(sub, common) -> None:
    from ._inputs import add_config_options

    p = sub.add_parser(
        "demo",
        parents=[common],
        help="simulate the tank, recognise, run SLAM in every mode, write a report",
        description="Build the built-in database, evaluate it, simulate the default tank mission, run the "
        "recognition and pose pipeline on every scan, run SLAM in every mode on the same "
        "detections, and write a run directory with report.html.",
    )
    p.add_argument("--out", default="runs/demo", help="run directory (default runs/demo)")
    p.add_argument("--seed", type=int, default=0, help="seed of everything (default 0)")
    p.add_argument(
        "--quick", action="store_true", help="two loops and one SVM grid search: a first look in well under a minute"
    )
    p.add_argument("--loops", type=int, default=None, help="loops of the mission (default 3, 2 with --quick)")
    p.add_argument("--overwrite", action="store_true", help="replace the run directory if it exists")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument(
        "--models",
        default=None,
        metavar="DIR",
        help="your CAD models (models.toml + STL/OBJ/PLY/DAE/glTF/STEP, as for 'db build --models'): the database and the "
        "mission's objects are yours instead of the built-in fittings",
    )
    p.add_argument("--db-sensor", choices=("laser", "kinect", "kinect+laser"), default=None,
                   help="the sensor the database views are rendered with (default: the demo's, see semslam.demo)")
    add_config_options(p, "the pipeline")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys

    from ..demo import DemoConfig, run_demo
    from ._output import emit

    over = {} if args.db_sensor is None else {"db_sensor": args.db_sensor}
    cfg = DemoConfig(seed=args.seed, quick=args.quick, loops=args.loops, models_dir=args.models, preset=args.preset,
                     config_file=args.config, **over)
    quiet = getattr(args, "json", False)
    log = (lambda s: None) if quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    metrics = run_demo(args.out, cfg, progress=not (args.no_progress or quiet), log=log, overwrite=args.overwrite)
    emit(args, metrics, lambda: summary_text(metrics))
    return 0


def summary_text(metrics: dict) -> str:
    lines = ["", "semslam demo: summary", ""]
    loo = metrics.get("leave_one_out", {})
    if loo:
        lines.append("leave-one-out accuracy: " + ", ".join(f"{k.replace('_', ' ').upper()} {100 * v['accuracy']:.1f}%"
                                                            for k, v in loo.items()))
    r = metrics.get("recognition", {})
    if r:
        lines.append(
            f"recognition: {r['n_detections']} detections in {r['n_scans']} scans, precision "
            f"{_pct(r['precision'])}, recall {_pct(r['recall'])}, median pose error "
            f"{r['pose_median_rotation_error_deg']:.1f} deg / {1000 * r['pose_median_translation_error_m']:.1f} mm, "
            f"median latency {r['scan_latency_ms_median']:.0f} ms/scan"
        )
    slam = metrics.get("slam", {})
    if slam:
        lines.append("")
        lines.append(f"{'mode':<14}{'ATE RMSE [m]':>14}{'smoothed [m]':>14}{'final err [m]':>15}{'landmarks':>11}")
        for mode, m in slam.items():
            lines.append(f"{mode:<14}{_f(m.get('ate_rmse_m')):>14}{_f(m.get('smoothed_ate_rmse_m')):>14}"
                         f"{_f(m.get('final_position_error_m')):>15}{str(m.get('n_landmarks', '')):>11}")
    t = metrics.get("timings_s", {})
    if t:
        lines.append("")
        lines.append(f"total time {t.get('total', float('nan')):.1f} s")
    lines.append("")
    lines.append(f"report: {metrics.get('report')}")
    return "\n".join(lines)


def _pct(x) -> str:
    try:
        return f"{100 * float(x):.1f}%"
    except (TypeError, ValueError):
        return "n/a"


def _f(x) -> str:
    try:
        return f"{float(x):.3f}"
    except (TypeError, ValueError):
        return "n/a"
