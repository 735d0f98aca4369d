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
from semslam.recognition.builtin import builtin_database
from semslam.simulation import simulate_mission
from semslam.simulation.truth import point_stamps_s
from semslam.slam.runner import run_slam

MODES = ("dr", "position", "pose", "pose+heading")


def pipeline_detections(mission, recognizer: ScanRecognizer, seed: int) -> dict:
    """Reliable detections per scan id, each stamped as the demo stamps them."""
    out = {}
    for rec in mission.scans:
        cloud = mission.load_scan(rec.scan_id)
        res = recognizer.recognize(cloud, seed=seed * 100003 + rec.scan_id, stamp_s=rec.end_stamp_s,
                                   scan_id=rec.scan_id, point_stamps_s=point_stamps_s(mission, rec, cloud))
        kept = [d for d in res.detections if d.reliable]
        if kept:
            out[rec.scan_id] = kept
    return out


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
        mission = simulate_mission(seed=seed)
        dets = pipeline_detections(mission, recognizer, seed)
        cells = []
        for mode in MODES:
            r = run_slam(mission, dets, mode=mode, seed=seed)
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
