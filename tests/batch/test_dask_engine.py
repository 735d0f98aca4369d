"""The Dask engine (semslam.batch.engine): ordered results, errors, a killed worker's task re-run, and the
engine-independence of Monte Carlo and database building (byte-identical outputs serially and on a local cluster
of 2 worker processes with 1 thread each)."""

from __future__ import annotations

import filecmp
import os
import signal
import threading
import time
import zipfile
from pathlib import Path

import psutil
import pytest

from semslam.errors import InputError, SlamError
from semslam.batch.engine import TaskFailed, check_jobs, map_tasks

DATA = Path(__file__).parents[1] / "data"


def test_serial_and_cluster_give_ordered_results(client):
    items = [0.3, 0.0, 0.1, 0.2]  # the first finishes last
    serial = map_tasks(abs, [-x for x in items])
    assert serial == items
    assert map_tasks(abs, [-x for x in items], client=client) == items
    seen = []
    map_tasks(time.sleep, items, client=client, on_result=lambda i, r: seen.append(i), progress=lambda d, t: None)
    assert sorted(seen) == [0, 1, 2, 3]


def test_task_error_raised_or_captured(client):
    with pytest.raises(TypeError):
        map_tasks(abs, [1, "x"], client=client, retries=0)
    out = map_tasks(abs, [-1, "x", -2], client=client, retries=0, capture_errors=True)
    assert out[0] == 1 and out[2] == 2
    assert isinstance(out[1], TaskFailed) and out[1].type == "TypeError"
    out = map_tasks(abs, [-1, "x"], capture_errors=True)  # serial: same contract
    assert out[0] == 1 and isinstance(out[1], TaskFailed)


def test_bad_jobs_and_scheduler_are_one_line_errors(monkeypatch):
    import semslam.batch.engine as engine

    monkeypatch.setattr(engine, "CONNECT_TIMEOUT", "1s")
    with pytest.raises(InputError, match="'--jobs'.*positive.*Got 0"):
        check_jobs(0)
    with pytest.raises(InputError, match="'--scheduler'.*tcp://127.0.0.1:1"):
        map_tasks(abs, [1], scheduler="tcp://127.0.0.1:1")


def test_worker_killed_mid_task_is_rerun(client):
    """SIGKILL the worker running a 2-second task, half-way: the scheduler re-runs it on another worker."""
    killed = []

    def killer():
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and not killed:
            busy = [w for w, keys in client.processing().items() if keys]
            if busy:
                time.sleep(0.7)  # well inside the task
                pid = client.run(os.getpid, workers=[busy[0]])[busy[0]]
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
            time.sleep(0.05)

    t = threading.Thread(target=killer)
    t.start()
    t0 = time.monotonic()
    out = map_tasks(time.sleep, [2.0], client=client)
    t.join()
    assert killed, "no worker was killed"
    assert out == [None]
    assert time.monotonic() - t0 > 2.5  # it ran again after the kill
    assert not psutil.pid_exists(killed[0]) or psutil.Process(killed[0]).status() == psutil.STATUS_ZOMBIE
    client.wait_for_workers(2, timeout=60)  # the nanny restarted it


def _same_files(a: Path, b: Path) -> list:
    """Files that differ between two outputs; the ownership marker (a random id per output) is not compared."""
    from semslam._outdir import MARKER

    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    return [n for n in names if n != MARKER and not filecmp.cmp(a / n, b / n, shallow=False)]


def test_montecarlo_byte_identical_serial_and_cluster(client, tmp_path):
    from semslam.experiments.montecarlo import run_montecarlo, write_montecarlo

    kw = dict(modes=("dr", "pose"), seed=11, source="synthetic", loops=1)
    serial = run_montecarlo(2, **kw)
    steps = []
    dist = run_montecarlo(2, client=client, progress=lambda d, t: steps.append((d, t)), **kw)
    assert steps[-1] == (4, 4)
    write_montecarlo(serial, tmp_path / "serial")
    write_montecarlo(dist, tmp_path / "dask")
    assert _same_files(tmp_path / "serial", tmp_path / "dask") == []
    ates = [m["ate_rmse_m"] for m in serial.run_metrics["pose"]]
    assert len(set(ates)) == 2 and min(ates) > 0  # run i has its own seed: the comparison is not vacuous


def test_montecarlo_task_error_reaches_the_caller(client):
    from semslam.experiments.montecarlo import run_montecarlo

    with pytest.raises(SlamError, match="source"):
        run_montecarlo(2, modes=("dr",), source="nowhere", client=client)


def test_models_database_byte_identical_serial_and_cluster(client, tmp_path):
    from functools import partial

    from semslam.recognition import save_database
    from semslam.simulation.cad_models import build_models_database

    kw = dict(n_views=3, n_model_views=1, esf_n_samples=2000, seed=4)
    serial = save_database(build_models_database(DATA / "models", **kw), tmp_path / "serial.npz")
    mapper = partial(_client_mapper, client=client)
    dist = save_database(build_models_database(DATA / "models", mapper=mapper, **kw), tmp_path / "dask.npz")
    with zipfile.ZipFile(serial) as a, zipfile.ZipFile(dist) as b:  # member bytes (zip timestamps excluded)
        assert a.namelist() == b.namelist()
        assert all(a.read(n) == b.read(n) for n in a.namelist())


def _client_mapper(fn, items, progress, *, client):
    return map_tasks(fn, items, client=client, progress=progress)


def test_cli_montecarlo_and_db_build_on_a_scheduler(client, tmp_path, capsys):
    """``--scheduler ADDRESS`` (here the test cluster's) gives the files of the serial run; bad ``--jobs`` is a
    one-line error."""
    from semslam.cli.main import main

    addr = client.scheduler.address
    mc = ["montecarlo", "--runs", "2", "--mode", "dr", "--source", "synthetic", "--loops", "1", "--seed", "5", "--json"]
    assert main([*mc, "--out", str(tmp_path / "serial")]) == 0
    assert main([*mc, "--out", str(tmp_path / "dask"), "--scheduler", addr]) == 0
    assert _same_files(tmp_path / "serial", tmp_path / "dask") == []
    db = ["db", "build", "--models", str(DATA / "models"), "--n-views", "2", "--model-views", "1", "--esf-samples",
          "1000", "--json"]
    assert main([*db, "--out", str(tmp_path / "serial.npz")]) == 0
    assert main([*db, "--out", str(tmp_path / "dask.npz"), "--scheduler", addr]) == 0
    with zipfile.ZipFile(tmp_path / "serial.npz") as a, zipfile.ZipFile(tmp_path / "dask.npz") as b:
        assert all(a.read(n) == b.read(n) for n in a.namelist())
    capsys.readouterr()
    assert main([*mc, "--jobs", "0"]) == 1
    assert main([*db, "--out", str(tmp_path / "x.npz"), "--jobs", "-1"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and all("'--jobs' option must be a positive" in e for e in err)


def test_local_cluster_is_sized_and_closed_with_its_workers():
    """``dask_client()`` without a scheduler: worker processes with 1 thread each, all gone on exit."""
    from semslam.batch.engine import dask_client

    with dask_client(workers=2) as c:
        assert sorted(c.nthreads().values()) == [1, 1]
        pids = list(c.run(os.getpid).values())
        assert len(set(pids)) == 2 and os.getpid() not in pids
        assert map_tasks(abs, [-1, -2, -3], client=c) == [1, 2, 3]
    _, alive = psutil.wait_procs([psutil.Process(p) for p in pids if psutil.pid_exists(p)], timeout=10)
    assert not alive
