"""Chi-square nearest-view queries: the exact index against the linear scan (issue 15, item 5).

    .venv/bin/python benchmarks/matching_query.py [--sizes 1000 10000 100000] [--queries 200] [--azimuths 64]

For ESF (640 bins) and VFH (308 bins) databases of 1k, 10k and 100k views it prints a table: the fit time of
``Chi2NearestNeighbor(algorithm="index")`` (the index build) and the index's extra memory; then for "near"
and "clutter" queries, the median time of one ``kneighbors`` call (one query, k = 1, through the public API)
with the index (wall clock, and in brackets the CPU time of the calling thread, which the machine's other
jobs do not inflate: one query runs on that thread) and with the linear scan (``algorithm="brute"``, the code before the
index, on both cores), the speed-up (wall clock over wall clock), the rows whose distance was summed at all
(most abandoned after a few blocks); and the exactness check: the index's rows and distances must equal the
linear scan's bit for bit, for every timed query with k = 1 and k = 5.

Data (clustered like real views; pruning depends on it):

* base descriptors: ESF and VFH (PCL 1.13 variant) of the simulator's Kinect views of the four built-in
  fittings at ``--azimuths`` azimuths each (256 base views by default), voxel grid 5 mm, normals within 15 mm,
  as the built-in database computes them;
* a database view: a base view and the next azimuth of the same object, mixed with a weight ``w ~ U(0, 1)``
  (a viewpoint in between), then resampled: ESF as Poisson(p * n) / n with n = 150,000, which reproduces the
  chi-square spread between two ESF runs of one view with 20,000 samples (~0.0035); VFH block by block from
  ``N ~ U[300, 1500)`` points (each point adds 100 / N to one bin of a block, Poisson approximation); stored as
  float32, as databases are;
* "near" queries: fresh draws of the same law (not in the database), so that the nearest view is at the noise
  level: a new scan of a known object, the hard case for pruning because many views are almost as near;
* "clutter" queries: the average of two such draws of different views (often different objects), far from
  every view, like the descriptor of an unknown cluster.

The machine is a shared 2-core VM (other jobs running), so timings carry noise: medians of many queries.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

ESF_NOISE_COUNTS = 150_000
VFH_BLOCKS = ((0, 45), (45, 90), (90, 135), (135, 180), (180, 308))


def base_descriptors(n_azimuths: int, seed: int) -> dict[str, np.ndarray]:
    """ESF (V, 640) and VFH (V, 308) of the four fittings' Kinect views, ordered object by object, azimuth by
    azimuth (V = 4 n_azimuths)."""
    from semslam.descriptors import compute_esf, compute_vfh, estimate_normals
    from semslam.segmentation import voxel_downsample
    from semslam.simulation import builtin_view_clouds

    views, _ = builtin_view_clouds(seed=seed, n_views=n_azimuths)
    esf, vfh = [], []
    for i, (_, _, cloud) in enumerate(views):
        pts = voxel_downsample(cloud.points_xyz_m, 0.005)
        esf.append(compute_esf(pts, seed=seed + i))
        normals = estimate_normals(pts, radius_m=0.015, viewpoint_xyz_m=cloud.viewpoint_xyz_m).normals_xyz
        ok = np.isfinite(normals).all(axis=1)
        vfh.append(compute_vfh(pts[ok], normals[ok], viewpoint_xyz_m=cloud.viewpoint_xyz_m))
    return {"esf": np.array(esf), "vfh": np.array(vfh)}


def draw(kind: str, bases: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` views from the law of the module docstring (float64 array of float32 values)."""
    per_object = len(bases) // 4
    i = rng.integers(len(bases), size=n)
    j = (i // per_object) * per_object + (i % per_object + 1) % per_object  # next azimuth, same object
    w = rng.random((n, 1))
    p = (1.0 - w) * bases[i] + w * bases[j]
    if kind == "esf":
        out = rng.poisson(p * ESF_NOISE_COUNTS) / ESF_NOISE_COUNTS
    else:
        n_points = rng.integers(300, 1500, size=(n, 1))
        out = np.zeros_like(p)
        for lo, hi in VFH_BLOCKS:
            block = p[:, lo:hi]
            total = block.sum(axis=1, keepdims=True)
            safe = np.where(total > 0, total, 1.0)
            out[:, lo:hi] = rng.poisson(block / safe * n_points) * (total / n_points)
    return out.astype(np.float32).astype(np.float64)


def draw_in_chunks(kind: str, bases: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    return np.concatenate([draw(kind, bases, min(20_000, n - a), rng) for a in range(0, n, 20_000)])


def timings(index_fn, brute_fn, queries: np.ndarray, n_brute: int) -> tuple[float, float, float]:
    """Median wall ms of one query with the index, median CPU ms of the same (thread CPU time: the query runs
    on the calling thread, and the machine's other jobs do not count), median wall ms of the linear scan on the
    first ``n_brute`` queries. The two are timed apart: the linear scan's parallel workers spin a while after
    each call, which would slow the next index query."""
    wall, cpu, lin = [], [], []
    for q in queries:
        c, t = time.thread_time(), time.perf_counter()
        index_fn(q[None])
        wall.append(time.perf_counter() - t)
        cpu.append(time.thread_time() - c)
    for q in queries[:n_brute]:
        t = time.perf_counter()
        brute_fn(q[None])
        lin.append(time.perf_counter() - t)
    return tuple(1e3 * float(np.median(v)) for v in (wall, cpu, lin))


def run(kind: str, bases: np.ndarray, size: int, n_queries: int, rng: np.random.Generator) -> dict:
    from semslam.recognition import Chi2NearestNeighbor

    X = draw_in_chunks(kind, bases, size, rng)
    y = np.zeros(size, dtype=int)
    near = draw(kind, bases, n_queries, rng)
    clutter = 0.5 * (draw(kind, bases, n_queries, rng) + draw(kind, bases, n_queries, rng))
    t = time.perf_counter()
    index = Chi2NearestNeighbor(algorithm="index").fit(X, y)
    fit_s = time.perf_counter() - t
    brute = Chi2NearestNeighbor(algorithm="brute").fit(X, y)
    n_brute = max(10, min(n_queries, 2_000_000 // size))  # the linear scan is slow at 100k: fewer queries
    out = {"fit_s": fit_s, "extra_mb": index.index_.nbytes / 2**20}
    for name, Q in (("near", near), ("clutter", clutter)):
        out[f"{name}_ms"], out[f"{name}_cpu_ms"], out[f"{name}_brute_ms"] = timings(
            index.kneighbors, brute.kneighbors, Q, n_brute)
        bounded = []
        for q in Q:
            index.kneighbors(q[None])
            bounded.append(int(index.index_.n_bounded_[0]))
        out[f"{name}_rows"] = float(np.median(bounded))
    exact = True
    Q = np.vstack([near, clutter])
    for k in (1, 5):
        for a in range(0, len(Q), 50):
            d, i = index.kneighbors(Q[a:a + 50], k)
            bd, bi = brute.kneighbors(Q[a:a + 50], k)
            exact &= bool(np.array_equal(d, bd) and np.array_equal(i, bi))
    out["exact"] = exact
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10_000, 100_000])
    parser.add_argument("--queries", type=int, default=200, help="near and clutter queries per size (each)")
    parser.add_argument("--azimuths", type=int, default=64, help="base views per object")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    import numba

    from semslam.recognition import Chi2NearestNeighbor

    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores, numba {numba.__version__} "
          f"({numba.config.NUMBA_NUM_THREADS} threads), load average at start {os.getloadavg()[0]:.2f}")
    t = time.perf_counter()
    bases = base_descriptors(args.azimuths, args.seed)
    print(f"# {len(bases['esf'])} base views described in {time.perf_counter() - t:.1f} s")
    warm = np.random.default_rng(1).random((300, 8))
    Chi2NearestNeighbor(algorithm="index").fit(warm, np.zeros(300)).kneighbors(warm[:2])  # compile once
    Chi2NearestNeighbor(algorithm="index").fit(warm.astype(np.float32), np.zeros(300)).kneighbors(warm[:1])
    rng = np.random.default_rng(args.seed)
    print()
    print("| descriptor | views | index fit s | extra MB | near: ms/query (CPU ms) | linear scan ms | speed-up "
          "| rows summed | clutter: ms/query (CPU ms) | linear scan ms | speed-up | rows summed | exact |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    for kind in ("esf", "vfh"):
        for size in args.sizes:
            r = run(kind, bases[kind], size, args.queries, rng)
            cells = [f"{kind.upper()} ({bases[kind].shape[1]})", f"{size:,}", f"{r['fit_s']:.2f}", f"{r['extra_mb']:.0f}"]
            for name in ("near", "clutter"):
                cells += [f"{r[name + '_ms']:.3f} ({r[name + '_cpu_ms']:.3f})", f"{r[name + '_brute_ms']:.2f}",
                          f"{r[name + '_brute_ms'] / r[name + '_ms']:.0f}x",
                          f"{r[name + '_rows']:.0f} ({100 * r[name + '_rows'] / size:.1f} %)"]
            cells.append("yes" if r["exact"] else "NO")
            print("| " + " | ".join(cells) + " |", flush=True)
    print(f"\n# load average at end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
