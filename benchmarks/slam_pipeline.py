"""SLAM on the real recognition pipeline's detections, not the truth-based source.

Missions ``--first`` .. ``--first + --missions - 1`` are simulated with their scans; every scan is recognised by
``ScanRecognizer`` on the built-in database (reliable detections only, as the demo does); every SLAM mode then runs
on the same detections. Prints per-mission ATE (online / smoothed), the means and the paired differences.

Run: ``.venv/bin/python benchmarks/slam_pipeline.py --missions 10`` (~10 s per mission on 2 cores).
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from semslam.pipeline import ScanRecognizer
from semslam.pipeline.dataset_detection import detect_dataset
from semslam.simulation.builtin_db import builtin_database
from semslam.simulation import simulate_dataset
from semslam.simulation.truth_slam import builtin_symmetries
from semslam.slam import MODES
from semslam.run import run_slam



def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--missions", type=int, default=10)
    args = ap.parse_args()
    recognizer = ScanRecognizer(builtin_database(seed=0))
    recognizer.warm_up()
    ate = {m: [] for m in MODES}
    print("| seed | " + " | ".join(f"{m} online / smoothed (m)" for m in MODES) + " |")
    print("|---" * (len(MODES) + 1) + "|")
    for seed in range(args.first, args.first + args.missions):
        mission = simulate_dataset(seed=seed)
        dets = detect_dataset(mission, recognizer, seed=seed).detections_by_scan  # reliable only, as the demo
        cells = []
        for mode in MODES:
            r = run_slam(mission, dets, mode=mode, symmetries=builtin_symmetries())
            ate[mode].append((r.metrics["ate_rmse_m"], r.metrics["smoother"]["ate_rmse_m"]))
            cells.append(f"{ate[mode][-1][0]:.4f} / {ate[mode][-1][1]:.4f}")
        print(f"| {seed} | " + " | ".join(cells) + " |", flush=True)
    a = {m: np.array(v) for m, v in ate.items()}
    print("| mean | " + " | ".join(f"**{a[m][:, 0].mean():.4f}** / {a[m][:, 1].mean():.4f}" for m in MODES) + " |")
    n = args.missions
    for mode, base in (("pose", "position"), ("pose+heading", "pose"), ("pose", "dr")):
        d = a[mode][:, 0] - a[base][:, 0]
        se = d.std(ddof=1) / math.sqrt(n) if n > 1 else float("nan")
        print(f"\n{mode} - {base}: {1000 * d.mean():+.2f} +- {1000 * se:.2f} mm (online, paired), "
              f"not worse in {int((d <= 0).sum())}/{n}; DR / {mode} = {a['dr'][:, 0].mean() / a[mode][:, 0].mean():.2f}")


if __name__ == "__main__":
    main()
