"""Scan-to-detections latency, stage by stage, against a PCL pipeline with the same parameters.

    .venv/bin/python benchmarks/pipeline.py [--scans 20] [--no-pcl] [--seed 0]

Inputs: ``--scans`` simulated laser scans of the four-object tank scene (~100k points each, the default
mission's scanner) and the real scenes of ../shared/data/real (mug, milk cartoon). Ours: the
:class:`semslam.pipeline.ScanRecognizer` with the built-in database (stage timings from its result: read is
timed separately). PCL (``pcl_ref`` from ../shared/pcl_oracle): ``segment`` (voxel grid, RMSAC plane,
Euclidean clusters, ESF of every cluster), ``vfh`` on every cluster (normals + VFH) and ``register``
(FPFH + SampleConsensusPrerejective + ICP) of the matched model view onto every recognised cluster, all on the
same files with the same parameters; PCL has no chi-square matcher, so matching is ours on both sides.

Prints a markdown table of medians (ms) and the ratio PCL / ours (> 1: we are faster), then the cold-start
latency (first scan of a fresh process, numba cache warm from installation).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SHARED = Path(os.environ.get("SEMSLAM_SHARED", ROOT.parent / "shared"))
PCL_REF = os.environ.get("PCL_REF", str(Path.home() / ".cache/pcl_oracle/pcl_ref"))
STAGES = ("read", "segmentation", "descriptors", "matching", "pose", "total")


def _pcl(*args) -> list[dict]:
    out = subprocess.run([PCL_REF, *map(str, args)], capture_output=True, text=True, timeout=600)
    if out.returncode != 0:
        raise RuntimeError(out.stderr[-500:])
    return [json.loads(line) for line in out.stdout.splitlines() if line.startswith("{")]


def _ours(recognizer, path: Path, seed: int) -> tuple[dict, object]:
    from semslam.io import read_point_cloud

    t0 = time.perf_counter()
    cloud = read_point_cloud(path)
    read_ms = (time.perf_counter() - t0) * 1e3
    res = recognizer.recognize(cloud, seed=seed)
    t = dict(res.timings_ms)
    t["read"] = read_ms
    t["total"] = t["total"] + read_ms
    return t, res


def _pcl_times(path: Path, res, db, tmp: Path, cfg) -> dict:
    from semslam.cloud import PointCloud
    from semslam.io import write_point_cloud

    seg = cfg.segmentation
    rows = _pcl("segment", path, seg.distance_threshold_m, seg.cluster_tolerance_m, seg.min_cluster_size,
                seg.max_cluster_size or 10**9, 5, seg.voxel_leaf_m or 0)
    r = rows[-1]
    t = {"read": float(_pcl("read", path, 1)[-1]["ms"]), "segmentation": r["plane_ms"] + r["cluster_ms"],
         "descriptors": r["esf_all_ms"], "matching": 0.0, "pose": 0.0}
    for k, cluster in enumerate(res.segmentation.clusters):
        cpath = tmp / f"cluster_{k}.pcd"
        write_point_cloud(cpath, PointCloud(cluster.points_xyz_m), encoding="binary")
        v = _pcl("vfh", cpath, db.params.get("normal_radius_m", 0.01), 1)
        t["descriptors"] += sum(x.get("normals_ms", 0) + x.get("ms", 0) for x in v)
    for k, outcome in enumerate(res.clusters):
        if outcome.detection is None:
            continue
        vi = int(outcome.detection.extras["view_index"])
        mpath = tmp / f"model_{vi}.pcd"
        if not mpath.exists():
            write_point_cloud(mpath, PointCloud(db.view_points(vi)), encoding="binary")
        reg = _pcl("register", mpath, tmp / f"cluster_{k}.pcd", cfg.pose.voxel_m)
        t["pose"] += sum(float(x.get("total_ms", x.get("ms", 0.0))) for x in reg if "total_ms" in x or "ms" in x)
    t["total"] = sum(t[s] for s in STAGES[:-1])
    return t


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scans", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-pcl", action="store_true")
    args = ap.parse_args()

    from semslam.io import write_point_cloud
    from semslam.pipeline import ScanRecognizer
    from semslam.recognition import build_database
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, builtin_view_clouds, simulate_mission

    views, classes = builtin_view_clouds(seed=args.seed)
    db = build_database(views, classes, seed=args.seed)
    recognizer = ScanRecognizer(db)
    t0 = time.perf_counter()
    recognizer.warm_up()
    warm_ms = (time.perf_counter() - t0) * 1e3
    use_pcl = not args.no_pcl and os.access(PCL_REF, os.X_OK)
    mission = simulate_mission(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1)), seed=args.seed)
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        inputs = []
        step = max(1, len(mission.scans) // max(args.scans, 1))
        for rec in mission.scans[::step][: args.scans]:
            p = tmp / f"scan_{rec.scan_id:04d}.pcd"
            write_point_cloud(p, mission.load_scan(rec.scan_id), encoding="binary_compressed")
            inputs.append(("simulated", p))
        for name in ("table_scene_mug_stereo_textured", "milk_cartoon_all_small_clorox"):
            p = SHARED / "data" / "real" / f"{name}.pcd"
            if p.is_file():
                inputs.append((name, p))
        results: dict[str, dict[str, list]] = {}
        for group, path in inputs:
            ours, res = _ours(recognizer, path, args.seed)
            results.setdefault(group, {"ours": [], "pcl": [], "points": []})
            results[group]["ours"].append(ours)
            results[group]["points"].append(res.segmentation.n_input_points)
            if use_pcl:
                results[group]["pcl"].append(_pcl_times(path, res, db, tmp, recognizer.config))
    print(f"pose models prepared once per class in {warm_ms:.0f} ms (not in the per-scan figures)\n")
    print("| input | n | points | stage | ours median (ms) | PCL median (ms) | PCL / ours |")
    print("|---|---|---|---|---|---|---|")
    for group, r in results.items():
        for stage in STAGES:
            ours = statistics.median(t[stage] for t in r["ours"])
            pcl = statistics.median(t[stage] for t in r["pcl"]) if r["pcl"] else float("nan")
            ratio = pcl / ours if ours > 0 and np.isfinite(pcl) else float("nan")
            print(f"| {group} | {len(r['ours'])} | {int(np.median(r['points']))} | {stage} | {ours:.1f} | "
                  f"{pcl:.1f} | {ratio:.2f} |")
    cold = subprocess.run([sys.executable, "-c", (
        "import time; t0=time.perf_counter();"
        "from semslam.simulation import builtin_view_clouds, simulate_mission, SimulatorConfig, TrajectoryConfig;"
        "from semslam.recognition import build_database; from semslam.pipeline import ScanRecognizer;"
        f"v,c=builtin_view_clouds(seed={args.seed}); db=build_database(v,c,seed={args.seed});"
        f"m=simulate_mission(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1)), seed={args.seed});"
        "s=m.load_scan(m.scans[len(m.scans)//2].scan_id); r=ScanRecognizer(db); t1=time.perf_counter();"
        "r.recognize(s, seed=0); print((time.perf_counter()-t1)*1e3)")], capture_output=True, text=True, cwd=ROOT)
    print(f"\ncold start: first scan of a fresh process {cold.stdout.strip() or cold.stderr[-300:]} ms "
          "(database built in that process; includes lazy pose-model preparation)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
