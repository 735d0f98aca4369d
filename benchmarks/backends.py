"""Backends benchmark (issue 17): the EKF against the GTSAM factor graph (iSAM2 online, batch LM) on the same
seeded Monte-Carlo missions and detections.

Run: ``.venv/bin/python benchmarks/backends.py [--runs 30] [--scenarios default,heading] [--csv DIR]``
(``--csv``: the mean error over time per backend and ``DIR/report.html`` with its figure), or
``--timing`` for the best-of-3 real-time factor of each backend on mission 0
(prints markdown tables). Scenarios: ``default`` (the default 3-loop mission, mode ``pose``) and ``heading`` (a 2-degree
constant AHRS yaw bias, mode ``pose+heading`` with the surveyed ``elbow_1``, as in history/slam.md's heading-bias section).

Columns: ATE of the current-time estimates (each epoch as estimated at that epoch: the EKF's filter, iSAM2's graph
at that moment; batch has no online solution and shows its front-end filter's), ATE of the trajectory as each
backend holds it at the end of the dive (EKF: its filtered history; iSAM2 / batch: the graph's final estimate;
the EKF's offline RTS smoother in its own row), ANEES fraction of epochs inside the 95 % band over the runs,
landmark position error, time per graph update and the real-time factor (mission duration / wall time of the
whole run, filter and graph included, mission simulation excluded).
"""

from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np

from semslam.experiments.montecarlo import make_dataset, truth_run
from semslam.slam import SlamConfig
from semslam.evaluation.metrics import anees, nees

SCENARIOS = {
    "default": dict(mode="pose", yaw_bias_deg=0.0, overrides={}, surveyed=()),
    "heading": dict(mode="pose+heading", yaw_bias_deg=2.0, overrides={}, surveyed=("elbow_1",)),
}


def run_scenario(name: str, n_runs: int, backends, seed0: int = 0) -> dict:
    sc = SCENARIOS[name]
    cfg = SlamConfig().updated(**sc["overrides"])
    rows: dict = {b: {"online_err": [], "end_err": [], "online_nees": [], "end_nees": [], "ate_on": [], "ate_end": [],
                      "lm": [], "wall": [], "dur": [], "upd": []} for b in backends}
    rows["ekf-rts"] = {"end_err": [], "end_nees": [], "ate_end": []}
    for i in range(n_runs):
        seed = seed0 + i
        mission = make_dataset(seed, yaw_bias_rad=math.radians(sc["yaw_bias_deg"]))
        for b in backends:
            t0 = time.perf_counter()
            res = truth_run(mission, sc["mode"], cfg, seed, b, sc["surveyed"])
            wall = time.perf_counter() - t0
            truth = res.truth_position_ned_m
            r = rows[b]
            e_on = res.position_ned_m - truth
            r["online_err"].append(np.linalg.norm(e_on, axis=1))
            r["online_nees"].append(nees(e_on, res.position_cov_m2))
            r["ate_on"].append(res.metrics["ate_rmse_m"])
            if b == "ekf":  # what the filter holds at the end of the dive: its filtered history
                r["end_err"].append(r["online_err"][-1])
                r["end_nees"].append(r["online_nees"][-1])
                r["ate_end"].append(res.metrics["ate_rmse_m"])
                e_s = res.smoothed_position_ned_m - truth
                rts = rows["ekf-rts"]
                rts["end_err"].append(np.linalg.norm(e_s, axis=1))
                rts["end_nees"].append(nees(e_s, res.smoothed_position_cov_m2))
                rts["ate_end"].append(res.metrics["smoother"]["ate_rmse_m"])
            else:
                e_s = res.smoothed_position_ned_m - truth
                r["end_err"].append(np.linalg.norm(e_s, axis=1))
                r["end_nees"].append(nees(e_s, res.smoothed_position_cov_m2))
                r["ate_end"].append(res.metrics["smoother"]["ate_rmse_m"])
                g = res.metrics["graph"]
                r["upd"].append(g["update_mean_s"] if b == "isam2" else g["update_max_s"])
            r["lm"].append(res.metrics.get("landmark_position_error_mean_m") or float("nan"))
            r["wall"].append(wall)
            r["dur"].append(res.metrics["duration_s"])
            print(f"  {name} run {i + 1}/{n_runs} {b}: ATE online {r['ate_on'][-1]:.4f} end {r['ate_end'][-1]:.4f} "
                  f"({wall:.2f} s)", flush=True)
    return rows


def _band(nees_runs: list) -> float:
    K = min(len(a) for a in nees_runs)
    return anees(np.array([a[:K] for a in nees_runs]), 3)["fraction_in_band"]


