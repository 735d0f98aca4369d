"""The user's path, measured: simulated dives recorded as bags, run through ``semslam run BAG --db DB`` with only
the files the recorder left (issue #27's Monte Carlo).

Each run: a dive of the simulator (``--loops``, default the papers' 3) with its tank ``depth`` drawn in [4.5, 11.5] m (the vehicle at 3-10 m,
1.5 m above the floor), ``--gps N`` surface GPS fixes before the dive (a per-dive error of ~2 m per axis plus
0.5 m white, with the stated covariance), written as a ROS 1 bag or a ROS 2 mcap with its ``.topics.toml`` and
``.vehicle.toml``; then ``semslam run`` (the same library call, :func:`semslam.run.dive.run_dive`) in every mode,
with the fixes, and again without them (a topic map without the GPS topic: the local frame; the second run takes
the first's ``detections.jsonl``, as ``semslam slam --detections`` would: the same seeded recognition, run once). The simulator's truth
is read only afterwards, for the table: the bag's clock is mapped back to the mission's by its time origin.

Per format and per start (fix / no fix), over the runs:
* ATE of every mode, unaligned (world frame: the fix error is in it) and after the 4-DoF alignment (yaw +
  translation); the launch error; the ratio DR / pose;
* one landmark per object (4) in how many runs; the max |depth error| of the pose run;
* the vehicle position NEES (mean over epochs, then over runs) and the share of epochs inside the per-epoch 95 %
  chi-square band (3 dof); the landmarks' position NEES (3 dof) and the share of them inside that band;
* the health verdicts.

    nice -n 5 .venv/bin/python benchmarks/real_path.py --runs 30 --seed 100 [--formats ros1,ros2-mcap] [--jobs 1]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from semslam.dataset import write_vehicle_toml  # noqa: E402
from semslam.dataset.rosbag_write import TIME_ORIGIN_NS, topic_map_of, write_bag  # noqa: E402
from semslam.run import open_dive, run_stream  # noqa: E402
from semslam.run.dive import run_dive, write_outcome  # noqa: E402
from semslam.simulation import SimulatorConfig, simulate_dataset  # noqa: E402
from semslam.simulation.builtin_db import builtin_database  # noqa: E402
from semslam.slam import MODES
from semslam.io.detections import read_detections_jsonl
from semslam.evaluation.slam_run import ate_4dof  # noqa: E402
from semslam.evaluation.metrics import nees  # noqa: E402


def make_dive(seed: int, gps: int, out: Path, fmt: str, loops: int = 3, scan_interval_s: float = 0.5):
    rng = np.random.default_rng(seed)
    base = SimulatorConfig()
    cfg = base.replace(world=dataclasses.replace(base.world, tank_depth_m=float(rng.uniform(4.5, 11.5))),
                       trajectory=dataclasses.replace(base.trajectory, loops=loops),
                       fixes=dataclasses.replace(base.fixes, gps_count=gps))
    m = simulate_dataset(cfg, seed=seed, scan_interval_s=scan_interval_s)
    bag = out / (f"dive{seed}.bag" if fmt == "ros1" else f"dive{seed}")
    write_bag(m, bag, fmt)
    write_vehicle_toml(m.vehicle, Path(str(bag) + ".vehicle.toml"))
    Path(str(bag) + ".topics.toml").write_text(topic_map_of(m).to_toml())
    no_fix = Path(str(bag) + ".nofix.topics.toml")
    no_fix.write_text(dataclasses.replace(topic_map_of(m), gps=None, origin=None).to_toml())
    return m, bag, no_fix


def evaluate(run_dir: Path, m, time_shift_s: float) -> dict:
    """Errors of every mode of a run directory against the simulator's truth (read here, after the run)."""
    out = {}
    for mode in MODES:
        d = run_dir / "slam" / mode.replace("+", "_")
        tr = np.loadtxt(d / "trajectory.csv", delimiter=",", skiprows=1, usecols=range(7))
        met = json.loads((d / "metrics.json").read_text())
        t = tr[:, 0] + time_shift_s
        est = tr[:, 1:4]
        truth = m.truth.interpolate_position(t)
        cov = _covs(d / "trajectory.csv")
        frame = met["start"]["frame"]
        err_est = est.copy()
        if frame == "local":  # the local frame's origin is the start point
            err_est[:, 0:2] += truth[0, 0:2] - est[0, 0:2]
        e = err_est - truth
        sm = d / "trajectory_smoothed.csv"
        a_sm = float("nan")
        if sm.is_file():
            ts = np.loadtxt(sm, delimiter=",", skiprows=1, usecols=range(4))
            a_sm = ate_4dof(ts[:, 1:4], m.truth.interpolate_position(ts[:, 0] + time_shift_s))
        lm = _landmark_nees(d / "map.json", m, truth[0, 0:2] - est[0, 0:2] if frame == "local" else np.zeros(2))
        out[mode] = {"ate": float(np.sqrt(np.mean(np.sum(e ** 2, axis=1)))), "ate_4dof": ate_4dof(est, truth),
                     "ate_4dof_smoothed": a_sm,
                     "launch": float(np.linalg.norm(e[0])), "depth_max": float(np.max(np.abs(e[:, 2]))),
                     "nees": float(np.mean(nees(e, cov))), "nees_in_band": _in_band(nees(e, cov)),
                     "n_landmarks": met["n_landmarks"],
                     "landmark_nees": lm, "verdict": met["health"]["verdict"], "frame": frame}
    return out


