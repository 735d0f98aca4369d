"""The ROS 1 node under `rosbag play` (issue #28, item 6): a simulated dive with ~100k-point scans at 2 Hz and
the AHRS at 20 Hz, played at `-r 1` then `-r 4` into `python -m semslam.run.ros1.node` (keep-newest scan queue,
default reorder window) on a roscore of its own. Reports, from the node's own counters (ros_node.json):
scan arrival -> detections ready p50/p90, navigation arrival -> odometry published p50/p90, scans dropped,
navigation messages dropped; and the node process's CPU time and peak RSS (psutil). Needs ROS 1 (docs/ros1.md).

    .venv/bin/python benchmarks/ros_node.py [--work /tmp/semslam_ros_bench] [--rates 1 4] [--points 320]
    .venv/bin/python benchmarks/ros_node.py --dive /tmp/bag30 --rates 2    # RSS over bag_stream's 30-min dive
    .venv/bin/python benchmarks/ros_node.py --rates 1 --config LA0.toml    # [pipeline] deskew_lookahead_s = 0

Everything started is stopped by PID (its process group); the load average is printed with every figure.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path


def _load() -> str:
    return "load %.2f %.2f %.2f" % os.getloadavg()


def make_dive(work: Path, points: int, seed: int = 4) -> dict:
    from semslam.dataset import read_dataset, write_dataset, write_vehicle_toml
    from semslam.dataset.rosbag_write import SEMSLAM_TOPICS, write_bag
    from semslam.recognition.storage import save_database
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset
    from semslam.simulation.builtin_db import builtin_database
    from semslam.simulation.config import ScannerConfig

    d = work / f"dive_{points}"
    files = {"bag": d / "dive.bag", "topics": d / "topics.toml", "vehicle": d / "vehicle.toml", "db": d / "objects.npz"}
    if all(p.exists() for p in files.values()):
        return files
    shutil.rmtree(d, ignore_errors=True)
    d.mkdir(parents=True)
    cfg = SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1),
                                    scanner=ScannerConfig(n_lines=points, points_per_line=points, scan_rate_hz=2.0))
    mission = read_dataset(write_dataset(simulate_dataset(cfg, seed=seed), d / "mission"))
    write_bag(mission, files["bag"], "ros1")
    files["topics"].write_text(SEMSLAM_TOPICS.to_toml(), encoding="utf-8")
    write_vehicle_toml(mission.vehicle, files["vehicle"])
    save_database(builtin_database(seed=0), files["db"])
    print(f"dive: {len(mission.scans)} scans of ~{mission.scans[0].n_points} points, "
          f"{mission.attitude.stamp_s[-1]:.1f} s, AHRS {len(mission.attitude)} samples")
    return files


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(proc: subprocess.Popen, timeout: float = 60.0) -> None:
    for sig, wait in ((signal.SIGINT, timeout), (signal.SIGKILL, 5.0)):
        if proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, sig)
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(wait)
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)


def run_once(files: dict, rate: float, work: Path, config: str | None = None) -> dict:
    import psutil
    import rosgraph

    from semslam.run.ros1.bridge import ensure_rospy

    ensure_rospy()
    port = _free_port()
    uri = f"http://127.0.0.1:{port}"
    home = work / f"ros_home_{rate:g}"
    home.mkdir(exist_ok=True)
    env = dict(os.environ, ROS_MASTER_URI=uri, ROS_HOME=str(home), ROS_LOG_DIR=str(home / "log"), ROS_IP="127.0.0.1")
    out = work / f"run_r{rate:g}"
    procs = []
    try:
        core = subprocess.Popen(["roscore", "-p", str(port)], env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, start_new_session=True)
        procs.append(core)
        while not rosgraph.is_master_online(master_uri=uri):
            time.sleep(0.1)
        cmd = ([sys.executable, "-m", "semslam.run.ros1.node"] if config is None else
               [sys.executable, "-m", "semslam.cli.main", "ros", "--config", str(config)])
        node = subprocess.Popen(cmd + ["--db", str(files["db"]), "--topics", str(files["topics"]), "--vehicle",
                                       str(files["vehicle"]), "--out", str(out), "--overwrite"], env=env,
                                stdout=open(work / f"node_r{rate:g}.log", "w"), stderr=subprocess.STDOUT,
                                start_new_session=True)
        procs.append(node)
        master = rosgraph.Master("/bench", master_uri=uri)
        while not any(t == "/semslam/scans" for t, _ in master.getSystemState()[1]):
            if node.poll() is not None:
                raise RuntimeError((work / f"node_r{rate:g}.log").read_text()[-2000:])
            time.sleep(0.2)
        ps = psutil.Process(node.pid)
        cpu0 = sum(ps.cpu_times()[:2])
        rss_peak = 0
        play = subprocess.Popen(["rosbag", "play", "-q", "-d", "1", "-r", str(rate), str(files["bag"])], env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        procs.append(play)
        t0 = time.monotonic()
        rss_trace = []  # (s since play started, RSS MB) every ~5 s: flat memory over a long bag
        while play.poll() is None:
            rss = ps.memory_info().rss
            rss_peak = max(rss_peak, rss)
            if not rss_trace or time.monotonic() - t0 - rss_trace[-1][0] >= 5.0:
                rss_trace.append((time.monotonic() - t0, rss / 2**20))
            time.sleep(0.2)
        wall = time.monotonic() - t0
        cpu = sum(ps.cpu_times()[:2]) - cpu0
        _stop(node)
        stats = json.loads((out / "ros_node.json").read_text())
        verdict = json.loads((out / "run.json").read_text())["verdict"]  # the run's health (semslam.run.health)
    finally:
        for p in reversed(procs):
            _stop(p, 10.0)
    return {"rate": rate, "wall_s": wall, "cpu_s": cpu, "cpu_percent": 100.0 * cpu / wall,
            "rss_peak_mb": rss_peak / 2**20, **stats["latency"], "scans": stats["stats"]["messages"]["scan"],
            "scans_recognised": stats["stats"]["scans_recognised"], "scans_dropped": stats["stats"]["scans_dropped"],
            "scans_late": stats["stats"]["scans_late"], "dropped_late": stats["dropped_late"],
            "navigation_errors": stats["stats"]["navigation_errors"], "verdict": verdict, "rss_trace": rss_trace}


def rss_summary(trace: list) -> str:
    """RSS at a quarter, half, three quarters and the end of the play, and the slope over the second half."""
    import numpy as np

    if len(trace) < 4:
        return "RSS trace too short"
    t, m = np.array(trace).T
    at = [float(np.interp(f * t[-1], t, m)) for f in (0.25, 0.5, 0.75, 1.0)]
    half = t >= t[-1] / 2
    slope = float(np.polyfit(t[half], m[half], 1)[0]) * 600.0 if half.sum() >= 2 else float("nan")
    return (f"RSS at 1/4, 1/2, 3/4, end of the play: {', '.join(f'{v:.0f}' for v in at)} MB; "
            f"second half slope {slope:+.1f} MB per 10 min")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="/tmp/semslam_ros_bench")
    ap.add_argument("--rates", type=float, nargs="+", default=[1.0, 4.0])
    ap.add_argument("--points", type=int, default=320, help="scan lines = points per line (320: ~100k points)")
    ap.add_argument("--dive", help="a directory with dive.bag, topics.toml and vehicle.toml (e.g. the 30-minute "
                    "dive of `bag_stream.py --format ros1`) instead of the simulated 24 s dive")
    ap.add_argument("--config", help="a run configuration file for the node (`semslam ros --config`), e.g. one "
                    "with [pipeline] deskew_lookahead_s = 0 for the lowest scan latency")
    args = ap.parse_args()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    if args.dive:
        from semslam.recognition.storage import save_database
        from semslam.simulation.builtin_db import builtin_database

        d = Path(args.dive)
        files = {"bag": d / "dive.bag", "topics": d / "topics.toml", "vehicle": d / "vehicle.toml",
                 "db": work / "objects.npz"}
        save_database(builtin_database(seed=0), files["db"])
    else:
        files = make_dive(work, args.points)
    for rate in args.rates:
        r = run_once(files, rate, work, args.config)
        print(f"-r {rate:g} ({_load()}): scan->detections p50 {r['scan_to_detections_p50_ms']:.0f} ms, "
              f"p90 {r['scan_to_detections_p90_ms']:.0f} ms; navigation->odometry p50 "
              f"{r['navigation_to_odometry_p50_ms']:.2f} ms, p90 {r['navigation_to_odometry_p90_ms']:.2f} ms; "
              f"scans {r['scans_recognised']}/{r['scans']} recognised, {r['scans_dropped']} dropped (newest kept), "
              f"{r['scans_late']} late; messages dropped late {r['dropped_late']}; verdict {r['verdict']}; CPU {r['cpu_percent']:.0f} %, "
              f"peak RSS {r['rss_peak_mb']:.0f} MB")
        print(rss_summary(r["rss_trace"]))
        print(json.dumps(r))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
