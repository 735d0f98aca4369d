"""``semslam batch`` / :func:`semslam.batch.dives.run_batch`: one run directory per dive, the summary and
index, byte-identical outputs serially and on a local cluster (2 worker processes, 1 thread each), a corrupt dive
failing alone, a worker killed mid-dive, reruns skipping complete dives. Tiny missions (1 loop, 4 coarse scans)
and a 1-class database keep it fast."""

from __future__ import annotations

import filecmp
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import pytest

from semslam._outdir import MARKER, is_owned
from semslam.cli.cmd_batch import process_dive
from semslam.batch.dives import INDEX, SUMMARY_CSV, SUMMARY_MD, TIMINGS, run_batch

DATA = Path(__file__).parents[1] / "data"
OPTIONS = {"modes": ["dr", "pose"], "seed": 3, "no_report": True}


@pytest.fixture(scope="module")
def dives(tmp_path_factory):
    """Two simulated missions, a corrupt one, and a small database."""
    from semslam.recognition import save_database
    from semslam.simulation import SimulatorConfig, simulate_dataset
    from semslam.dataset import write_dataset
    from semslam.simulation.cad_models import build_models_database

    root = tmp_path_factory.mktemp("dives")
    out = []
    for seed in (1, 2):
        m = simulate_dataset(SimulatorConfig.quick(), seed=seed, scan_interval_s=3.0)
        out.append(write_dataset(m, root / f"dive{seed}"))
    bad = root / "corrupt"
    bad.mkdir()
    (bad / "mission.json").write_text("{ not json", encoding="utf-8")
    models = root / "models"
    models.mkdir()
    shutil.copy(DATA / "models" / "elbow.stl", models)
    (models / "models.toml").write_text('[elbow]\nfile = "elbow.stl"\nunit = "mm"\nsymmetry = "none"\n')
    db = save_database(build_models_database(models, n_views=2, n_model_views=1, esf_n_samples=2000), root / "db.npz")
    return [str(out[0]), str(bad), str(out[1])], str(db)


@pytest.fixture(scope="module")
def serial_runs(dives, tmp_path_factory):
    paths, db = dives
    out = tmp_path_factory.mktemp("serial") / "runs"
    done = []
    res = run_batch(paths, out, process_dive, options={**OPTIONS, "db": db}, jobs=1,
                    progress=lambda d, t: done.append((d, t)))
    assert done[-1] == (3, 3)
    return res


def _tree(root: Path) -> dict:
    """Every file but the ownership markers (each holds an id drawn for its directory: semslam._outdir)."""
    return {p.relative_to(root): p for p in sorted(root.rglob("*")) if p.is_file() and p.name != MARKER}


def _differing(a: Path, b: Path, exclude=(TIMINGS,)) -> list:
    ta, tb = _tree(a), _tree(b)
    assert sorted(ta) == sorted(tb)
    return [str(k) for k in ta if str(k) not in exclude and not filecmp.cmp(ta[k], tb[k], shallow=False)]


def test_corrupt_dive_fails_alone(serial_runs, dives):
    res = serial_runs
    assert [r["dive"] for r in res.rows] == ["dive1", "corrupt", "dive2"]
    assert [r["status"] for r in res.rows] == ["ok", "failed", "ok"]
    assert res.n_failed == 1
    assert "mission.json" in res.rows[1]["error"] and "DatasetError" in res.rows[1]["error"]
    for r in (res.rows[0], res.rows[2]):
        assert is_owned(res.out / r["dive"], "run")
        assert r["duration_s"] > 10 and r["modes"]["pose"]["ate_m"] > 0 and r["detections"] >= 0
    assert not (res.out / "corrupt").exists()
    csv = (res.out / SUMMARY_CSV).read_text().splitlines()
    assert csv[0] == "dive,status,duration_s,detections,landmarks_dr,ate_dr_m,landmarks_pose,ate_pose_m,error"
    assert csv[2].startswith("corrupt,failed,") and "mission.json" in csv[2]
    assert "| dive1 | ok |" in (res.out / SUMMARY_MD).read_text()
    assert "<td>corrupt</td><td>failed</td>" in (res.out / INDEX).read_text()
    assert [t[0] for t in res.timings] == ["processed", "failed", "processed"]


def test_cluster_outputs_byte_identical_to_serial(serial_runs, dives, client, tmp_path):
    paths, db = dives
    seen = []
    res = run_batch(paths, tmp_path / "runs", process_dive, options={**OPTIONS, "db": db}, client=client,
                    on_dive=lambda i, row: seen.append(i))
    assert sorted(seen) == [0, 1, 2]
    assert [r["status"] for r in res.rows] == ["ok", "failed", "ok"]
    # every file, run directories and tables alike; timings.csv (wall times) is the one file excluded
    assert _differing(serial_runs.out, res.out) == []
    assert len(_tree(res.out)) > 20


