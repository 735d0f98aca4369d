"""Bounded ``semslam register`` and ``semslam describe --descriptor fpfh`` (issue #18, item 4).

Runs every case as its own ``semslam`` process (so that the peak RSS is that case's alone) and prints two
tables:

* register: cloud kind x size (20k, 100k, 300k points) -> wall time of the whole command, outcome
  (converged / not converged / budget exhausted / the one-line error), translation error against the
  known motion, peak RSS. Kinds: a real scan (``rs1.pcd`` and ``table_scene_mug_stereo_textured.pcd``
  from ``../shared/data/real/``, randomly subsampled, moved by a known 10 degree / 5 cm motion onto
  itself), the same with one point at 1e9 m in the target, a plane, a line;
* FPFH: ``describe --descriptor fpfh --normal-radius R --fpfh-radius 2R`` at 100k, 300k, 1M points of a
  wavy surface as dense as a 30 cm RealSense frame, plus the real valve frame and a 1e9 m outlier
  -> wall time, peak RSS.

    .venv/bin/python benchmarks/register_budget.py [--only register|fpfh] [--sizes 20000,100000,300000]

Note the machine load (``uptime``) next to the numbers: the machine has 2 cores.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real"
SEMSLAM = [sys.executable, "-m", "semslam.cli.main"] if not (ROOT / ".venv" / "bin" / "semslam").exists() \
    else [str(ROOT / ".venv" / "bin" / "semslam")]
MOTION_DEG, MOTION_M = 10.0, np.array([0.05, -0.03, 0.02])


def run(argv: list[str]) -> tuple[float, int, int, str, str]:
    """(seconds, exit code, peak RSS in MiB, stdout, stderr) of one semslam command (GNU time's %M)."""
    t0 = time.perf_counter()
    proc = subprocess.run(["/usr/bin/time", "-f", "RSS_KB %M", *SEMSLAM, *argv], capture_output=True, text=True)
    elapsed = time.perf_counter() - t0
    lines = proc.stderr.strip().splitlines()
    rss = next((int(x.split()[1]) // 1024 for x in reversed(lines) if x.startswith("RSS_KB")), -1)
    err = "\n".join(x for x in lines if not x.startswith("RSS_KB") and not x.startswith("Command exited"))
    return elapsed, proc.returncode, rss, proc.stdout, err


def motion() -> np.ndarray:
    c, s = np.cos(np.radians(MOTION_DEG)), np.sin(np.radians(MOTION_DEG))
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = MOTION_M
    return T


def real_scan(name: str, n: int, seed: int = 0) -> np.ndarray | None:
    from semslam.io import read_point_cloud

    path = REAL / name
    if not path.exists():
        return None
    pts = read_point_cloud(path).points_xyz_m
    pts = pts[np.isfinite(pts).all(axis=1)]
    if n <= len(pts):
        return pts[np.sort(np.random.default_rng(seed).choice(len(pts), n, replace=False))]
    reps = int(np.ceil(n / len(pts)))  # more than the scan holds: jittered copies
    rng = np.random.default_rng(seed)
    return np.vstack([pts + rng.normal(0, 5e-4, pts.shape) for _ in range(reps)])[:n]


def synthetic(kind: str, n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    if kind == "plane":
        return np.c_[rng.uniform(-0.5, 0.5, (n, 2)), rng.normal(0, 0.001, n)]
    if kind == "line":
        return np.c_[rng.uniform(-0.5, 0.5, n), rng.normal(0, 0.001, (n, 2))]
    side = np.sqrt(n * np.pi * 0.02**2 / 100.0)  # ~100 points within 2 cm, as a 30 cm RealSense frame
    xy = rng.uniform(0, side, (n, 2))
    return np.c_[xy, 0.03 * np.sin(xy[:, 0] / 0.05) * np.cos(xy[:, 1] / 0.07)]


def register_cases(sizes: list[int]):
    T = motion()
    for n in sizes:
        for kind in ("rs1", "table_scene", "rs1+1e9 outlier", "plane", "line"):
            if kind.startswith("rs1") or kind == "table_scene":
                tgt = real_scan("rs1.pcd" if kind.startswith("rs1") else "table_scene_mug_stereo_textured.pcd", n)
                if tgt is None:
                    continue
                src = (tgt - T[:3, 3]) @ T[:3, :3]  # T maps the source onto the target
                if "outlier" in kind:
                    tgt = np.vstack([tgt, [[1e9, 1e9, 1e9]]])
            else:
                tgt = synthetic(kind, n)
                src = (tgt - T[:3, 3]) @ T[:3, :3]
            yield kind, n, src, tgt


def bench_register(sizes: list[int], extra: list[str]) -> None:
    import json

    print("\n## register (default options: --voxel auto --time-budget 10)\n")
    print("| cloud | points | time s | outcome | error cm | voxel m | peak RSS MiB |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for kind, n, src, tgt in register_cases(sizes):
            s, t = Path(tmp) / "s.npy", Path(tmp) / "t.npy"
            np.save(s, src)
            np.save(t, tgt)
            sec, rc, rss, out, err = run(["register", str(s), str(t), "--json", *extra])
            err_cm = voxel = "-"
            if out.strip():
                p = json.loads(out)
                M = np.array(p["T_target_source"]["matrix"])
                err_cm = f"{100 * np.linalg.norm(M[:3, 3] - motion()[:3, 3]):.2f}"
                voxel = f"{p.get('extras', {}).get('voxel_m', float('nan')):.4f}"
                outcome = "converged" if p["converged"] else "not converged"
                if p.get("extras", {}).get("budget_exhausted"):
                    outcome += ", budget exhausted"
            else:
                outcome = "error: " + " ".join(err.strip().splitlines()[-1:])[:110]
            print(f"| {kind} | {n} | {sec:.1f} | {outcome} (exit {rc}) | {err_cm} | {voxel} | {rss} |", flush=True)


def bench_fpfh(sizes: list[int]) -> None:
    print("\n## describe --descriptor fpfh --normal-radius 0.01 --fpfh-radius 0.02 (all points' FPFH)\n")
    print("| cloud | points | time s | exit | peak RSS MiB |")
    print("|---|---|---|---|---|")
    cases = []
    valve = sorted(REAL.glob("valves/*/*/1/Captured_Frame.pcd"))
    if valve:
        cases.append(("valve frame (real)", None, str(valve[0])))
    for n in sizes:
        cases.append(("wavy surface", n, synthetic("surface", n)))
    cases.append(("wavy surface + 1e9 outlier", sizes[0], np.vstack([synthetic("surface", sizes[0]), [[1e9] * 3]])))
    with tempfile.TemporaryDirectory() as tmp:
        for name, n, data in cases:
            path = data if isinstance(data, str) else str(Path(tmp) / "c.npy")
            if not isinstance(data, str):
                np.save(path, data)
            sec, rc, rss, _, err = run(["describe", path, "--descriptor", "fpfh", "--normal-radius", "0.01",
                                        "--fpfh-radius", "0.02", "--json"])
            note = "" if rc == 0 else " " + " ".join(err.strip().splitlines()[-1:])[:80]
            print(f"| {name} | {n if n else 'file'} | {sec:.1f} | {rc}{note} | {rss} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=("register", "fpfh"))
    ap.add_argument("--sizes", default="20000,100000,300000")
    ap.add_argument("--fpfh-sizes", default="100000,300000,1000000")
    ap.add_argument("--register-args", default="", help="extra arguments for every register call")
    args = ap.parse_args()
    print(f"load: {os.getloadavg()}")
    if args.only in (None, "register"):
        bench_register([int(x) for x in args.sizes.split(",")], args.register_args.split())
    if args.only in (None, "fpfh"):
        bench_fpfh([int(x) for x in args.fpfh_sizes.split(",")])
    print(f"\nload: {os.getloadavg()}")


if __name__ == "__main__":
    main()
