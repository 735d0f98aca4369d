"""Simulator benchmark: time of the default mission (all scans and sensors), navigation-only missions,
and single scans of the four-object scene. Prints a markdown table.

    .venv/bin/python benchmarks/simulation.py [--quick]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from semslam.simulation import (
    LaserScanner,
    SimulatorConfig,
    build_world,
    builtin_objects,
    simulate_mission,
)
from semslam.simulation._ray_kernels import RayCaster
from semslam.simulation.simulate import mission_trajectory


def _time(fn, repeat: int = 1) -> float:
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="quick config instead of the default mission")
    args = ap.parse_args()
    cfg = SimulatorConfig.quick() if args.quick else SimulatorConfig()
    rows = []
    t = time.perf_counter()
    builtin_objects()
    rows.append(("build the four meshes (once per process)", time.perf_counter() - t, ""))
    m = None

    def full():
        nonlocal m
        m = simulate_mission(cfg, seed=0)

    rows.append(("mission, all scans and sensors", _time(full),
                 f"{len(m.scans)} scans, {np.mean([s.n_points for s in m.scans]):.0f} points/scan, {m.duration_s:.0f} s"))
    rows.append(("mission, navigation only (with_scans=False)", _time(lambda: simulate_mission(cfg, seed=1, with_scans=False), 3), ""))
    world = build_world(cfg.world, builtin_objects(), seed=0)
    traj = mission_trajectory(world, cfg, np.random.default_rng(0))
    scanner = LaserScanner(cfg.scanner)
    caster = RayCaster(world.scene)
    stamps = scanner.line_stamps(2.0)
    T = traj.sample(stamps).T_world_vehicle() @ scanner.T_vehicle_scanner.matrix
    n = 20
    dt = _time(lambda: [scanner.scan(caster, T, seed=i, face_instance=world.face_instance) for i in range(n)]) / n
    pts = scanner.scan(caster, T, seed=0, face_instance=world.face_instance).cloud.n_points
    rows.append(("single scan of the scene", dt, f"{1 / dt:.1f} scans/s, {pts} points, {cfg.scanner.n_lines * cfg.scanner.points_per_line} rays"))
    print("| step | time (s) | notes |\n|---|---:|---|")
    for name, sec, note in rows:
        print(f"| {name} | {sec:.3f} | {note} |")


if __name__ == "__main__":
    main()