def table(name: str, rows: dict, n_runs: int) -> str:
    out = [f"### {name} ({n_runs} runs, mode {SCENARIOS[name]['mode']})", "",
           "| backend | ATE current-time (m) | ATE held at end of dive (m) | end / EKF online | ANEES in band online | "
           "ANEES in band end | landmark pos. error (m) | time per update (ms) | real-time factor |",
           "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    ekf_on = float(np.mean(rows["ekf"]["ate_on"])) if "ekf" in rows else float("nan")
    for b, r in rows.items():
        end = float(np.mean(r["ate_end"]))
        if b == "ekf-rts":
            out.append(f"| EKF + RTS (offline) | - | {end:.4f} | {end / ekf_on:.2f}x | - | {_band(r['end_nees']):.0%} "
                       f"| - | - | - |")
            continue
        upd = f"{1e3 * np.mean(r['upd']):.2f}" if r["upd"] else "-"
        rtf = float(np.sum(r["dur"]) / np.sum(r["wall"]))
        out.append(f"| {b} | {np.mean(r['ate_on']):.4f} | {end:.4f} | {end / ekf_on:.2f}x | {_band(r['online_nees']):.0%} "
                   f"| {_band(r['end_nees']):.0%} | {np.nanmean(r['lm']):.4f} | {upd} | {rtf:.0f}x |")
    if "batch" in rows:
        out.append("")
        out.append("batch: 'time per update' is its one optimisation at the end of the dive; its current-time row is "
                   "its front-end filter's.")
    return "\n".join(out)


def write_csv(directory: str, name: str, rows: dict, n_runs: int, seed0: int = 0) -> None:
    """Mean error over time per backend (current-time and end-of-dive) as ``error_over_time_<name>.csv`` (+ .json,
    :mod:`semslam.report.backends`); :func:`main` then writes ``report.html`` with the figure."""
    from semslam.report.backends import write_error_over_time

    curves, stats = {}, {}
    for b, r in rows.items():
        for kind, ate, nees_key in (("online", "ate_on", "online_nees"), ("end", "ate_end", "end_nees")):
            if r.get(f"{kind}_err"):
                K = min(len(a) for a in r[f"{kind}_err"])
                key = f"{b}_{kind}"
                curves[key] = np.mean([a[:K] for a in r[f"{kind}_err"]], axis=0)
                stats[key] = {"ate_rmse_mean_m": float(np.mean(r[ate])), "fraction_in_band": _band(r[nees_key])}
    K = min(len(c) for c in curves.values())
    sc = SCENARIOS[name]
    scenario = {"benchmark": "benchmarks/backends.py", "mode": sc["mode"], "n_runs": n_runs, "seed": seed0,
                "yaw_bias_deg": sc["yaw_bias_deg"], "config_overrides": sc["overrides"]}
    write_error_over_time(directory, name, np.arange(K) * 0.5, curves, scenario=scenario, stats=stats)


def timing(backends, repeats: int = 3) -> str:
    """Best-of-``repeats`` wall time of one pose run of mission 0 per backend (less sensitive to machine load)."""
    mission = make_dataset(0)
    cfg = SlamConfig()
    lines = ["| backend | mission (s) | wall, best of %d (s) | real-time factor |" % repeats, "|---|---:|---:|---:|"]
    truth_run(mission, "pose", cfg, 0, "ekf")  # warm-up (numba cache, imports)
    truth_run(mission, "pose", cfg, 0, "isam2")
    for b in backends:
        w = min(_timed(mission, cfg, b) for _ in range(repeats))
        lines.append(f"| {b} | {mission.duration_s:.0f} | {w:.2f} | {mission.duration_s / w:.0f}x |")
    return "\n".join(lines)


def _timed(mission, cfg, backend) -> float:
    t0 = time.perf_counter()
    truth_run(mission, "pose", cfg, 0, backend)
    return time.perf_counter() - t0


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scenarios", default="default,heading")
    ap.add_argument("--backends", default="ekf,isam2,batch")
    ap.add_argument("--csv", help="directory for the mean error-over-time CSV per scenario")
    ap.add_argument("--timing", action="store_true", help="only the best-of-3 real-time factor on mission 0")
    args = ap.parse_args(argv)
    backends = tuple(args.backends.split(","))
    if args.timing:
        print(timing(backends))
        print(f"(load {os.getloadavg()[0]:.1f})")
        return
    for name in args.scenarios.split(","):
        t0 = time.perf_counter()
        rows = run_scenario(name, args.runs, backends, args.seed)
        print()
        print(table(name, rows, args.runs))
        print(f"\n(wall time {time.perf_counter() - t0:.0f} s; load {os.getloadavg()[0]:.1f})\n", flush=True)
        if args.csv:
            write_csv(args.csv, name, rows, args.runs, args.seed)
    if args.csv:
        from semslam.report.backends import build_backends_report

        print(f"report: {build_backends_report(args.csv)}")


if __name__ == "__main__":
    main()
