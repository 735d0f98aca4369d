"""Scaling of the backends to large maps (issue 17): a synthetic long dive with 1,000 and 10,000 landmarks, time per
update and memory of the EKF against iSAM2.

Run: ``.venv/bin/python benchmarks/graph_scaling.py [--sizes 1000,10000] [--phases]`` (prints a markdown table;
``--phases``: where the time goes), or ``--chain 1000,10000,20000``: GTSAM's own iSAM2 update on a plain chain.

The dive: a straight survey line; a keyframe every 0.5 s (the graph backend's history rate), one landmark per
keyframe, each seen from 4 consecutive keyframes (6-DoF pose detections), and every 100th keyframe re-observes a
landmark seen 50 keyframes earlier (short loop closures). The iSAM2 side builds the same factors as
:class:`~semslam.slam.graph.GraphSession` (segment between-factors on the 6-dim vehicle state, the filter's landmark
measurement factor, one iSAM2 update and the current keyframe's marginal per keyframe); its memory is the process'
resident-set growth. The variables start where GraphSession's front-end filter would put them: a keyframe at the
prediction from the graph's estimate of the previous one, a new landmark placed from that guess by its detection
(``SCALING_TRUTH_GUESS=1``: at the noiseless truth instead, as before; the estimates then drift more than the
relinearisation threshold from it and every update relinearises its detection factors). The EKF side: its dense
covariance holds ``(6 + 6 N)^2`` doubles; an object update costs the
compressed EKF ``O(|A|^2)`` (active area) plus an ``O(n^2)`` flush whenever the active area changes, and the dense
EKF an ``O(n^2)`` rank-6 covariance update every time (measured where the matrix fits in memory, from
``benchmarks/slam.py``).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from functools import partial

import gtsam
import numpy as np

REALISTIC = os.environ.get("SCALING_TRUTH_GUESS", "0") != "1"

from semslam.detection import Detection
from semslam.geometry import RigidTransform
from semslam.slam.association import measurement_from_detection
from semslam.slam.graph import factors as fac
from semslam.slam.graph.backend import GraphBackend

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return float(line.split()[1]) / 1024.0
    return float("nan")


def bench_isam2(n_landmarks: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    rss0 = _rss_mb()
    g = GraphBackend("isam2", 6)
    dt, v = 0.5, 0.5
    x = np.array([0.0, 0.0, 5.0, v, 0.0, 0.0])
    g.start(0.0, x, np.diag([1e-6] * 3 + [1e-3] * 3))
    F = np.eye(6)
    F[0:3, 3:6] = np.eye(3) * dt
    q = 0.01 ** 2
    Q = np.zeros((6, 6))
    Q[0:3, 0:3], Q[0:3, 3:6], Q[3:6, 3:6] = np.eye(3) * q * dt ** 3 / 3, np.eye(3) * q * dt ** 2 / 2, np.eye(3) * q * dt
    Q[3:6, 0:3] = Q[0:3, 3:6]
    dvl = np.hstack([np.zeros((3, 3)), np.eye(3)])
    R_dvl = np.eye(3) * 0.005 ** 2
    cov_det = np.diag([1e-4] * 3 + [1e-3] * 3)
    lm_true, times, phases, n_kf = [], [], [], n_landmarks + 4
    for k in range(1, n_kf):
        # the segment: prediction and one DVL sample, pre-integrated as GraphSession does
        g.seg.predict(F, np.zeros(6), Q)
        g.seg.measure(dvl, np.array([v, 0.0, 0.0]) + rng.normal(0, 0.005, 3), R_dvl)
        x = F @ x
        seen = [j for j in range(max(0, k - 4), min(k, n_landmarks))]
        if k % 100 == 0 and k > 60:
            seen.append(k - 50)
        if k <= n_landmarks:  # a new landmark 1 m to starboard of this keyframe
            lm_true.append(np.r_[x[0:3] + [0.0, 1.0, 0.0], rng.normal(0, 0.2, 3)])
        T_wv = RigidTransform.from_xyz_rpy(x[0:3], [0.0, 0.0, 0.0])
        meas = [measurement_from_detection(Detection("a", 0.0, T_wv.inverse() @ RigidTransform.from_xyz_rpy(
            lm_true[j][:3], lm_true[j][3:]), cov_det, stamp_s=k * dt), RigidTransform.identity()) for j in seen]
        # the front end's guesses, as GraphSession's filter gives them: the keyframe predicted from the graph's estimate
        # of the previous one, a new landmark placed from that guess by its detection
        guess = F @ g.vector(g.key) if REALISTIC and k > 1 else x
        t0 = time.perf_counter()  # the front end's work above is not timed: the graph's from here
        key = g.keyframe(k * dt, guess)
        if k <= n_landmarks:
            lm0 = np.r_[guess[0:3] - x[0:3], np.zeros(3)] if REALISTIC else 0.0
            kl = g.new_landmark(lm_true[-1] + lm0 + np.r_[rng.normal(0, 0.01, 3), rng.normal(0, 0.01, 3)])
            g.add_factor(fac.prior_factor(kl, lm_true[-1], np.eye(6) * 100.0, "a weak landmark prior"))
        for j, m in zip(seen, meas):
            g.add_landmark_factor((key, fac.L(j)), partial(fac.landmark_factor, key, fac.L(j), m, np.eye(3), "pose",
                                                           m.noise_cov, n_v=6, yaw_bias=False, i_yaw=-1))
        t1 = time.perf_counter()
        g.flush()
        t2 = time.perf_counter()
        g.vector(key)
        t3 = time.perf_counter()
        g.cov(key)
        times.append(time.perf_counter() - t0)
        phases.append((t1 - t0, t2 - t1, t3 - t2, t0 + times[-1] - t3))
    t = np.asarray(times)
    return {"n": n_landmarks, "keyframes": n_kf, "update_ms_median": 1e3 * float(np.median(t)),
            "update_ms_p95": 1e3 * float(np.percentile(t, 95)), "update_ms_last100": 1e3 * float(t[-100:].mean()),
            "total_s": float(t.sum()), "rss_mb": _rss_mb() - rss0, "phases_ms": 1e3 * np.asarray(phases),
            "relinearized": g.n_relinearized}


def bench_chain(n: int) -> float:
    """GTSAM alone: mean iSAM2 update (ms) over the last 500 of ``n`` keyframes of a chain of native linear 3-dof
    between-factors (no Python factor, no landmark): what GTSAM 4.3.0's update costs as the tree grows."""
    isam = gtsam.ISAM2(gtsam.ISAM2Params())
    ts = []
    for i in range(n):
        f, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        v.insert(fac.X(i), np.zeros(3))
        f.add(fac.linear_factor([fac.X(0)], [np.eye(3)], np.zeros(3)) if i == 0 else
              fac.linear_factor([fac.X(i - 1), fac.X(i)], [-np.eye(3), np.eye(3)], np.ones(3)))
        t0 = time.perf_counter()
        isam.update(f, v)
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.mean(ts[-500:]))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000,10000")
    ap.add_argument("--phases", action="store_true",
                    help="also the time per phase (building the factors, iSAM2 update, estimate, marginal) over the "
                         "first, middle and last 100 keyframes")
    ap.add_argument("--chain", help="only GTSAM's own update time on a chain of these lengths (e.g. 1000,10000,20000)")
    args = ap.parse_args(argv)
    if args.chain:
        print("| chain keyframes | iSAM2 update, mean of the last 500 (ms) |\n|---:|---:|")
        for n in (int(s) for s in args.chain.split(",")):
            print(f"| {n} | {bench_chain(n):.3f} |", flush=True)
        return
    sizes = [int(s) for s in args.sizes.split(",")]
    from slam import bench_dense_update, bench_update  # benchmarks/slam.py

    print("| landmarks | backend | update (ms): median / p95 / last 100 | memory (MB) | note |")
    print("|---|---|---|---|---|")
    for n in sizes:
        r = bench_isam2(n)
        print(f"| {n} | iSAM2 (keyframe update + current marginal) | {r['update_ms_median']:.2f} / {r['update_ms_p95']:.2f} / "
              f"{r['update_ms_last100']:.2f} | {r['rss_mb']:.0f} (RSS growth) | {r['keyframes']} keyframes, "
              f"{r['total_s']:.0f} s in all |", flush=True)
        if args.phases:
            ph, k = r["phases_ms"], len(r["phases_ms"])
            for name, lo in (("first", 0), ("middle", k // 2 - 50), ("last", k - 100)):
                m = ph[lo:lo + 100].mean(axis=0)
                print(f"|   | phases, {name} 100 keyframes (ms) | factors {m[0]:.2f}, iSAM2 update {m[1]:.2f}, "
                      f"estimate {m[2]:.2f}, marginal {m[3]:.2f} | | {r['relinearized']} detection factors "
                      f"relinearised in all |", flush=True)
        mem = (6 + 6 * n) ** 2 * 8 / 1e6
        if mem < 2000:
            c = bench_update(n, repeats=20)
            print(f"| {n} | compressed EKF (active area) | {c['update_ms']:.3f} + flush {c['flush_ms']:.0f} | "
                  f"{mem:.0f} (covariance) | flush when the active area changes |", flush=True)
            print(f"| {n} | dense EKF | {bench_dense_update(n):.1f} (rank-6 P update) | {mem:.0f} (covariance) | "
                  f"every object update |", flush=True)
        else:
            print(f"| {n} | EKF (dense or compressed) | - | {mem:.0f} (covariance) | over this benchmark's 2 GB budget: "
                  f"not run (a flush alone touches every entry) |", flush=True)


if __name__ == "__main__":
    main()
