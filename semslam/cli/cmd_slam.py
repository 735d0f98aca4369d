"""``semslam slam`` (run the semantic EKF on a mission) and ``semslam montecarlo`` (seeded N-run evaluation)."""

from __future__ import annotations

import argparse
from pathlib import Path
from ..modes import BACKENDS, MODES


#: the filter modes (:mod:`semslam.modes`, a light module) and "all"
MODE_CHOICES = (*MODES, "all")
BACKEND_CHOICES = BACKENDS


def register(subparsers, common) -> None:
    from ._inputs import add_config_options
    from ._scheduler_tls import add_tls_options

    p = subparsers.add_parser("slam", parents=[common], help="run the semantic EKF-SLAM on a mission",
                              description="Run the semantic EKF-SLAM on a dataset directory (or 'synthetic:SEED') "
                                          "and write trajectory.csv, landmarks.csv, updates.csv, metrics.json.")
    p.add_argument(
        "dataset",
        metavar="DATASET",
        help="dataset directory, or synthetic:SEED for the built-in analytic square dataset",
    )
    p.add_argument("--mode", choices=MODE_CHOICES, help="filter mode (default pose, or --config's [run] modes; all: "
                                                        "one sub-directory per mode)")
    p.add_argument("--out", required=True, help="run directory to write (new, or an earlier run with --overwrite)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier semslam run in --out")
    p.add_argument("--detections", help="JSON lines of Detection.to_dict(), e.g. from `semslam detect` (default, or "
                                        "'truth': truth-based detections simulated from the dataset's ground truth)")
    add_config_options(p, "the filter")  # a run's config.json (SlamConfig's sections at the top) is read too
    p.add_argument("--vehicle", help="vehicle description (TOML) replacing the dataset's; 'girona500' for the defaults")
    p.add_argument("--db", help="view database whose class symmetries the map uses (default: the built-in objects')")
    p.add_argument("--export", action="store_true",
                   help="also write TUM and KITTI trajectories, the map as JSON/CSV/PLY and run.mcap (ROS 2)")
    p.add_argument("--seed", type=int, help="seed of the truth-based detections (default 0, or --config's)")
    p.add_argument(
        "--survey", metavar="FILE", help="landmarks known a priori: a survey CSV or an earlier run's map.json"
    )
    p.add_argument("--surveyed", action="append", default=[], metavar="OBJECT",
                   help="with truth-based detections: a mission object given to the run as a simulated survey (its "
                        "true pose plus the survey's error); repeatable")
    p.add_argument("--backend", choices=BACKEND_CHOICES,
                   help="estimator: the EKF (default), or a GTSAM factor graph: isam2 (online smoothing) or batch")
    p.set_defaults(func=run)

    q = subparsers.add_parser(
        "montecarlo",
        parents=[common],
        help="seeded Monte-Carlo evaluation of the filter modes",
        description="Simulate N seeded missions, run each filter mode, report ATE and ANEES "
        "(summary.json/.md, ANEES and error-over-time curves, report.html; "
        "`semslam report` of a folder of several backends' Monte Carlos compares them).",
    )
    q.add_argument("--runs", type=int, default=30, help="number of missions (default 30)")
    q.add_argument("--mode", choices=MODE_CHOICES, default="all", help="mode to run (default all)")
    q.add_argument("--yaw-bias-deg", type=float, default=0.0, help="constant AHRS yaw bias of the missions (degrees)")
    q.add_argument("--seed", type=int, default=0, help="seed of the first mission (default 0)")
    q.add_argument("--loops", type=int, default=3, help="loops per mission (default 3)")
    q.add_argument("--source", choices=("auto", "simulator", "synthetic"), default="auto",
                   help="mission generator (auto: the simulator when available)")
    q.add_argument("--yaw-bias-walk", type=float, default=0.0, metavar="DEG_PER_SQRT_S",
                   help="random walk of the AHRS yaw bias of the missions (degrees per sqrt(s); default 0)")
    q.add_argument("--surveyed", action="append", default=[], metavar="OBJECT",
                   help="name of a mission object whose pose is known a priori (a surveyed reference structure, "
                        "e.g. reducing_socket_0); repeatable")
    q.add_argument("--white-dvl", action="store_true",
                   help="missions with a white-noise-only DVL (no scale factor, misalignment or biases)")
    q.add_argument("--launch-sigma", type=float, default=None, metavar="M",
                   help="standard deviation (m, per axis) of the start point of a dive without position fixes, "
                        "which defines its local frame (default: SlamConfig's, 0.001)")
    q.add_argument("--no-smooth", action="store_true", help="skip the RTS-smoothed trajectories")
    q.add_argument("--out", help="directory for summary.json, summary.md and ANEES curves (new, or an earlier Monte "
                                 "Carlo of semslam's with --overwrite)")
    q.add_argument("--overwrite", action="store_true", help="replace an earlier semslam Monte Carlo in --out")
    q.add_argument("--jobs", type=int, default=1, metavar="N",
                   help="worker processes of a local Dask cluster (default 1: serial, in this process); same results")
    q.add_argument("--scheduler", metavar="ADDRESS", help="run on the Dask cluster of this scheduler: tls://host:8786 "
                   "with --tls-* certificates, or tcp://host:8786 (unauthenticated: trusted networks only)")
    add_tls_options(q)
    q.add_argument("--backend", choices=BACKEND_CHOICES, default="ekf",
                   help="estimator: the EKF (default), or a GTSAM factor graph: isam2 or batch")
    q.set_defaults(func=run_montecarlo_cmd)


