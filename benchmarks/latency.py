"""Tail latency of scan -> detections (issue #18, item 5): p50 / p90 / p99 over the default mission's scans,
warm (the recognizer prepared as the demo does it, the first scan dropped), and the wall time of a cold
single-scan ``semslam recognize SCAN --db DB`` (a fresh process: best and median of N) with its ``timings_ms``, on the
demo's database (the built-in Kinect views, 8 per class) and on the database a user of the laser vehicle builds
(``semslam db build --builtin --sensor laser``: 64 views and 16 pose-model views per class, ~8 s to build).

Run from the repository root, on the demo's mission and database (``make demo`` or ``semslam demo --quick --out
DIR`` makes them; without them the script stops and says so)::

    .venv/bin/python benchmarks/latency.py                                   # runs/demo, warm + cold
    .venv/bin/python benchmarks/latency.py --run runs/demo --repeat 3 --cold-scans 10 40
    .venv/bin/python benchmarks/latency.py --only warm --warm-up models     # the warm-up before issue #18
    .venv/bin/python benchmarks/latency.py --only cold
    .venv/bin/python benchmarks/latency.py --only cold --cold-scans 1 10 15 17 25 --cold-repeat 5 --cold-cache empty

The cold table ends with the floor under any such command: a fresh Python that imports numpy, scipy.spatial and
numba and calls one cached numba kernel (numba's first call sets up its compiler and typing registries). The
children run with Python's bytecode cache on, as an installed package has it (``--no-bytecode`` keeps the parent's
``PYTHONDONTWRITEBYTECODE``: every run then compiles semslam's sources again). Last, the numba kernels of one cold
run of the first ``--cold-scans`` scan: each one's first call (loaded from numba's cache) and the bytes it read.

Every figure is printed with the machine's load average (``os.getloadavg``): the latencies are only
comparable at a similar load.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def _load() -> str:
    return "load %.2f %.2f %.2f" % os.getloadavg()


def _pct(x) -> str:
    x = np.asarray(x, dtype=float)
    p50, p90, p99 = np.percentile(x, [50, 90, 99])
    return f"p50 {p50:.1f} ms, p90 {p90:.1f} ms ({p90 / p50:.2f}x), p99 {p99:.1f} ms, max {x.max():.1f} ms"


def warm(args) -> None:
    from semslam.cli._inputs import load_dataset
    from semslam.pipeline import PipelineConfig, ScanRecognizer
    from semslam.pipeline.dataset_detection import scan_seed
    from semslam.recognition import load_database

    run = Path(args.run)
    cfg = json.loads((run / "config.json").read_text()).get("demo", {}) if (run / "config.json").is_file() else {}
    db = load_database(run / "db.npz")
    ds = load_dataset(str(run / "mission"))
    pipe = PipelineConfig(descriptor=cfg.get("descriptor", "esf+vfh"), classifier=cfg.get("classifier", "chi2"))
    seed = int(cfg.get("seed", 0))
    clouds = [(rec, ds.load_scan(rec.scan_id)) for rec in ds.scans]  # read first: time recognition only
    print(f"\n## Warm scan -> detections ({run}, {len(clouds)} scans, descriptor {pipe.descriptor}, "
          f"classifier {pipe.classifier}, warm-up {args.warm_up})\n")
    for rep in range(args.repeat):
        rec_ = ScanRecognizer(db, pipe, seed=seed)
        if args.warm_up == "models":  # the warm-up before issue #18: the pose models only
            for label in db.classes:
                rec_.pose_model(label, int(db.views_of(label)[0]))
        else:
            rec_.warm_up()  # as the demo does
        load0 = _load()
        rows = []
        for rec, cloud in clouds:
            stamps = ds.point_stamps_s(rec, cloud)
            g0 = sum(s["collections"] for s in gc.get_stats())
            t0 = time.perf_counter()
            r = rec_.recognize(cloud, seed=scan_seed(seed, rec.scan_id), stamp_s=rec.end_stamp_s, scan_id=rec.scan_id,
                               point_stamps_s=stamps)
            wall = (time.perf_counter() - t0) * 1e3
            g1 = sum(s["collections"] for s in gc.get_stats())
            t = r.timings_ms
            rows.append((wall, t["total"], t["segmentation"], t["descriptors"], t["pose"], len(r.clusters),
                         len(r.detections), g1 - g0, rec.scan_id))
        a = np.array(rows)[1:]  # warm: after a first scan
        print(f"repeat {rep + 1}: first scan {rows[0][0]:.1f} ms; every scan (as the demo's recognition.json): "
              f"{_pct(np.array(rows)[:, 1])}")
        print(f"repeat {rep + 1} ({load0} -> {_load()}): wall {_pct(a[:, 0])}")
        print(f"  timings_ms total: {_pct(a[:, 1])}")
        for name, col in (("segmentation", 2), ("descriptors", 3), ("pose", 4)):
            print(f"  {name}: {_pct(a[:, col])}")
        slow = a[:, 0] > np.percentile(a[:, 0], 90)
        print(f"  scans above p90: {int(slow.sum())}; their mean clusters {a[slow, 5].mean():.1f} / detections "
              f"{a[slow, 6].mean():.1f} / GC runs {a[slow, 7].mean():.1f}, against {a[~slow, 5].mean():.1f} / "
              f"{a[~slow, 6].mean():.1f} / {a[~slow, 7].mean():.1f} for the others")
        top = np.argsort(-a[:, 0])[:3]
        print("  slowest: " + "; ".join(f"scan {int(a[i, 8])} {a[i, 0]:.1f} ms (seg {a[i, 2]:.1f}, desc {a[i, 3]:.1f}, "
                                        f"pose {a[i, 4]:.1f}, {int(a[i, 6])} det, {int(a[i, 7])} GC)" for i in top))
        by_det = {int(n): np.median(a[a[:, 6] == n, 0]) for n in np.unique(a[:, 6])}
        print("  median wall by detections per scan: " + ", ".join(f"{n}: {v:.1f} ms ({int((a[:, 6] == n).sum())} scans)"
                                                                for n, v in by_det.items()))


def cold(args) -> None:
    """Fresh ``semslam recognize`` processes: process wall (and CPU: user + sys, which the machine's load inflates
    less) best and median of ``--cold-repeat``, with the on-disk cache as it is (``--cold-cache warm``: one
    unmeasured run fills it first) or empty (a new empty ``SEMSLAM_CACHE_DIR`` for every run), on every database
    of ``--cold-db``."""
    import tempfile

    run = Path(args.run)
    base_env = _child_env(args.no_bytecode)
    with tempfile.TemporaryDirectory(prefix="semslam_cold_db_") as tmp:
        for which in args.cold_db:
            _cold_table(args, run, _cold_database(which, run, Path(tmp), base_env), base_env)
    _floor(args.cold_repeat, base_env)
    _kernel_loads(run, args.cold_scans[0], base_env)


def _cold_database(which: str, run: Path, tmp: Path, env: dict) -> Path:
    """The database of a cold table: ``demo`` (the run's db.npz: the built-in Kinect views, 8 per class),
    ``user`` (what a user of the laser vehicle builds: ``semslam db build --builtin --sensor laser``, 64 views
    and 16 pose-model views per class) or a file."""
    if which == "demo":
        return run / "db.npz"
    if which != "user":
        return Path(which)
    out = tmp / "user_db.npz"
    cmd = [str(Path(sys.executable).with_name("semslam")), "db", "build", "--builtin", "--sensor", "laser",
           "--out", str(out)]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, env=env)
    print(f"\n(`{' '.join(cmd[1:-2])}`: {time.perf_counter() - t0:.0f} s)")
    return out


def _cold_table(args, run: Path, db: Path, base_env: dict) -> None:
    """One cold table: fresh ``semslam recognize`` processes on ``db``."""
    import shutil
    import tempfile

    exe = str(Path(sys.executable).with_name("semslam"))
    print(f"\n## Cold `semslam recognize SCAN --db {db.name} --json` (fresh process, {args.cold_repeat} runs, "
          f"on-disk cache {args.cold_cache}, bytecode cache "
          f"{'off' if base_env.get('PYTHONDONTWRITEBYTECODE') else 'on'})\n")
    print("| scan | detections | load (first run) | wall best / median s | CPU best / median s | "
          "load_db + recognize best / median ms | best run's timings_ms |")
    print("|---|---|---|---:|---:|---:|---|")
    for sid in args.cold_scans:
        scan = run / "mission" / "scans" / f"scan_{sid:05d}.pcd"
        cmd = [exe, "recognize", str(scan), "--db", str(db), "--json"]
        env = dict(base_env)
        if args.cold_cache == "warm":
            subprocess.run(cmd, check=True, capture_output=True, env=env)
        rows, load0 = [], _load()
        for _ in range(args.cold_repeat):
            empty = tempfile.mkdtemp(prefix="semslam_cold_") if args.cold_cache == "empty" else None
            if empty:
                env["SEMSLAM_CACHE_DIR"] = empty
            try:
                t0, cpu0 = time.perf_counter(), _children_cpu_s()
                proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
                wall, cpu = time.perf_counter() - t0, _children_cpu_s() - cpu0
                out, err = proc.stdout, proc.stderr
            finally:
                if empty:
                    shutil.rmtree(empty, ignore_errors=True)
            if proc.returncode:
                raise SystemExit(f"{' '.join(cmd)} failed: {err[-2000:]}")
            payload = json.loads(out)
            t = payload["timings_ms"]
            rows.append((wall, cpu, t["load_db"] + t["total"], t, len(payload["detections"])))
        walls, cpus, inproc = (np.array([r[k] for r in rows]) for k in range(3))
        best = rows[int(np.argmin(walls))]
        print(f"| {sid} | {best[4]} | {load0} | {walls.min():.2f} / {np.median(walls):.2f} | "
              f"{cpus.min():.2f} / {np.median(cpus):.2f} | {inproc.min():.0f} / {np.median(inproc):.0f} | "
              + ", ".join(f"{k} {v:.0f}" for k, v in best[3].items()) + " |")


_FLOOR_KERNEL = '''import numpy as np
from numba import njit


@njit(cache=True)
def total(x):
    return x.sum()
'''


def _floor(repeat: int, env: dict) -> None:
    """The floor row: fresh processes that import numpy, scipy.spatial and numba and call one cached kernel."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="semslam_floor_") as tmp:
        Path(tmp, "floor_kernel.py").write_text(_FLOOR_KERNEL)
        cmd = [sys.executable, "-c", "import numpy, scipy.spatial, numba, floor_kernel; "
               "floor_kernel.total(numpy.ones(3))"]
        env = dict(env, PYTHONPATH=tmp)
        subprocess.run(cmd, check=True, env=env, cwd=tmp)  # fills numba's cache
        load0, walls, cpus = _load(), [], []
        for _ in range(repeat):
            t0, cpu0 = time.perf_counter(), _children_cpu_s()
            subprocess.run(cmd, check=True, env=env, cwd=tmp)
            walls.append(time.perf_counter() - t0)
            cpus.append(_children_cpu_s() - cpu0)
    print(f"| floor: `import numpy, scipy.spatial, numba` + one cached kernel | - | {load0} | "
          f"{min(walls):.2f} / {np.median(walls):.2f} | {min(cpus):.2f} / {np.median(cpus):.2f} | - | - |")


_KERNEL_LOADS = """
import contextlib, io, json, os, sys, threading, time
from numba.core import caching, dispatcher
first, read = dispatcher._DispatcherBase._compile_for_args, caching.IndexDataCacheFile._load_data
loads, mine = [], threading.local()  # (the descriptors' kernels load in two threads at once)
def timed(self, *a, **k):
    t0, mine.read = time.perf_counter(), 0
    try:
        return first(self, *a, **k)
    finally:
        loads.append(((time.perf_counter() - t0) * 1e3, self.py_func.__module__, self.py_func.__name__, mine.read))
def sized(self, name):
    mine.read += os.path.getsize(self._data_path(name))
    return read(self, name)
dispatcher._DispatcherBase._compile_for_args = timed
caching.IndexDataCacheFile._load_data = sized
from semslam.cli.main import main
with contextlib.redirect_stdout(io.StringIO()):
    rc = main(sys.argv[1:])
print(json.dumps({"rc": rc, "loads": loads}))
"""


def _kernel_loads(run: Path, sid: int, env: dict, top: int = 10) -> None:
    """What a cold ``semslam recognize`` spends in numba: each kernel's first call (its machine code loaded
    from numba's on-disk cache; the first call also sets numba up: the floor's kernel pays that too) in one fresh
    process, with the size of the cache file it read. The load time follows the size: numba's own code that a
    kernel uses (``np.linalg.solve``, sorting, the shape-error messages of array expressions) is compiled into
    it. The descriptors' kernels load in two threads at once: their times overlap."""
    scan = run / "mission" / "scans" / f"scan_{sid:05d}.pcd"
    cmd = [sys.executable, "-c", _KERNEL_LOADS, "recognize", str(scan), "--db", str(run / "db.npz"), "--json"]
    subprocess.run(cmd, check=True, capture_output=True, env=env)  # the cache filled
    load0 = _load()
    loads = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True, env=env).stdout)["loads"]
    print(f"\n## Numba kernels of one cold `semslam recognize` (scan {sid}, the run's db.npz; {load0})\n")
    print("| kernel | first call ms | cache file read kB |\n|---|---:|---:|")
    for ms, module, name, size in sorted(loads, key=lambda r: -r[0])[:top]:
        print(f"| `{module.removeprefix('semslam.')}.{name}` | {ms:.1f} | {size / 1e3:.0f} |")
    print(f"| all {len(loads)} kernels | {sum(r[0] for r in loads):.0f} | {sum(r[3] for r in loads) / 1e3:.0f} |")


