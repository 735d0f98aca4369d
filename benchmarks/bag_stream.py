"""A long recorded dive through `semslam run`: peak memory and throughput (issue 14).

Simulates a dive of ``--minutes`` (loops of the default tank mission, scans every 0.5 s whatever is in view:
2 Hz, ``--lines`` x ``--lines`` rays per scan), writes it as a ROS 2 mcap bag as a vehicle would record it, then
runs ``semslam run BAG --db builtin --mode pose`` in a child process and reports its wall time, the real-time
factor and the child's peak RSS (``VmHWM`` of ``/proc/PID/status``). The bag is streamed through the runner
(:mod:`semslam.run`): nothing is converted on disk and no scan written; every scan is recognised as it comes, so
memory is bounded by one scan, the delay line and the navigation history (a few MB per hour).

    .venv/bin/python benchmarks/bag_stream.py --minutes 30 --lines 100 --work /tmp/bagbench
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import subprocess
import sys
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--lines", type=int, default=100, help="lines and points per line of a scan (default 100)")
    ap.add_argument("--work", default="/tmp/semslam_bagbench")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    from semslam.dataset import write_vehicle_toml
    from semslam.dataset.rosbag_write import topic_map_of, write_bag
    from semslam.simulation import ScannerConfig, SimulatorConfig, TrajectoryConfig, simulate_dataset

    work = Path(args.work)
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    one = simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1)), seed=0, with_scans=False)
    loops = max(1, round(args.minutes * 60.0 / one.duration_s))
    cfg = SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=loops),
                                    scanner=ScannerConfig(n_lines=args.lines, points_per_line=args.lines,
                                                          only_when_objects_in_view=False))
    cfg = cfg.replace(scanner=dataclasses.replace(cfg.scanner, scan_rate_hz=3.0))
    t = time.perf_counter()
    mission = simulate_dataset(cfg, seed=args.seed, progress=True)
    t_sim = time.perf_counter() - t
    t = time.perf_counter()
    bag = write_bag(mission, work / "dive", "ros2-mcap")
    t_bag = time.perf_counter() - t
    write_vehicle_toml(mission.vehicle, work / "vehicle.toml")
    (work / "topics.toml").write_text(topic_map_of(mission).to_toml())
    size_mb = sum(f.stat().st_size for f in bag.rglob("*") if f.is_file()) / 1e6
    n_scans, n_points = len(mission.scans), sum(s.n_points for s in mission.scans)
    del mission
    t = time.perf_counter()
    cmd = [sys.executable, "-m", "semslam.cli.main", "run", str(bag), "--db", "builtin", "--mode", "pose",
           "--vehicle", str(work / "vehicle.toml"), "--topics", str(work / "topics.toml"), "--out", str(work / "run"),
           "--no-report", "--json"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    hwm_kb = 0
    while proc.poll() is None:  # the child's own high-water mark (getrusage would count the pages a fork of this
        try:                    # big process shares with it before exec)
            for line in Path(f"/proc/{proc.pid}/status").read_text().splitlines():
                if line.startswith("VmHWM:"):
                    hwm_kb = max(hwm_kb, int(line.split()[1]))
        except (OSError, ValueError):
            pass
        time.sleep(0.2)
    wall = time.perf_counter() - t
    if proc.returncode != 0:
        sys.exit(proc.stderr.read()[-2000:])
    rss_mb = hwm_kb / 1024
    dive_s = one.duration_s * loops
    print("| dive (min) | scans (2 Hz) | points | bag (MB, mcap) | simulate (s) | write bag (s) | semslam run (s) | real time | peak RSS (MB) |")
    print("|---|---|---|---|---|---|---|---|---|")
    print(f"| {dive_s / 60:.1f} | {n_scans} | {n_points / 1e6:.1f} M | {size_mb:.0f} | {t_sim:.0f} | {t_bag:.0f} | {wall:.0f} | "
          f"{dive_s / wall:.1f}x | {rss_mb:.0f} |")


if __name__ == "__main__":
    main()