def run(args: argparse.Namespace) -> int:
    from .._outdir import staged_output_dir
    from ..errors import InputError
    from ..run.config import write_resolved_config
    from ..io.detections import read_detections_jsonl
    from ..run.dive import slam_dive
    from ..run.rundir import write_run
    from ..run.rundir import mode_dir
    from ._inputs import load_dataset, run_config_from_args
    from ._output import emit

    mission = load_dataset(args.dataset, args.vehicle)
    rc = run_config_from_args(args, default_modes=("pose",))  # --preset, --config, the explicit options
    cfg = rc.slam_config()
    survey = None
    if args.survey:
        from ..slam.survey import read_survey

        survey = read_survey(args.survey)
    dets = None
    if args.detections and args.detections != "truth":
        dets = read_detections_jsonl(args.detections)
    elif mission.truth is None or not mission.objects:
        raise InputError("The dataset has no ground truth to simulate detections from: give --detections FILE "
                         "(from `semslam detect`).")
    if args.surveyed and dets is not None:
        raise InputError("The '--surveyed' option simulates a survey from the ground truth, with truth-based "
                         "detections only: give a survey file with --survey instead.")
    if args.db:
        from ..recognition import load_database

        symmetries = load_database(args.db).symmetries()
    else:
        from ..simulation.truth_slam import builtin_symmetries

        symmetries = builtin_symmetries()
    modes = rc.run.modes
    final = Path(args.out)
    payload = {}
    with staged_output_dir(final, overwrite=args.overwrite,
                           inputs=(args.dataset, args.detections, args.config, args.vehicle, args.db,
                                   args.survey)) as out:
        if dets is None:  # detections drawn from the simulator's truth (experiments): one run per mode
            from ..simulation.truth_slam import run_truth_slam

            results = {mode: run_truth_slam(mission, mode=mode, config=cfg, seed=rc.run.seed, backend=rc.run.backend,
                                            surveyed=tuple(args.surveyed)) for mode in modes}
        else:  # the runner of `semslam run`, every mode in one pass (semslam.run.dive.slam_dive)
            results = slam_dive(mission, dets, modes=modes, config=cfg, symmetries=symmetries,
                                backend=rc.run.backend, survey=survey)
        for mode, res in results.items():
            where = mode_dir(out, mode) if len(modes) > 1 else out
            write_run(res, where)
            if args.export:
                from ..run.export import export_run

                export_run(res, where, detections_by_scan=dets or None,
                           T_vehicle_scanner=mission.vehicle.scanner.T_vehicle_scanner if dets else None)
            payload[mode] = res.metrics
        write_resolved_config(rc, out)  # RUN/config.toml: every setting, the preset named
    out = final

    def text() -> str:
        lines = [f"{'mode':<14}{'ATE (m)':>10}{'final (m)':>11}{'3-sigma (m)':>13}{'NEES':>8}{'landmarks':>11}"]
        for mode, mt in payload.items():
            lines.append(
                f"{mode:<14}{mt.get('ate_rmse_m', float('nan')):>10.4f}{mt.get('final_position_error_m', float('nan')):>11.4f}"
                f"{mt.get('final_3sigma_m', float('nan')):>13.4f}{mt.get('nees_position_mean', float('nan')):>8.2f}"
                f"{mt['n_landmarks']:>11d}"
            )
        lines.append(f"written to {out}")
        return "\n".join(lines)

    emit(args, {"out": str(out), "metrics": payload}, text)
    return 0


def run_montecarlo_cmd(args: argparse.Namespace) -> int:
    from ..batch.engine import scheduler_tls

    with scheduler_tls(args.scheduler, getattr(args, "tls_ca_file", None), getattr(args, "tls_cert", None),
                       getattr(args, "tls_key", None)):
        return _run_montecarlo(args)


def _run_montecarlo(args: argparse.Namespace) -> int:
    import sys

    from ..errors import InputError
    from ..experiments.montecarlo import run_montecarlo, write_montecarlo
    from ..slam import MODES
    from ._output import emit

    modes = MODES if args.mode == "all" else (args.mode,)
    if args.out:  # before the work: only an earlier Monte Carlo semslam's marker proves it wrote (semslam._outdir)
        from .._outdir import check_output_dir

        check_output_dir(args.out, overwrite=args.overwrite, kind="montecarlo")
    overrides: dict = {}
    if args.launch_sigma is not None:
        if not (args.launch_sigma > 0 and args.launch_sigma < float("inf")):
            raise InputError(
                f"The '--launch-sigma' option must be a positive number of metres. Got {args.launch_sigma!r} instead."
            )
        overrides["initial_position_sigma_m"] = float(args.launch_sigma)
    if args.no_smooth:
        overrides["smooth"] = False
    res = run_montecarlo(args.runs, modes=modes, yaw_bias_deg=args.yaw_bias_deg, seed=args.seed, source=args.source,
                         loops=args.loops, log=None if getattr(args, "json", False) else
                         (lambda s: print(s, file=sys.stderr)), yaw_bias_walk_deg_per_sqrt_s=args.yaw_bias_walk,
                         white_dvl=args.white_dvl, jobs=args.jobs, scheduler=args.scheduler,
                         config_overrides=overrides or None, backend=args.backend, surveyed=tuple(args.surveyed))
    if args.out:
        from .._outdir import staged_output_dir

        with staged_output_dir(args.out, overwrite=args.overwrite, kind="montecarlo") as tmp:
            write_montecarlo(res, tmp)
    emit(args, {"n_runs": res.n_runs, "summary": res.summary}, res.table)
    return 0