def _child_env(no_bytecode: bool) -> dict:
    """The cold runs' environment: the parent's, with Python's bytecode cache on unless ``no_bytecode``."""
    env = dict(os.environ)
    if not no_bytecode:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def _children_cpu_s() -> float:
    """CPU seconds (user + sys) of this process's finished children."""
    import resource

    u = resource.getrusage(resource.RUSAGE_CHILDREN)
    return u.ru_utime + u.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", default="runs/demo", help="a demo output directory (mission/ and db.npz)")
    ap.add_argument("--only", choices=("warm", "cold"))
    ap.add_argument("--repeat", type=int, default=1, help="passes over the mission (warm)")
    ap.add_argument("--warm-up", choices=("full", "models"), default="full",
                    help="ScanRecognizer.warm_up (full) or only the pose models prepared (models: as before issue #18)")
    ap.add_argument("--cold-scans", type=int, nargs="+", default=[10])
    ap.add_argument("--cold-repeat", type=int, default=3)
    ap.add_argument("--cold-cache", choices=("warm", "empty"), default="warm",
                    help="the on-disk cache of the cold runs: filled by a first run, or empty for every run")
    ap.add_argument("--cold-db", nargs="+", default=["demo", "user"], metavar="DB",
                    help="the cold tables' databases: demo (the run's db.npz, 8 Kinect views per class), user (built "
                         "as a user of the laser vehicle does: `semslam db build --builtin --sensor laser`) or files")
    ap.add_argument("--no-bytecode", action="store_true",
                    help="keep the parent's PYTHONDONTWRITEBYTECODE in the cold runs (default: bytecode cache on)")
    args = ap.parse_args()
    run = Path(args.run)
    if not ((run / "db.npz").is_file() and (run / "mission").is_dir()):
        ap.error(f"--run {run} holds no demo run (mission/ and db.npz): run `make demo` first, or "
                 f"`semslam demo --quick --out {run}`")
    if args.only in (None, "warm"):
        warm(args)
    if args.only in (None, "cold"):
        cold(args)


if __name__ == "__main__":
    main()
