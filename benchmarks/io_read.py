"""Read speed of semslam.io against PCL 1.13 (``pcl_ref read FILE N``) and Open3D (when importable).

    .venv/bin/python benchmarks/io_read.py [--reps 20] [--data ../shared/data/real] [--pcl-ref PATH]
    .venv/bin/python benchmarks/io_read.py --only pointcloud2 [--points 102400]

Prints a markdown table: best-of-N milliseconds per real scene for ``read_pcd`` (every field at its dtype,
NaN points kept, like PCL's reader), ``read_point_cloud`` (NaN points dropped, float64 coordinates), PCL
and Open3D. Then the per-scan cost of a bag's scan: rosbags' ROS 1 deserialisation and
:func:`semslam.io.ros.decode_pointcloud2` of a ``sensor_msgs/PointCloud2`` laid out as the simulator records it
(x, y, z, intensity float32, t uint32 ns; 5 % NaN points).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import time
from pathlib import Path

from semslam.io import read_point_cloud
from semslam.io.pcd import read_pcd

ROOT = Path(__file__).resolve().parents[1]


def best_ms(fn, reps: int) -> float:
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best * 1e3


def pcl_ms(pcl_ref: str | None, path: Path, reps: int) -> str:
    if not pcl_ref:
        return "n/a"
    out = subprocess.run(
        [pcl_ref, "read", str(path), str(reps)], check=False, capture_output=True, text=True
    )
    if out.returncode != 0:
        return "error"
    return f"{json.loads(out.stdout.splitlines()[0])['ms']:.2f}"


def open3d_ms(path: Path, reps: int) -> str:
    try:
        import open3d as o3d
    except ImportError:
        return "not installed"
    return (
        f"{best_ms(lambda: o3d.io.read_point_cloud(str(path), remove_nan_points=False), reps):.2f}"
    )


def pointcloud2(n_points: int, reps: int) -> None:
    import numpy as np
    from rosbags.typesys import Stores, get_typestore

    from semslam.io.ros import decode_pointcloud2, encode_pointcloud2

    ts = get_typestore(Stores.ROS1_NOETIC)
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(n_points, 3)).astype(np.float32)
    pts[rng.random(n_points) < 0.05] = np.nan
    msg = encode_pointcloud2(pts, intensity=rng.random(n_points), time_offset_s=np.linspace(0.0, 0.3, n_points),
                             stamp_ns=10**18, typestore=ts)
    raw = ts.serialize_ros1(msg, "sensor_msgs/msg/PointCloud2")
    back = ts.deserialize_ros1(raw, "sensor_msgs/msg/PointCloud2")
    print(f"\nbest of {reps}, milliseconds, one PointCloud2 of {n_points} points\n")
    print("| rosbags deserialize_ros1 | decode_pointcloud2 |")
    print("|---:|---:|")
    des = best_ms(lambda: ts.deserialize_ros1(raw, "sensor_msgs/msg/PointCloud2"), reps)
    print(f"| {des:.2f} | {best_ms(lambda: decode_pointcloud2(back), reps):.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=20)
    parser.add_argument("--only", choices=("pcd", "pointcloud2"), default=None)
    parser.add_argument("--points", type=int, default=102400, help="points of the PointCloud2 (default 102400)")
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data" / "real")
    default_ref = os.environ.get("PCL_REF") or str(Path.home() / ".cache/pcl_oracle/pcl_ref")
    parser.add_argument(
        "--pcl-ref",
        default=default_ref if os.access(default_ref, os.X_OK) else shutil.which("pcl_ref"),
    )
    args = parser.parse_args()
    if args.only != "pcd":
        pointcloud2(args.points, args.reps)
    if args.only == "pointcloud2":
        return
    files = sorted(args.data.glob("*.pcd"), key=lambda p: p.stat().st_size)
    if not files:
        raise SystemExit(f"no .pcd files in {args.data}")
    print(f"best of {args.reps} reads, milliseconds\n")
    print("| file | encoding | points | NaN | read_pcd | read_point_cloud | PCL 1.13 | Open3D |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    for path in files:
        data = read_pcd(path)
        ours = best_ms(lambda p=path: read_pcd(p), args.reps)
        cloud = best_ms(lambda p=path: read_point_cloud(p), args.reps)
        print(
            f"| {path.name} | {data.encoding} | {data.n_points} | {data.n_nan} | {ours:.2f} | {cloud:.2f} | "
            f"{pcl_ms(args.pcl_ref, path, args.reps)} | {open3d_ms(path, args.reps)} |"
        )


if __name__ == "__main__":
    main()
