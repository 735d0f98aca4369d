"""Map reuse across dives (issue #28): dive 2 over the same structure with dive 1's map (``--survey map.json``)
against dive 2 alone.

Each run: dive 1 (seed s) and dive 2 (seed s + 1000, the same world: ``world_seed=s``), each a one-loop dive with
``--gps`` surface fixes before it (a per-dive GPS error of ~2 m per axis): both live in the world frame about the
site's geodetic origin. Dive 1 runs in pose mode and writes its map (``map.json``, with covariances); dive 2 runs
alone and with that map as its prior, through the same runner as ``semslam run`` (truth-based detections:
:func:`semslam.simulation.truth_slam.run_truth_slam`). Reported: dive 2's online ATE (world frame, unaligned:
what a vehicle returning to the structure gets) and after the 4-DoF alignment, with and without the map; the time
of its first landmark update against its first detection of an object of the map.

    nice -n 5 .venv/bin/python benchmarks/map_reuse.py --runs 10 --seed 200
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from semslam.simulation import SimulatorConfig, simulate_dataset  # noqa: E402
from semslam.simulation.truth_slam import run_truth_slam  # noqa: E402
from semslam.slam import read_survey  # noqa: E402
from semslam.run.export import write_landmarks_json  # noqa: E402


def one(seed: int, gps: int, work: Path) -> dict:
    base = SimulatorConfig()
    cfg = base.replace(trajectory=dataclasses.replace(base.trajectory, loops=1),
                       fixes=dataclasses.replace(base.fixes, gps_count=gps))
    d1 = simulate_dataset(cfg, seed=seed, with_scans=False)
    d2 = simulate_dataset(cfg, seed=seed + 1000, world_seed=seed, with_scans=False)
    r1 = run_truth_slam(d1, mode="pose", seed=seed)
    path = write_landmarks_json(r1, work / f"map{seed}.json")
    alone = run_truth_slam(d2, mode="pose", seed=seed + 1000)
    reuse = run_truth_slam(d2, mode="pose", seed=seed + 1000, survey=read_survey(path))
    first_det = min((r["stamp_s"] for r in reuse.update_log if r["kind"] == "landmark"), default=np.nan)
    first_up = min((r["stamp_s"] for r in reuse.update_log if r["kind"] == "landmark" and r.get("accepted")),
                   default=np.nan)
    return {"seed": seed, "ate_alone": alone.metrics["ate_rmse_m"], "ate_reuse": reuse.metrics["ate_rmse_m"],
            "ate4_alone": alone.metrics["ate_4dof_rmse_m"], "ate4_reuse": reuse.metrics["ate_4dof_rmse_m"],
            "map1_landmarks": len(r1.landmarks), "landmarks_alone": len(alone.landmarks),
            "landmarks_reuse": len(reuse.landmarks), "first_detection_s": first_det, "first_update_s": first_up,
            "launch_alone": alone.metrics["launch_error_m"], "nees_reuse": reuse.metrics["nees_position_mean"],
            "nees_alone": alone.metrics["nees_position_mean"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--seed", type=int, default=200)
    ap.add_argument("--gps", type=int, default=10)
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.runs):
            r = one(args.seed + k, args.gps, Path(tmp))
            rows.append(r)
            print(f"seed {r['seed']}: online ATE alone {r['ate_alone']:.3f} m, with map {r['ate_reuse']:.3f} m; 4-DoF "
                  f"{r['ate4_alone']:.4f} / {r['ate4_reuse']:.4f}; first detection {r['first_detection_s']:.1f} s, "
                  f"first landmark update {r['first_update_s']:.1f} s; landmarks {r['landmarks_alone']} / "
                  f"{r['landmarks_reuse']} (map {r['map1_landmarks']})", flush=True)
    a = np.array([[r["ate_alone"], r["ate_reuse"], r["ate4_alone"], r["ate4_reuse"], r["nees_alone"],
                   r["nees_reuse"]] for r in rows])
    same = sum(abs(r["first_update_s"] - r["first_detection_s"]) < 1e-9 for r in rows)
    print("\n| runs | online ATE alone (m) | with dive 1's map (m) | lower with the map | 4-DoF alone | 4-DoF with map "
          "| vehicle NEES alone / with map | first update at the first detection |")
    print("|---|---|---|---|---|---|---|---|")
    print(f"| {len(rows)} | {a[:, 0].mean():.3f} | {a[:, 1].mean():.3f} | {int(np.sum(a[:, 1] < a[:, 0]))}/{len(rows)} | "
          f"{a[:, 2].mean():.4f} | {a[:, 3].mean():.4f} | {a[:, 4].mean():.2f} / {a[:, 5].mean():.2f} | "
          f"{same}/{len(rows)} |")


if __name__ == "__main__":
    main()