def _covs(path: Path) -> np.ndarray:
    import csv

    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    keys = [["cov_p_xx", "cov_p_xy", "cov_p_xz"], ["cov_p_xy", "cov_p_yy", "cov_p_yz"], ["cov_p_xz", "cov_p_yz", "cov_p_zz"]]
    return np.array([[[float(r[k]) for k in row] for row in keys] for r in rows])


def _in_band(values, dof: int = 3) -> float:
    """Share of NEES values inside their two-sided 95 % chi-square band (``dof`` degrees of freedom)."""
    from scipy.stats import chi2

    v = np.asarray(values, dtype=float)
    lo, hi = chi2.ppf(0.025, dof), chi2.ppf(0.975, dof)
    return float(np.mean((v >= lo) & (v <= hi))) if v.size else float("nan")


def _landmark_nees(path: Path, m, shift_ne) -> list:

    doc = json.loads(path.read_text())
    out = []
    for lm in doc["landmarks"]:
        p = np.asarray(lm["position_ned_m"]) + np.r_[shift_ne, 0.0]
        objs = [o for o in m.objects if o.label == lm["label"]]
        if not objs:
            continue
        o = min(objs, key=lambda o: np.linalg.norm(o.T_world_object.translation_m - p))
        e = o.T_world_object.translation_m - p
        C = np.asarray(lm["covariance_6x6"])[:3, :3]
        out.append(float(e @ np.linalg.solve(C, e)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--gps", type=int, default=10)
    ap.add_argument("--loops", type=int, default=3, help="loops of the tank mission per dive (default 3, the papers')")
    ap.add_argument("--scan-interval", type=float, default=0.5, help="time between scan starts (s; default 0.5)")
    ap.add_argument("--formats", default="ros1,ros2-mcap")
    ap.add_argument("--out", default=None, help="keep the bags and runs here (default: a temporary folder)")
    ap.add_argument("--json", default=None, help="write the per-run numbers to this file")
    args = ap.parse_args()
    db = builtin_database(seed=0)
    work = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="semslam-real-path-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    try:
        for fmt in args.formats.split(","):
            for k in range(args.runs):
                seed = args.seed + k
                t0 = time.perf_counter()
                m, bag, no_fix = make_dive(seed, args.gps, work, fmt, args.loops, args.scan_interval)
                dets = None
                for start, topics in (("fix", None), ("no fix", no_fix)):
                    run = work / f"run_{fmt}_{seed}_{start.replace(' ', '')}"
                    shutil.rmtree(run, ignore_errors=True)
                    run.mkdir()
                    if dets is None:
                        payload = run_dive(bag, run, db=db, topics=topics)
                        dets = read_detections_jsonl(run / "detections.jsonl")
                    else:  # the same scans, the same detections (recognition is seeded): SLAM from the other start
                        dive = open_dive(bag, topics=topics, scans=False)
                        out = run_stream(dive, modes=MODES, detections_by_scan=dets, symmetries=db.symmetries())
                        payload = write_outcome(out, run, dive=dive, export=True)
                    dive = open_dive(bag, topics=topics)
                    next(iter(dive.messages()), None)  # the time origin is known after the first message
                    shift = (int(dive.metadata.get("time_origin_ns", TIME_ORIGIN_NS)) - TIME_ORIGIN_NS) / 1e9
                    ev = evaluate(run, m, shift)
                    rows.append({"format": fmt, "seed": seed, "start": start, "modes": ev,
                                 "verdict": payload["verdict"], "wall_s": time.perf_counter() - t0})
                    p = ev["pose"]
                    print(f"{fmt} seed {seed} {start:6s}: pose ATE {p['ate']:.3f} (4-DoF {p['ate_4dof']:.3f}) "
                          f"DR {ev['dr']['ate_4dof']:.3f} launch {p['launch']:.2f} landmarks {p['n_landmarks']} "
                          f"depth {p['depth_max']:.3f} NEES {p['nees']:.2f} verdict {payload['verdict']} "
                          f"({time.perf_counter() - t0:.0f} s)",
                          flush=True)
    finally:
        if not args.out:
            shutil.rmtree(work, ignore_errors=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    print(table(rows))


def table(rows: list) -> str:
    lines = ["| format | start | runs | pose ATE 4-DoF (m) | smoothed (DR/smoothed) | DR ATE 4-DoF (m) | DR/pose | unaligned pose ATE "
             "(m) | launch error (m) | 1 landmark per object | max depth error (m) | vehicle NEES | vehicle NEES epochs "
             "in 95 % band | landmark NEES (3 dof) | landmarks in 95 % band | verdicts |", "|" + "---|" * 16]
    for fmt in sorted({r["format"] for r in rows}):
        for start in ("fix", "no fix"):
            rs = [r for r in rows if r["format"] == fmt and r["start"] == start]
            if not rs:
                continue
            pose = [r["modes"]["pose"] for r in rs]
            dr = [r["modes"]["dr"] for r in rs]
            a4 = np.mean([p["ate_4dof"] for p in pose])
            d4 = np.mean([p["ate_4dof"] for p in dr])
            lm = [x for p in pose for x in p["landmark_nees"]]
            verdicts = {v: sum(r["verdict"] == v for r in rs) for v in ("ok", "warning", "bad")}
            s4 = np.mean([p["ate_4dof_smoothed"] for p in pose])
            lines.append(f"| {fmt} | {start} | {len(rs)} | {a4:.4f} | {s4:.4f} ({d4 / s4:.1f}x) | {d4:.4f} | "
                         f"{d4 / a4:.1f}x | "
                         f"{np.mean([p['ate'] for p in pose]):.3f} | {np.mean([p['launch'] for p in pose]):.2f} | "
                         f"{sum(p['n_landmarks'] == 4 for p in pose)}/{len(rs)} | "
                         f"{max(p['depth_max'] for p in pose):.3f} | {np.mean([p['nees'] for p in pose]):.2f} | "
                         f"{100 * np.mean([p['nees_in_band'] for p in pose]):.0f} % | "
                         f"{np.mean(lm) if lm else float('nan'):.2f} | {100 * _in_band(lm):.0f} % | {verdicts} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
