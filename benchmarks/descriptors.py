"""Descriptor timings, ours vs PCL 1.13 (pcl_ref), on clusters of 400-5000 points.

    .venv/bin/python benchmarks/descriptors.py [--reps 7]
    .venv/bin/python benchmarks/descriptors.py --describe-ab [--reps 10]

Prints a markdown table: our cold (first call in this process: numba cache load / compile) time,
our median and best of REPS, PCL's best of REPS (pcl_ref's own timer, computation only), and the
ratio PCL best / our best (> 1: we are faster). ESF uses our default numpy sampler; "vfh" is normals
(radius) + VFH; "fpfh" is FPFH only (normals precomputed) as pcl_ref times it.

``--describe-ab``: the pipeline's describe step (voxel grid, ESF, normals, VFH) on the clusters of 20 simulated
scans that pass the size test, serial against normals + VFH on a helper thread
(``ViewDatabase.describe(..., concurrent=)``), interleaved in one process (REPS rounds, the order
alternating), medians per cluster.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = Path(os.environ.get("SEMSLAM_SHARED", ROOT.parent / "shared")) / "data" / "real"
PCL_REF = os.environ.get("PCL_REF", str(Path.home() / ".cache/pcl_oracle/pcl_ref"))


def pcl(*args: str) -> list[dict]:
    out = subprocess.run([PCL_REF, *args], check=True, capture_output=True, text=True).stdout
    return [json.loads(line) for line in out.splitlines() if line.strip()]


def timed(fn, reps: int) -> tuple[float, float, float]:
    t = time.perf_counter()
    fn()
    cold = time.perf_counter() - t
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return cold * 1e3, float(np.median(ts)) * 1e3, min(ts) * 1e3


def main() -> None:
    from semslam.cloud import PointCloud
    from semslam.descriptors import compute_esf, compute_vfh, estimate_normals
    from semslam.descriptors.fpfh import compute_fpfh
    from semslam.io import read_point_cloud, write_point_cloud

    ap = argparse.ArgumentParser()
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--describe-ab", action="store_true")
    args = ap.parse_args()
    reps = args.reps
    if args.describe_ab:
        describe_ab(reps)
        return
    rng = np.random.default_rng(0)
    milk = read_point_cloud(REAL / "milk.pcd").points_xyz_m
    chef = read_point_cloud(REAL / "chef.pcd").points_xyz_m
    bun0 = read_point_cloud(REAL / "bun0.pcd").points_xyz_m
    clusters = {
        "bun0 (397)": bun0,
        "milk 1000": milk[rng.choice(len(milk), 1000, replace=False)],
        "milk 2500": milk[rng.choice(len(milk), 2500, replace=False)],
        "milk 5000": milk[rng.choice(len(milk), 5000, replace=False)],
        "chef (5092)": chef,
    }
    # normal radius / FPFH radius per cluster (about 3 and 6 point spacings)
    radii = {"bun0 (397)": (0.01, 0.02), "chef (5092)": (0.008, 0.016)}
    tmp = Path(tempfile.mkdtemp(prefix="semslam_bench_"))
    rows = []
    first = True
    for name, pts in clusters.items():
        nr, fr = radii.get(name, (0.01, 0.02))
        path = tmp / (name.split()[0] + f"_{len(pts)}.pcd")
        write_point_cloud(path, PointCloud(pts.astype(np.float32).astype(float)), encoding="binary")
        p32 = pts.astype(np.float32).astype(float)

        cold, med, best = timed(lambda: compute_esf(p32, seed=1), reps)
        ref = pcl("esf", str(path), str(reps))[0]["ms"]
        rows.append((name, "esf", cold if first else None, med, best, ref))

        def vfh():
            n = estimate_normals(p32, radius_m=nr).normals_xyz
            return compute_vfh(p32, n)

        cold, med, best = timed(vfh, reps)
        out = pcl("vfh", str(path), str(nr), str(reps))
        ref = out[0]["normals_ms"] + out[1]["ms"]
        rows.append((name, f"normals r={nr} + vfh", cold if first else None, med, best, ref))

        normals = estimate_normals(p32, radius_m=nr).normals_xyz
        cold, med, best = timed(lambda: compute_fpfh(p32, normals, radius_m=fr), reps)
        ref = min(pcl("fpfh", str(path), str(nr), str(fr))[0]["ms"] for _ in range(3))
        rows.append((name, f"fpfh r={fr}", cold if first else None, med, best, ref))
        first = False

    print(f"| cluster | descriptor | ours cold ms | ours median ms | ours best ms | PCL best ms | PCL/ours |")
    print("|---|---|---|---|---|---|---|")
    for name, what, cold, med, best, ref in rows:
        c = f"{cold:.1f}" if cold is not None else ""
        print(f"| {name} | {what} | {c} | {med:.2f} | {best:.2f} | {ref:.2f} | {ref / best:.2f} |")


def describe_ab(reps: int) -> None:
    from semslam.pipeline import ScanRecognizer
    from semslam.recognition import build_database
    from semslam.recognition.plausibility import cluster_extent_m
    from semslam.segmentation.scene import segment_scene
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, builtin_view_clouds, simulate_dataset

    views, classes = builtin_view_clouds(seed=0)
    db = build_database(views, classes, seed=0)
    rec = ScanRecognizer(db)
    mission = simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1)), seed=0)
    step = max(1, len(mission.scans) // 20)
    clusters = [c for r in mission.scans[::step][:20]
                for c in segment_scene(mission.load_scan(r.scan_id), rec.config.segmentation, seed=0).clusters]
    limit = rec.max_plausible_extent_m()
    clusters = [c for c in clusters if cluster_extent_m(c.points_xyz_m)[0] <= limit]
    times: dict[bool, list[float]] = {False: [], True: []}
    for flag in (False, True):  # warm both paths
        db.describe(clusters[0], seed=0, concurrent=flag)
    for r in range(max(reps, 1)):
        for flag in ((False, True) if r % 2 == 0 else (True, False)):
            for k, c in enumerate(clusters):
                t = time.perf_counter()
                db.describe(c, seed=k, concurrent=flag)
                times[flag].append((time.perf_counter() - t) * 1e3)
    print(f"| describe, {len(clusters)} clusters x {reps} | serial median ms | concurrent median ms | serial / concurrent |")
    print("|---|---|---|---|")
    a, b = float(np.median(times[False])), float(np.median(times[True]))
    print(f"| voxel + ESF + normals + VFH | {a:.2f} | {b:.2f} | {a / b:.2f} |")


if __name__ == "__main__":
    main()