def test_rerun_skips_complete_dives_and_redoes_half_written_ones(serial_runs, dives, tmp_path):
    paths, db = dives
    out = tmp_path / "runs"
    shutil.copytree(serial_runs.out, out)
    # dive2 was interrupted half-way: only its staged sibling exists, never a marked run directory
    shutil.rmtree(out / "dive2")
    (out / ".dive2.semslam-1-interrupted.tmp").mkdir()
    (out / ".dive2.semslam-1-interrupted.tmp" / "detections.jsonl").write_text("half")
    before = (out / "dive1" / "slam" / "pose" / "metrics.json").stat().st_mtime_ns
    res = run_batch(paths, out, process_dive, options={**OPTIONS, "db": db}, jobs=1)
    assert [t[0] for t in res.timings] == ["skipped", "failed", "processed"]
    assert (out / "dive1" / "slam" / "pose" / "metrics.json").stat().st_mtime_ns == before
    # another process's staging folder is not this one's to remove (semslam._outdir): the user removes it
    assert (out / ".dive2.semslam-1-interrupted.tmp" / "detections.jsonl").read_text() == "half"
    shutil.rmtree(out / ".dive2.semslam-1-interrupted.tmp")
    assert _differing(serial_runs.out, out) == []  # the same tables whether a dive was kept or redone
    res = run_batch(paths[:1], out, process_dive, options={**OPTIONS, "db": db}, overwrite=True)
    assert [t[0] for t in res.timings] == ["processed"]
    assert (out / "dive1" / "slam" / "pose" / "metrics.json").stat().st_mtime_ns != before


def test_worker_killed_mid_dive_is_retried_and_batch_completes(serial_runs, dives, client, tmp_path):
    paths, db = dives
    killed, staged = [], []
    runs = tmp_path / "runs"

    def killer():  # SIGKILL a worker running a dive once the dives' staged run directories exist: mid-dive
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not killed:
            busy = [w for w, keys in client.processing().items() if keys]
            half = list(runs.glob(".dive*.tmp")) if runs.is_dir() else []
            if busy and half:
                staged.extend(half)
                pid = client.run(os.getpid, workers=[busy[0]])[busy[0]]
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
            time.sleep(0.02)

    t = threading.Thread(target=killer)
    t.start()
    res = run_batch([paths[0], paths[2]], runs, process_dive, options={**OPTIONS, "db": db}, client=client)
    t.join()
    assert killed and staged, "no worker was killed mid-dive"
    assert [r["status"] for r in res.rows] == ["ok", "ok"]
    assert all(is_owned(runs / n, "run") for n in ("dive1", "dive2"))
    # only the killed worker's staging can be left (no other process removes it); the re-run's own is gone
    assert all(f".semslam-{killed[0]}-" in p.name for p in runs.glob(".*.tmp")), list(runs.glob(".*.tmp"))
    for n in ("dive1", "dive2"):  # the re-run dive's files are those of the serial batch
        assert _differing(serial_runs.out / n, runs / n) == []
    client.wait_for_workers(2, timeout=120)


def test_cli_batch_exit_status_and_errors(serial_runs, dives, tmp_path, capsys):
    from semslam.cli.main import main

    paths, db = dives
    out = tmp_path / "runs"
    shutil.copytree(serial_runs.out, out)  # complete: the CLI skips them (fast), and still reports the corrupt one
    assert main(["batch", *paths, "--db", db, "--out", str(out), "--workers", "1", "--mode", "pose"]) == 1
    err = capsys.readouterr().err
    assert "[3/3]" in err and "semslam: error: 1 of 3 dives failed" in err
    assert main(["batch", paths[0], "--db", db, "--out", str(out), "--workers", "1", "--json"]) == 0
    assert main(["batch", paths[0], "--db", db, "--out", str(out), "--workers", "0"]) == 1
    assert "'--workers' option must be a positive" in capsys.readouterr().err
    assert main(["batch", str(tmp_path / "nope"), "--db", db, "--out", str(out)]) == 1
    assert "does not exist" in capsys.readouterr().err
    assert main(["batch", paths[0], paths[0], "--db", db, "--out", str(out), "--workers", "1"]) == 1
    assert "share the run directory" in capsys.readouterr().err


def test_bag_dive_without_ground_truth(dives, tmp_path):
    """A ROS 1 bag as a vehicle records it: streamed (nothing converted on disk), no ATE in the summary."""
    from semslam.dataset import write_vehicle_toml
    from semslam.dataset.rosbag_write import SEMSLAM_TOPICS, write_bag
    from semslam.simulation import SimulatorConfig, simulate_dataset

    _, db = dives
    m = simulate_dataset(SimulatorConfig.quick(), seed=5, scan_interval_s=3.0)
    bag = write_bag(m, tmp_path / "dive5.bag", "ros1")
    write_vehicle_toml(m.vehicle, tmp_path / "vehicle.toml")
    (tmp_path / "topics.toml").write_text(SEMSLAM_TOPICS.to_toml())
    opts = {**OPTIONS, "db": db, "modes": ["pose"], "vehicle": str(tmp_path / "vehicle.toml"),
            "topics": str(tmp_path / "topics.toml")}
    res = run_batch([bag], tmp_path / "runs", process_dive, options=opts)
    (row,) = res.rows
    assert row["dive"] == "dive5" and row["status"] == "ok", row
    assert row["modes"]["pose"]["ate_m"] is None and row["duration_s"] > 10
    assert not (tmp_path / "runs" / "dive5" / "mission").exists()
    assert (tmp_path / "runs" / "dive5" / "run.json").is_file()
    assert (tmp_path / "runs" / SUMMARY_CSV).read_text().splitlines()[1].startswith("dive5,ok,")
