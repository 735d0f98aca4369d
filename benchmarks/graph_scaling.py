"""Scaling of the backends to large maps (issue 17): a synthetic long dive with 1,000 and 10,000 landmarks, time per
update and memory of the EKF against iSAM2.

Run: ``.venv/bin/python benchmarks/graph_scaling.py [--sizes 1000,10000]`` (prints a markdown table).

The dive: a straight survey line; a keyframe every 0.5 s (the graph backend's history rate), one landmark per
keyframe, each seen from 4 consecutive keyframes (6-DoF pose detections), and every 100th keyframe re-observes a
landmark seen 50 keyframes earlier (short loop closures). The iSAM2 side builds the same factors as
:class:`~semslam.slam.graph.GraphSession` (segment between-factors on the 6-dim vehicle state, the filter's landmark
measurement factor, one iSAM2 update and the current keyframe's marginal per keyframe); its memory is the process'
resident-set growth. The EKF side: its dense covariance holds ``(6 + 6 N)^2`` doubles; an object update costs the
compressed EKF ``O(|A|^2)`` (active area) plus an ``O(n^2)`` flush whenever the active area changes, and the dense
EKF an ``O(n^2)`` rank-6 covariance update every time (measured where the matrix fits in memory, from
``benchmarks/slam.py``).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

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
    lm_true, times, n_kf = [], [], n_landmarks + 4
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
        t0 = time.perf_counter()  # the front end's work above is not timed: the graph's from here
        key = g.keyframe(k * dt, x)
        if k <= n_landmarks:
            kl = g.new_landmark(lm_true[-1] + np.r_[rng.normal(0, 0.01, 3), rng.normal(0, 0.01, 3)])
            g.add_factor(fac.prior_factor(kl, lm_true[-1], np.eye(6) * 100.0, "a weak landmark prior"))
        for j, m in zip(seen, meas):
            g.add_factor(fac.landmark_factor(key, fac.L(j), m, np.eye(3), "pose", m.noise_cov, n_v=6,
                                             yaw_bias=False, i_yaw=-1))
        g.flush()
        g.vector(key)
        g.cov(key)
        times.append(time.perf_counter() - t0)
    t = np.asarray(times)
    return {"n": n_landmarks, "keyframes": n_kf, "update_ms_median": 1e3 * float(np.median(t)),
            "update_ms_p95": 1e3 * float(np.percentile(t, 95)), "update_ms_last100": 1e3 * float(t[-100:].mean()),
            "total_s": float(t.sum()), "rss_mb": _rss_mb() - rss0}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000,10000")
    args = ap.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",")]
    from slam import bench_dense_update, bench_update  # benchmarks/slam.py

    print("| landmarks | backend | update (ms): median / p95 / last 100 | memory (MB) | note |")
    print("|---|---|---|---|---|")
    for n in sizes:
        r = bench_isam2(n)
        print(f"| {n} | iSAM2 (keyframe update + current marginal) | {r['update_ms_median']:.2f} / {r['update_ms_p95']:.2f} / "
              f"{r['update_ms_last100']:.2f} | {r['rss_mb']:.0f} (RSS growth) | {r['keyframes']} keyframes, "
              f"{r['total_s']:.0f} s in all |", flush=True)
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
