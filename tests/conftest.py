"""Shared fixtures: where the shared data and the PCL oracle are, skipping cleanly when absent.

No silent skips: the run ends with one line saying how many tests were skipped and why, and a run that must
have the data fails instead of skipping: ``SEMSLAM_REQUIRE_SHARED=1`` (``../shared`` and the data in it; CI sets
it, since CI always has ``../shared`` beside the clone) and ``SEMSLAM_REQUIRE_PCL=1`` (the ``pcl_ref`` oracle).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from tests._support.shared import SHARED, TEST_DATA, require_shared
from tests._support.shared import missing as _missing


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """One closing line: how many tests were skipped, grouped by reason."""
    skipped = terminalreporter.stats.get("skipped", [])
    if not skipped:
        terminalreporter.write_line("semslam: no test skipped")
        return
    reasons: dict[str, int] = {}
    for rep in skipped:
        longrepr = rep.longrepr
        reason = longrepr[2] if isinstance(longrepr, tuple) and len(longrepr) == 3 else str(longrepr)
        reason = reason.removeprefix("Skipped: ")
        reasons[reason] = reasons.get(reason, 0) + 1
    text = "; ".join(f"{n} x {r}" for r, n in sorted(reasons.items(), key=lambda kv: -kv[1]))
    terminalreporter.write_line(f"semslam: {len(skipped)} test(s) skipped: {text}")


@pytest.fixture(scope="session")
def test_data() -> Path:
    """``tests/data``: small fixtures that always ship with the repository."""
    return TEST_DATA


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """``../shared`` beside the clone; tests that need it skip when it is absent."""
    return require_shared(SHARED, "shared data folder (set SEMSLAM_SHARED)")


@pytest.fixture(scope="session")
def real_data(shared_dir: Path) -> Path:
    """``../shared/data/real``: PCL's real test scans."""
    path = shared_dir / "data" / "real"
    return require_shared(path, "real scans")


@pytest.fixture(scope="session")
def pcl_ref() -> str:
    """Path of the ``pcl_ref`` oracle binary (``../shared/pcl_oracle/build.sh``); skip when not built."""
    candidates = [os.environ.get("PCL_REF", ""), str(Path.home() / ".cache/pcl_oracle/pcl_ref"),
                  shutil.which("pcl_ref") or ""]
    for c in candidates:
        if c and os.access(c, os.X_OK):
            return c
    _missing("pcl_ref oracle not built (run ../shared/pcl_oracle/build.sh)", "SEMSLAM_REQUIRE_PCL")


@pytest.fixture(scope="module")
def client():
    """A Dask LocalCluster of 2 worker processes with 1 thread each (the engine tests); after the module, every
    worker process must be gone."""
    import psutil
    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    c = Client(cluster)
    pids = set(c.run(os.getpid).values())
    try:
        yield c
    finally:
        pids |= set(c.run(os.getpid).values())
        c.close()
        cluster.close()
        _, alive = psutil.wait_procs([psutil.Process(p) for p in pids if psutil.pid_exists(p)], timeout=10)
        assert not alive, f"worker processes survived the cluster: {alive}"


@pytest.fixture(scope="module")
def builtin_db_fresh(tmp_path_factory):
    """The built-in database built afresh (seed 0) in a private cache, not the user's ~/.cache copy."""
    from semslam.simulation.builtin_db import builtin_database

    os.environ["SEMSLAM_CACHE_DIR"] = str(tmp_path_factory.mktemp("cache"))
    try:
        return builtin_database(seed=0)
    finally:
        del os.environ["SEMSLAM_CACHE_DIR"]
