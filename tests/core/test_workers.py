"""Worker processes die with their parent (issue 18: loky workers outlived a kill -9 of semslam by minutes)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from semslam._workers import parallel_map


def _square(x):
    return x * x


def test_parallel_map_keeps_order_and_runs_serially_with_one_job():
    assert list(parallel_map(_square, range(7), 2)) == [x * x for x in range(7)]
    assert list(parallel_map(_square, range(3), 1)) == [0, 1, 4]
    assert list(parallel_map(_square, [], 2)) == []


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split()[2] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_workers_die_when_the_parent_is_killed(tmp_path):
    """The parent runs a slow parallel map, its workers write their pids, the parent gets SIGKILL: every worker
    must be gone within seconds. Without the death signal they idle on (loky's default timeout is minutes)."""
    pids = tmp_path / "pids"
    pids.mkdir()
    script = textwrap.dedent(f"""
        import os, time
        from semslam._workers import parallel_map

        def slow(i):
            open(os.path.join({str(pids)!r}, str(os.getpid())), "w").close()
            time.sleep(60)
            return i

        if __name__ == "__main__":
            for _ in parallel_map(slow, range(4), 2):
                pass
    """)
    (tmp_path / "parent.py").write_text(script)
    proc = subprocess.Popen([sys.executable, str(tmp_path / "parent.py")], cwd=tmp_path)
    try:
        deadline = time.monotonic() + 60
        while len(os.listdir(pids)) < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        workers = [int(p) for p in os.listdir(pids)]
        assert len(workers) == 2, "the workers never started"
        assert all(_alive(p) for p in workers)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    deadline = time.monotonic() + 10
    while any(_alive(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    survivors = [p for p in workers if _alive(p)]
    for p in survivors:
        os.kill(p, signal.SIGKILL)
    assert not survivors, f"workers {survivors} outlived their parent"
