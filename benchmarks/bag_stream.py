"""A long recorded dive through `semslam run`: peak memory and throughput (issues 14, 27).

Simulates a dive of ``--minutes`` (loops of the default tank mission, scans every 0.5 s whatever is in view:
2 Hz, ``--lines`` x ``--lines`` rays per scan), writes it as a bag as a vehicle would record it (``--format``,
ROS 2 mcap by default; the scans simulated and written one at a time, never all in memory), then runs
``semslam run BAG --db builtin --mode pose`` in a child process and reports its wall time, the real-time factor
and the child's peak RSS (``VmHWM`` of ``/proc/PID/status``). The bag is streamed through the runner
(:mod:`semslam.run`): nothing is converted on disk and no scan written; scans are recognised as they come (two
at a time in background threads), so memory is bounded by a few scans, the delay line and the navigation history
(a few MB per hour). ``--reuse`` runs on the bag an earlier call left in ``--work``.

    .venv/bin/python benchmarks/bag_stream.py --minutes 30 --lines 100 --work /tmp/bagbench
    .venv/bin/python benchmarks/bag_stream.py --minutes 30 --lines 320 --format ros1 --work /tmp/bag30  # ~100k
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
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
    ap.add_argument("--format", default="ros2-mcap", choices=("ros1", "ros2-mcap"))
    ap.add_argument("--reuse", action="store_true", help="run on the bag an earlier call left in --work")
    args = ap.parse_args()
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset

    work = Path(args.work)
    one = simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1)), seed=0, with_scans=False)
    loops = max(1, round(args.minutes * 60.0 / one.duration_s))
    info = work / "bag.json"
    if not (args.reuse and info.is_file()):
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir(parents=True)
        info.write_text(json.dumps(make_bag(work, loops, args.lines, args.seed, args.format)))
    made = json.loads(info.read_text())
    bag, t_sim_bag, size_mb, n_scans, n_points = (Path(made["bag"]), made["seconds"], made["size_mb"],
                                                  made["n_scans"], made["n_points"])
    speed = machine_speed_s()
    t = time.perf_counter()
    cmd = [sys.executable, "-m", "semslam.cli.main", "run", str(bag), "--db", "builtin", "--mode", "pose",
           "--vehicle", str(work / "vehicle.toml"), "--topics", str(work / "topics.toml"), "--out", str(work / "run"),
           "--no-report", "--json", "--overwrite"]
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
    load = "%.2f %.2f %.2f" % os.getloadavg()
    print(f"machine speed: a fixed numpy + Python loop took {speed:.2f} s before the run and {machine_speed_s():.2f} s "
          "after (0.72-1.50 s seen on this shared VM, whose speed varies by up to 2x; RESULTS.md gives it per run)")
    print(f"| dive (min) | scans | points | bag (MB, {made['format']}) | simulate + write bag (s) | semslam run (s) | "
          "real time | peak RSS (MB) | load after |")
    print("|---|---|---|---|---|---|---|---|---|")
    print(f"| {dive_s / 60:.1f} | {n_scans} | {n_points / 1e6:.1f} M | {size_mb:.0f} | {t_sim_bag:.0f} | {wall:.0f} | "
          f"{dive_s / wall:.1f}x | {rss_mb:.0f} | {load} |")


def machine_speed_s() -> float:
    """Seconds of a fixed numpy + pure-Python loop (the load average does not see a shared host's contention)."""
    import numpy as np

    a = np.random.default_rng(0).random((2000, 2000))
    t = time.perf_counter()
    for _ in range(5):
        a @ a
    x = 0
    for i in range(3_000_000):
        x += i
    return time.perf_counter() - t


def make_bag(work: Path, loops: int, lines: int, seed: int, fmt: str) -> dict:
    """The dive as a bag in ``work`` with its topic map and vehicle file (the scans simulated and written one at a
    time: a 30-minute dive of 100k-point scans is ~6 GB)."""
    from semslam.dataset import write_vehicle_toml
    from semslam.dataset.rosbag_write import topic_map_of, write_bag
    from semslam.simulation import ScannerConfig, SimulatorConfig, TrajectoryConfig, simulate_dataset, simulate_scans

    cfg = SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=loops),
                                    scanner=ScannerConfig(n_lines=lines, points_per_line=lines,
                                                          only_when_objects_in_view=False))
    cfg = cfg.replace(scanner=dataclasses.replace(cfg.scanner, scan_rate_hz=3.0))
    t = time.perf_counter()
    nav = simulate_dataset(cfg, seed=seed, with_scans=False)
    counted = {"scans": 0, "points": 0}

    def scans():
        for rec, cloud in simulate_scans(cfg, seed=seed, progress=True):
            counted["scans"] += 1
            counted["points"] += cloud.n_points
            yield rec, cloud

    bag = write_bag(nav, work / ("dive.bag" if fmt == "ros1" else "dive"), fmt, scans=scans())
    write_vehicle_toml(nav.vehicle, work / "vehicle.toml")
    (work / "topics.toml").write_text(topic_map_of(nav, scans=True).to_toml())
    files = [bag] if bag.is_file() else [f for f in bag.rglob("*") if f.is_file()]
    return {"bag": str(bag), "format": fmt, "seconds": time.perf_counter() - t, "n_scans": counted["scans"],
            "n_points": counted["points"], "size_mb": sum(f.stat().st_size for f in files) / 1e6}


if __name__ == "__main__":
    main()
