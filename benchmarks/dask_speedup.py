"""Speed-up of the Dask engine (issue 19): a Monte Carlo of ``--missions`` missions and a batch of ``--dives`` dives,
serially in this process and on a local cluster of 1 and 2 worker processes (1 thread each), and the per-task
overhead of the engine (``--empty`` empty tasks).

    .venv/bin/python benchmarks/dask_speedup.py --missions 30 --dives 20 --work /tmp/dask_bench

The serial rows are measured after a warm-up in this process; each cluster's wall time includes its workers' cold
start (importing semslam, loading the numba cache), which is what a user pays. The cluster start itself
(scheduler + workers up) is reported apart. The outputs of every engine are compared byte by byte (the batch's
timings.csv excepted).
"""

from __future__ import annotations

import argparse
import filecmp
import json
import shutil
import sys
import time
from pathlib import Path


def _noop(x):
    return x


def _cpu_s() -> float:
    """CPU seconds (user + system) of this worker process and its threads."""
    import psutil

    t = psutil.Process().cpu_times()
    return t.user + t.system


def _same(a: Path, b: Path) -> bool:
    fa = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file() and p.name != "timings.csv")
    fb = sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file() and p.name != "timings.csv")
    return fa == fb and all(filecmp.cmp(a / f, b / f, shallow=False) for f in fa)


def _engines(workers):
    """(name, client factory or None for serial)."""
    yield "serial (in process)", None
    for n in workers:
        yield f"local cluster, {n} worker{'s' if n > 1 else ''}", n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--missions", type=int, default=30)
    ap.add_argument("--loops", type=int, default=1, help="loops per Monte-Carlo mission (default 1)")
    ap.add_argument("--dives", type=int, default=20)
    ap.add_argument("--empty", type=int, default=2000, help="empty tasks for the overhead (default 2000)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--work", default="/tmp/semslam_dask_bench")
    ap.add_argument("--skip", nargs="*", default=[], choices=("montecarlo", "batch", "overhead"))
    args = ap.parse_args()

    from distributed import Client, LocalCluster

    from semslam.cli.cmd_batch import process_dive
    from semslam.batch.dives import run_batch
    from semslam.experiments.montecarlo import run_montecarlo, write_montecarlo

    work = Path(args.work)
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    results: dict = {"args": vars(args), "rows": []}

    dives = []
    if "batch" not in args.skip:
        from semslam.simulation import SimulatorConfig, simulate_dataset
        from semslam.dataset import write_dataset
        from semslam.simulation.builtin_db import builtin_database

        builtin_database(seed=0)  # the disk cache, once, outside the timings
        t = time.perf_counter()
        for i in range(args.dives):
            m = simulate_dataset(SimulatorConfig.quick(), seed=i, scan_interval_s=1.0)
            dives.append(str(write_dataset(m, work / "dives" / f"dive{i:03d}")))
        print(f"simulated {len(dives)} dives ({m.duration_s:.0f} s, {len(m.scans)} scans each) in "
              f"{time.perf_counter() - t:.1f} s", file=sys.stderr)

    def cpu(client) -> float:
        """CPU seconds used so far by the workers (or by this process, serial)."""
        if client is None:
            return time.process_time()
        return sum(client.run(_cpu_s).values())

    def measure(name, n, client):
        if "montecarlo" not in args.skip:
            t, c = time.perf_counter(), cpu(client)
            res = run_montecarlo(args.missions, modes=("dr", "position", "pose"), seed=0, loops=args.loops,
                                 **({"client": client} if client else {}))
            wall, cpu_s = time.perf_counter() - t, cpu(client) - c
            out = write_montecarlo(res, work / "mc" / str(n or 0))
            results["rows"].append({"workload": f"Monte Carlo, {args.missions} missions", "engine": name,
                                    "wall_s": wall, "cpu_s": cpu_s, "same_as_serial": _same(work / "mc" / "0", out)})
            print(results["rows"][-1], file=sys.stderr)
        if dives:
            t, c = time.perf_counter(), cpu(client)
            res = run_batch(dives, work / "runs" / str(n or 0), process_dive,
                            options={"db": "builtin", "modes": ["dr", "pose"], "no_report": True},
                            **({"client": client} if client else {}))
            wall, cpu_s = time.perf_counter() - t, cpu(client) - c
            assert res.n_failed == 0, res.rows
            results["rows"].append({"workload": f"batch, {len(dives)} dives", "engine": name, "wall_s": wall,
                                    "cpu_s": cpu_s,
                                    "same_as_serial": _same(work / "runs" / "0", res.out)})
            print(results["rows"][-1], file=sys.stderr)

    for name, n in _engines(args.workers):
        if n is None:  # warm this process first (imports, numba cache): the serial rows are the steady state
            run_montecarlo(1, modes=("dr",), loops=1)
            if dives:
                run_batch(dives[:1], work / "warm", process_dive, options={"db": "builtin", "modes": ["dr"],
                                                                           "no_report": True})
            measure(name, None, None)
            continue
        t = time.perf_counter()
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                          silence_logs=40) as cluster, Client(cluster) as client:
            client.wait_for_workers(n)
            results.setdefault("cluster_start_s", {})[n] = time.perf_counter() - t
            measure(name, n, client)
            if "overhead" not in args.skip:
                client.gather(client.map(_noop, range(50), pure=False))  # warm
                t = time.perf_counter()
                client.gather(client.map(_noop, range(args.empty), pure=False))
                wall = time.perf_counter() - t
                results["rows"].append({"workload": f"{args.empty} empty tasks", "engine": name, "wall_s": wall,
                                        "per_task_ms": 1e3 * wall / args.empty})
                t = time.perf_counter()
                for i in range(200):
                    client.submit(_noop, i, pure=False).result()
                results["rows"].append({"workload": "200 empty tasks, one at a time (round trip)", "engine": name,
                                        "wall_s": time.perf_counter() - t,
                                        "per_task_ms": 1e3 * (time.perf_counter() - t) / 200})
                print(results["rows"][-2:], file=sys.stderr)

    base = {r["workload"]: r["wall_s"] for r in results["rows"] if r["engine"].startswith("serial")}
    lines = ["| workload | engine | wall (s) | speed-up vs serial | CPU (s) | cores used (CPU / wall) | "
             "per task (ms) | outputs = serial |", "|---|---|---:|---:|---:|---:|---:|---|"]
    for r in results["rows"]:
        sp = base.get(r["workload"])
        speed = "" if sp is None else f"{sp / r['wall_s']:.2f}"
        per = f"{r['per_task_ms']:.2f}" if "per_task_ms" in r else ""
        same = "" if "same_as_serial" not in r else ("yes" if r["same_as_serial"] else "NO")
        cpu_s = f"{r['cpu_s']:.1f} | {r['cpu_s'] / r['wall_s']:.2f}" if "cpu_s" in r else " | "
        lines.append(f"| {r['workload']} | {r['engine']} | {r['wall_s']:.2f} | {speed} | {cpu_s} | {per} | {same} |")
    lines.append("")
    starts = results.get("cluster_start_s", {}).items()
    lines.append("cluster start (s): " + ", ".join(f"{n} workers {s:.1f}" for n, s in starts))
    (work / "results.json").write_text(json.dumps(results, indent=2))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
