"""How low the online pose error of `real_path.py`'s dives could go with a perfect recogniser (issue 27's analysis).

Not a figure of semslam: an oracle to judge its figures by. The dives are `real_path.py`'s (the same seeds give the
same missions: tank depth drawn in [4.5, 11.5] m, the papers' 3 loops, scans every 0.5 s), simulated without scans.
The detections are the simulator's truth (:func:`semslam.simulation.detections.simulate_detections`): every object
whose centre lies in a cone about the scanner's optical axis, at every scan, reported with the noise and the
covariance given (``--sigma-mm``, ``--sigma-deg``), none missed, none false. They go through the runner a bag goes
through (:func:`semslam.run.open_dive` of the mission, :func:`semslam.run.run_stream`, modes dr and pose, the EKF, no
position fix: the local frame); the error is the ATE after the 4-DoF alignment (yaw + translation), as in
`real_path.py`. Cones: the laser's footprint is a 50 x 50 degree square, so a 50-degree cone lies inside it (fewer
sightings than the scanner could give) and a 66.8-degree cone around it (more: objects cut by its border counted
whole).

    .venv/bin/python benchmarks/slam_bound.py --runs 10 --seed 100 [--cones 50,66.8] [--sigma-mm 0.3 --sigma-deg 0.1]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from semslam.evaluation.slam_run import ate_4dof  # noqa: E402
from semslam.run import open_dive, run_stream  # noqa: E402
from semslam.simulation import SimulatorConfig, simulate_dataset  # noqa: E402
from semslam.simulation.detections import TruthDetectionConfig, simulate_detections  # noqa: E402
from semslam.simulation.truth_slam import builtin_symmetries  # noqa: E402


def mission(seed: int, loops: int = 3):
    """`real_path.make_dive`'s mission (the same draws), without scans and without fixes."""
    rng = np.random.default_rng(seed)
    base = SimulatorConfig()
    cfg = base.replace(world=dataclasses.replace(base.world, tank_depth_m=float(rng.uniform(4.5, 11.5))),
                       trajectory=dataclasses.replace(base.trajectory, loops=loops))
    return simulate_dataset(cfg, seed=seed, with_scans=False, scan_interval_s=0.5, progress=False)


def one_run(m, seed: int, cone_deg: float, sigma_m: float, sigma_rad: float) -> dict:
    syms = builtin_symmetries()
    cfg = TruthDetectionConfig(scan_rate_hz=2.0, fov_rad=float(np.radians(cone_deg)), position_sigma_m=sigma_m,
                               rotation_sigma_rad=sigma_rad)
    dets = simulate_detections(m, cfg, seed=seed, symmetries=syms)
    out = run_stream(open_dive(m, scans=False), modes=("dr", "pose"), detections_by_scan=dets, symmetries=syms)
    dr, pose = out.results["dr"], out.results["pose"]
    return {"dr": ate_4dof(dr.position_ned_m, m.truth.interpolate_position(dr.stamps_s)),
            "pose": ate_4dof(pose.position_ned_m, m.truth.interpolate_position(pose.stamps_s)),
            "n_detections": sum(map(len, dets.values()))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--cones", default="50,66.8", help="full cone angles (degrees), comma-separated")
    ap.add_argument("--sigma-mm", type=float, default=0.3, help="position noise per axis (mm)")
    ap.add_argument("--sigma-deg", type=float, default=0.1, help="rotation noise per axis (degrees)")
    args = ap.parse_args()
    cones = [float(c) for c in args.cones.split(",")]
    rows = {c: [] for c in cones}
    for k in range(args.runs):
        seed = args.seed + k
        m = mission(seed)
        for c in cones:
            r = one_run(m, seed, c, args.sigma_mm * 1e-3, float(np.radians(args.sigma_deg)))
            rows[c].append(r)
            print(f"seed {seed} cone {c:g} deg: pose {r['pose']:.4f} m, DR {r['dr']:.4f} m, "
                  f"{r['n_detections']} detections", flush=True)
    print(f"\nperfect detections ({args.sigma_mm:g} mm / {args.sigma_deg:g} deg), seeds {args.seed}-"
          f"{args.seed + args.runs - 1}, ATE after the 4-DoF alignment (means over runs)\n")
    print("| cone (deg) | detections per dive | pose ATE (m) | DR ATE (m) | DR / pose | median per-run ratio |")
    print("|---|---|---|---|---|---|")
    for c in cones:
        pose = np.array([r["pose"] for r in rows[c]])
        dr = np.array([r["dr"] for r in rows[c]])
        n = np.mean([r["n_detections"] for r in rows[c]])
        print(f"| {c:g} | {n:.0f} | {pose.mean():.4f} | {dr.mean():.4f} | {dr.mean() / pose.mean():.1f}x | "
              f"{np.median(dr / pose):.1f}x |")


if __name__ == "__main__":
    main()
