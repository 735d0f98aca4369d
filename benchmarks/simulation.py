"""Simulator benchmark: time of the default mission (all scans and sensors), navigation-only missions,
and single scans of the four-object scene. Prints a markdown table with wall-clock and CPU (process)
times: on a loaded machine the CPU column is the steadier one.

    .venv/bin/python benchmarks/simulation.py [--quick] [--repeat N]
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
    simulate_dataset,
)
from semslam.simulation._ray_kernels import RayCaster
from semslam.simulation.simulate import mission_trajectory


def _time(fn, repeat: int = 1) -> tuple[float, float]:
    """Best wall-clock and best CPU time (s) of ``repeat`` calls."""
    wall = cpu = np.inf
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        fn()
        wall, cpu = min(wall, time.perf_counter() - w), min(cpu, time.process_time() - c)
    return wall, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="quick config instead of the default mission")
    ap.add_argument("--repeat", type=int, default=3, help="repeats of the mission (best kept)")
    args = ap.parse_args()
    cfg = SimulatorConfig.quick() if args.quick else SimulatorConfig()
    rows = []
    rows.append(("build the four meshes (once per process)", *_time(builtin_objects), ""))
    rows.append(("warm-up: tiny mission (numba kernels loaded from cache)",
                 *_time(lambda: simulate_dataset(SimulatorConfig.quick(), seed=0)), ""))
    m = None

    def full():
        nonlocal m
        m = simulate_dataset(cfg, seed=0)

    wall, cpu = _time(full, args.repeat)
    rows.append(("mission, all scans and sensors", wall, cpu,
                 f"{len(m.scans)} scans, {np.mean([s.n_points for s in m.scans]):.0f} points/scan, {m.duration_s:.0f} s, "
                 f"{len(m.scans) / wall:.1f} scans/s"))
    rows.append(("mission, navigation only (with_scans=False)",
                 *_time(lambda: simulate_dataset(cfg, seed=1, with_scans=False), 3), ""))
    world = build_world(cfg.world, builtin_objects(), seed=0)
    traj = mission_trajectory(world, cfg, np.random.default_rng(0))
    scanner = LaserScanner(cfg.scanner)
    caster = RayCaster(world.scene)
    rows.append(("ray caster of the world (Embree scenes, split)", *_time(lambda: RayCaster(world.scene).split()), ""))
    n = 20
    # the start that sees an object closest to the optical axis at mid-scan
    cand = np.arange(0.0, traj.duration_s - 1.0, 0.5)
    mids = traj.sample(cand + scanner.duration_s / 2).T_world_vehicle() @ scanner.T_vehicle_scanner.matrix
    centres = np.array([o.T_world_object.translation_m for o in world.objects])
    rel = centres[None] - mids[:, None, :3, 3]  # (starts, objects, 3) world
    cos_axis = np.einsum("soi,si->so", rel, mids[:, :3, 2]) / np.linalg.norm(rel, axis=2)
    best = cand[int(np.argmax(cos_axis.max(axis=1)))]
    starts = {"single scan of the scene": 2.0, "single scan over the objects": best}
    for name, start in starts.items():
        stamps = scanner.line_stamps(start)
        T = traj.sample(stamps).T_world_vehicle() @ scanner.T_vehicle_scanner.matrix
        wall, cpu = _time(lambda: [scanner.scan(caster, T, seed=i, face_instance=world.face_instance) for i in range(n)])
        cloud = scanner.scan(caster, T, seed=0, face_instance=world.face_instance).cloud
        rows.append((name, wall / n, cpu / n,
                     f"{n / wall:.1f} scans/s ({n / cpu:.1f} per CPU s), {cloud.n_points} points "
                     f"({np.sum(cloud.fields['instance'] >= 0)} on objects), "
                     f"{cfg.scanner.n_lines * cfg.scanner.points_per_line} rays"))
    print("| step | time (s) | CPU (s) | notes |\n|---|---:|---:|---|")
    for name, sec, cpu, note in rows:
        print(f"| {name} | {sec:.3f} | {cpu:.3f} | {note} |")


if __name__ == "__main__":
    main()
