"""Time per scan of a dive's recognition with a preset, through the user's path: :func:`semslam.run.dive.detect_dive`
(``semslam detect``, the same runner as ``semslam run`` and the ROS node's worker), the recognizer warmed up first
as those do. Prints the per-scan total and each stage's median / p90 / max, the share of scans within the scan
period, and the slowest scans stage by stage, with the machine's load.

The runner recognises one scan ahead in a worker thread while the filter follows (``LOOKAHEAD``), and the numba
kernels use both cores, so the figures are those a user's ``semslam run`` sees on this machine, not single-thread
CPU times.

Usage (from the repository root; ``DIR`` is a demo run directory: ``mission/`` and ``db.npz``, e.g. ``runs/demo``
after ``make demo``, or a seed directory of ``benchmarks/unseen_parts.py --out OUT``)::

    .venv/bin/python benchmarks/scan_time.py --run runs/demo                          # the default preset
    .venv/bin/python benchmarks/scan_time.py --run OUT/seed_0 --preset seabed --up-from-attitude
    .venv/bin/python benchmarks/scan_time.py --run OUT/seed_0 --preset seabed --up-from-attitude --profile 30

``--profile N`` then runs the dive again with every scan recognised in the calling thread under cProfile and prints
the N top functions by cumulative and by own time.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

STAGES = ("segmentation", "descriptors", "matching", "pose", "parts", "attached", "fragments", "tracking", "total")


def _load() -> str:
    return "load %.2f %.2f %.2f" % os.getloadavg()


def _pipeline_config(preset: str | None, config: str | None):
    from semslam.run.config import load_run_config

    return load_run_config(config, preset=preset).pipeline_config()


def time_dive(run: Path, *, preset: str | None, config: str | None, up_from_attitude: bool, seed: int) -> list[dict]:
    """Per-scan statistics (``timings_ms`` per stage) of ``semslam detect`` on ``run``'s mission and database."""
    from semslam.recognition import load_database
    from semslam.run.dive import detect_dive

    db = load_database(run / "db.npz")
    outcome = detect_dive(str(run / "mission"), db=db, pipeline_config=_pipeline_config(preset, config), seed=seed,
                          up_from_attitude=up_from_attitude)
    return list(outcome.scans)


def print_table(scans: list[dict], period_s: float, slowest: int) -> None:
    print(f"{len(scans)} scans; per scan (ms):")
    print(f"{'stage':<14}{'median':>10}{'p90':>10}{'max':>10}{'sum (s)':>10}")
    for stage in STAGES:
        ms = np.array([s["timings_ms"].get(stage, 0.0) for s in scans], dtype=float)
        if not ms.any():
            continue
        print(f"{stage:<14}{np.median(ms):>10.1f}{np.percentile(ms, 90):>10.1f}{ms.max():>10.1f}{ms.sum() / 1e3:>10.2f}")
    total = np.array([s["timings_ms"]["total"] for s in scans], dtype=float)
    within = int(np.sum(total <= period_s * 1e3))
    print(f"within the scan period ({period_s:.2f} s): {within} of {len(scans)} scans")
    order = np.argsort(-total)[:slowest]
    print(f"slowest {len(order)} scans (ms):")
    print("scan  clusters  dets  " + "  ".join(f"{s[:6]:>6}" for s in STAGES))
    for i in order:
        s = scans[i]
        row = "  ".join(f"{s['timings_ms'].get(k, 0.0):>6.0f}" for k in STAGES)
        print(f"{s['scan_id']:>4}  {s['n_clusters']:>8}  {s['n_detections']:>4}  {row}")


def profile_dive(run: Path, *, top: int = 30, **kw) -> None:
    """cProfile of the same :func:`time_dive` with every scan recognised in this thread (``lookahead`` 0: the
    detections are the same bit for bit), the top functions by cumulative and by own time."""
    import cProfile
    import pstats

    import semslam.run.dive as dive

    lookahead, dive.LOOKAHEAD = dive.LOOKAHEAD, 0
    prof = cProfile.Profile()
    try:
        prof.runcall(time_dive, run, **kw)
    finally:
        dive.LOOKAHEAD = lookahead
    for key in ("cumulative", "tottime"):
        pstats.Stats(prof, stream=sys.stdout).strip_dirs().sort_stats(key).print_stats(top)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", default="runs/demo", help="a demo run directory (mission/ and db.npz)")
    ap.add_argument("--preset", default=None,
                    help="named settings (default, cluttered, seabed, depth-camera; default: the --config file's)")
    ap.add_argument("--config", default=None, help="a configuration file on top of the preset")
    ap.add_argument("--up-from-attitude", action="store_true", help="as `semslam run --up-from-attitude`")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--slowest", type=int, default=8, help="rows of the slowest scans' table")
    ap.add_argument("--profile", type=int, default=0, metavar="N",
                    help="then profile the dive again in one thread and print the N top functions")
    args = ap.parse_args(argv)
    run = Path(args.run)
    if not (run / "db.npz").is_file() or not (run / "mission").is_dir():
        print(f"{run} is not a demo run directory (mission/ and db.npz): run `make demo`, or "
              "benchmarks/unseen_parts.py --out OUT and pass OUT/seed_0", file=sys.stderr)
        return 2
    from semslam.cli._inputs import load_dataset

    period_s = float(np.median(np.diff([s.start_stamp_s for s in load_dataset(str(run / "mission")).scans])))
    kw = dict(preset=args.preset, config=args.config, up_from_attitude=args.up_from_attitude, seed=args.seed)
    preset = args.preset or "of the config file"
    print(f"{run}: preset {preset}{' + ' + args.config if args.config else ''}"
          f"{', up from the attitude' if args.up_from_attitude else ''}; {_load()}")
    t0 = time.perf_counter()
    scans = time_dive(run, **kw)
    print(f"detect_dive: {time.perf_counter() - t0:.1f} s wall; {_load()}")
    print_table(scans, period_s, args.slowest)
    if args.profile:
        profile_dive(run, top=args.profile, **kw)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
