"""SLAM benchmark: cost of one object update vs map size (compressed EKF) and mission real-time factor.

Run: ``.venv/bin/python benchmarks/slam.py`` (prints markdown tables).
"""

from __future__ import annotations

import time

import numpy as np

from semslam.detection import Detection
from semslam.simulation.truth_slam import run_truth_slam
from semslam.geometry import RigidTransform, rotation_from_rpy
from semslam.slam import _ekf_kernels as kern
from semslam.slam.association import innovation, measurement_from_detection
from semslam.slam.ekf import SemanticEkf
from semslam.simulation.synthetic import square_dataset


def _map(n_landmarks: int, rng) -> SemanticEkf:
    ekf = SemanticEkf(np.zeros(3), [0.3, 0.0, 0.0], np.eye(6) * 1e-2)
    poses = np.column_stack([rng.uniform(-50, 50, (n_landmarks, 2)), np.full(n_landmarks, 5.0),
                             rng.uniform(-0.2, 0.2, (n_landmarks, 2)), rng.uniform(-3, 3, n_landmarks)])
    poses[0, :3] = [1.0, 0.0, 5.0]
    covs = np.tile(np.diag([0.01] * 3 + [0.003] * 3), (n_landmarks, 1, 1))
    ekf.add_prior_landmarks(poses, covs, ["a"] * n_landmarks)
    # correlate the map (a full, dense covariance) by one dense round of position updates on every landmark
    ekf.set_active_landmarks(range(n_landmarks))
    return ekf


def bench_update(n_landmarks: int, repeats: int = 50) -> dict:
    rng = np.random.default_rng(0)
    ekf = _map(n_landmarks, rng)
    for j in rng.choice(n_landmarks, min(n_landmarks, 30), replace=False):  # correlate some of the map
        off = ekf.landmarks[j].offset
        ekf.update(np.r_[0, 1, 2, off, off + 1, off + 2], np.hstack([-np.eye(3), np.eye(3)]), rng.normal(0, .01, 3),
                   np.eye(3) * 1e-3)
    ekf.set_active_landmarks([0])  # active area: vehicle + the observed landmark
    x0 = ekf.landmark_pose(0)
    det = Detection("a", 0.0, RigidTransform.from_xyz_rpy(x0[:3] - [0.0, 0.0, 0.0], x0[3:]),
                    np.diag([1e-4] * 3 + [1e-3] * 3))
    meas = measurement_from_detection(det, RigidTransform.identity())
    R = np.eye(3)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        inn = innovation(ekf, 0, meas, R, None)
        ekf.update(inn.idx, inn.H, inn.nu, inn.R)
        ekf.predict(0.2, R, velocity_rw=0.01)
        times.append(time.perf_counter() - t)
    t = time.perf_counter()
    ekf.flush()
    t_flush = time.perf_counter() - t
    return {"n": n_landmarks, "update_ms": 1e3 * float(np.median(times)), "flush_ms": 1e3 * t_flush}


def bench_dense_update(n_landmarks: int) -> float:
    """Reference: the O(n^2) rank-6 covariance update a non-compressed EKF pays on every object update."""
    n = 6 + 6 * n_landmarks
    rng = np.random.default_rng(0)
    P = np.eye(n)
    W = rng.normal(size=(n, 6)) * 1e-3
    kern.subtract_outer_inplace(P, W)
    t = time.perf_counter()
    for _ in range(3):
        kern.subtract_outer_inplace(P, W)
    return 1e3 * (time.perf_counter() - t) / 3


def main() -> None:
    print("## Object update cost vs map size (compressed EKF, active area = vehicle + 1 landmark)\n")
    print("| landmarks | update + predict (ms, median) | one flush (ms) | dense rank-6 P update (ms) |")
    print("|---|---|---|---|")
    for n in (10, 100, 1000):
        r = bench_update(n)
        print(f"| {n} | {r['update_ms']:.3f} | {r['flush_ms']:.1f} | {bench_dense_update(n):.1f} |")
    print("\n## Mission processing speed (truth-based detections generated inside run_truth_slam; best of 3)\n")
    print("| mission | mode | mission (s) | wall (s) | real-time factor |")
    print("|---|---|---|---|---|")
    missions = [("synthetic square, 3 loops", square_dataset(seed=0), {})]
    from semslam.experiments.montecarlo import make_dataset
    from semslam.simulation.truth_slam import builtin_symmetries

    missions.append(("simulator default (3 loops)", make_dataset(0, source="simulator"), builtin_symmetries()))
    for name, m, sym in missions:
        run_truth_slam(m, mode="pose", seed=0, symmetries=sym)  # warm-up (numba cache)
        for mode in ("dr", "position", "pose", "pose+heading"):
            w = np.inf
            for _ in range(3):
                t = time.perf_counter()
                run_truth_slam(m, mode=mode, seed=0, symmetries=sym)
                w = min(w, time.perf_counter() - t)
            print(f"| {name} | {mode} | {m.duration_s:.0f} | {w:.2f} | {m.duration_s / w:.0f}x |")


if __name__ == "__main__":
    main()
