"""Scan-to-detections latency, stage by stage, against a PCL pipeline with the same parameters.

    .venv/bin/python benchmarks/pipeline.py [--scans 20] [--reps 1] [--no-pcl] [--seed 0] [--pose-set NAME=VALUE ...]

Inputs: ``--scans`` simulated laser scans of the four-object tank scene (~100k points each, the default
mission's scanner) and the real scenes of ../shared/data/real (mug, milk cartoon). Ours: the
:class:`semslam.pipeline.ScanRecognizer` with the built-in database (stage timings from its result: read is
timed separately). PCL (``pcl_ref`` from ../shared/pcl_oracle): ``segment`` (voxel grid, RMSAC plane,
Euclidean clusters, ESF of every cluster), ``vfh`` on every cluster (normals + VFH) and ``register``
(FPFH + SampleConsensusPrerejective + ICP) of the matched model view onto every recognised cluster, all on the
same files with the same parameters; PCL has no chi-square matcher, so matching is ours on both sides.

Prints a markdown table of medians (ms) and the ratio PCL / ours (> 1: we are faster), then the cold-start
latency (imports, then the first scan of a fresh process: the recognizer is built and the pose model of the
recognised class prepared lazily; numba cache warm from installation). ``--pose-set`` overrides PoseConfig
fields, e.g. the previous pose search: ``--pose-set icp_backend=small_gicp n_coarse_rotations=0``.
``--reps R`` runs our pipeline R times on every input (same seed, same result) and takes the medians over all
the runs, to tame the noise of a shared machine (PCL runs once per input). "other" is the per-cluster glue:
total minus read, segmentation, descriptors, matching and pose.
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
        t["pose"] += sum(float(x.get(key, 0.0)) for x in reg for key in ("feat_ms", "sac_ms", "icp_ms"))
    t["total"] = sum(t[s] for s in STAGES[:-1])
    return t


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scans", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--reps", type=int, default=1, help="runs of our pipeline per input (medians over all runs)")
    ap.add_argument("--no-pcl", action="store_true")
    ap.add_argument("--pose-set", nargs="*", default=[], metavar="NAME=VALUE",
                    help="PoseConfig overrides, e.g. --pose-set icp_backend=small_gicp n_coarse_rotations=0 (before)")
    args = ap.parse_args()

    from semslam.io import write_point_cloud
    from semslam.pipeline import ScanRecognizer
    from semslam.recognition import build_database
    from semslam.recognition.storage import save_database
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, builtin_view_clouds, simulate_dataset

    from semslam.pipeline import PipelineConfig
    from semslam.pose import PoseConfig

    overrides = {}
    for item in args.pose_set:
        name, _, value = item.partition("=")
        default = getattr(PoseConfig(), name)
        overrides[name] = value if isinstance(default, str) else type(default)(value)
    views, classes = builtin_view_clouds(seed=args.seed)
    db = build_database(views, classes, seed=args.seed)
    recognizer = ScanRecognizer(db, PipelineConfig(pose=PoseConfig(**overrides)))
    t0 = time.perf_counter()
    recognizer.warm_up()
    warm_ms = (time.perf_counter() - t0) * 1e3
    use_pcl = not args.no_pcl and os.access(PCL_REF, os.X_OK)
    mission = simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1)), seed=args.seed)
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
        busiest, most = mission.scans[0].scan_id, -1  # the cold start is measured on the scan with most detections
        for group, path in inputs:
            results.setdefault(group, {"ours": [], "pcl": [], "points": []})
            for _ in range(max(args.reps, 1)):
                ours, res = _ours(recognizer, path, args.seed)
                results[group]["ours"].append(ours)
            if group == "simulated" and len(res.detections) > most:
                busiest, most = int(path.stem.split("_")[-1]), len(res.detections)
            results[group]["points"].append(res.segmentation.n_input_points)
            if use_pcl:
                results[group]["pcl"].append(_pcl_times(path, res, db, tmp, recognizer.config))
    print(f"pose models prepared once per class in {warm_ms:.0f} ms (not in the per-scan figures)"
          + (f"; PoseConfig overrides {overrides}" if overrides else "") + "\n")
    print("| input | n | points | stage | ours median (ms) | PCL median (ms) | PCL / ours |")
    print("|---|---|---|---|---|---|---|")
    for group, r in results.items():
        for stage in STAGES:
            ours = statistics.median(t[stage] for t in r["ours"])
            pcl = statistics.median(t[stage] for t in r["pcl"]) if r["pcl"] else float("nan")
            ratio = pcl / ours if ours > 0 and np.isfinite(pcl) else float("nan")
            pcl_s, ratio_s = f"{pcl:.1f}", f"{ratio:.2f}"
            if stage == "matching" or not np.isfinite(pcl):  # PCL has no matcher: ours on both sides, not compared
                pcl_s = ratio_s = "-"
            print(f"| {group} | {len(r['ours'])} | {int(np.median(r['points']))} | {stage} | {ours:.1f} | "
                  f"{pcl_s} | {ratio_s} |")
        other = [t["total"] - sum(t[st] for st in STAGES[:-1]) for t in r["ours"]]
        print(f"| {group} | {len(other)} | | other (per-cluster glue) | {statistics.median(other):.1f} | | |")
        if group == "simulated":
            tot = [t["total"] - t["read"] for t in r["ours"]]
            print(f"| {group} | {len(tot)} | | scan-to-detections (no read) median | {statistics.median(tot):.1f} | | |")
            print(f"| {group} | {len(tot)} | | scan-to-detections (no read) p90 | {np.percentile(tot, 90):.1f} | | |")
            print(f"| {group} | {len(tot)} | | scans/s (1 / median) | {1e3 / statistics.median(tot):.1f} | | |")
    with tempfile.TemporaryDirectory() as tmpdir:  # a fresh process: import, recognizer, first scan
        db_path, scan_path = Path(tmpdir) / "db.npz", Path(tmpdir) / "scan.pcd"
        save_database(db, db_path)
        write_point_cloud(scan_path, mission.load_scan(busiest), encoding="binary_compressed")
        cold = subprocess.run([sys.executable, "-c", (
            "import time; t0=time.perf_counter();"
            "from semslam.pipeline import PipelineConfig, ScanRecognizer; from semslam.pose import PoseConfig;"
            "from semslam.recognition import load_database;"
            "from semslam.io import read_point_cloud; t1=time.perf_counter();"
            f"db=load_database({str(db_path)!r});"
            f"s=read_point_cloud({str(scan_path)!r}); t2=time.perf_counter();"
            f"r=ScanRecognizer(db, PipelineConfig(pose=PoseConfig(**{overrides!r})));"
            "res=r.recognize(s, seed=0); t3=time.perf_counter();"
            "print(f'{(t1-t0)*1e3:.0f} {(t3-t2)*1e3:.0f} {len(res.detections)}')")],
            capture_output=True, text=True, cwd=ROOT)
    try:
        imp, first, n_det = cold.stdout.split()
        print(f"\ncold start (fresh process, numba cache on disk): imports {imp} ms; first scan {first} ms "
              f"(recognizer construction + lazy pose-model preparation + recognition of scan {busiest}, "
              f"{n_det} detection(s)); database loaded from a file, not timed")
    except ValueError:
        print(f"\ncold start failed: {cold.stderr[-500:]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
