"""ROS 1 test helpers: is ROS here (skip, or fail under SEMSLAM_REQUIRE_ROS=1), a roscore on a free port, processes
started in their own process group and stopped by PID, and a bag's raw ROS 1 messages (what a subscriber gets)."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Iterator

import pytest


def _missing(what: str) -> None:
    """Skip naming ``what``, unless SEMSLAM_REQUIRE_ROS says this run must have ROS: then fail."""
    if os.environ.get("SEMSLAM_REQUIRE_ROS", "") not in ("", "0"):
        pytest.fail(f"{what} (required by SEMSLAM_REQUIRE_ROS=1)")
    pytest.skip(what)


def require_ros() -> None:
    """rospy importable (through the venv's bridge) and roscore / rosbag on PATH, else skip (or fail)."""
    from semslam.errors import SemslamError
    from semslam.run.ros1.bridge import APT_LINE, ensure_rospy

    try:
        ensure_rospy()
    except SemslamError as err:
        _missing(f"ROS 1 not installed ({err})")
    for exe in ("roscore", "rosbag"):
        if shutil.which(exe) is None:
            _missing(f"ROS 1 '{exe}' not on PATH (install with `{APT_LINE}`)")


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def ros_env(master_uri: str, ros_home: Path) -> dict:
    """The environment of a process of this test's ROS graph: its master, logs under ``ros_home``."""
    env = dict(os.environ, ROS_MASTER_URI=master_uri, ROS_HOME=str(ros_home), ROS_LOG_DIR=str(ros_home / "log"),
               ROS_IP="127.0.0.1", PYTHONUNBUFFERED="1")
    env.pop("ROS_HOSTNAME", None)
    return env


def stop(proc: subprocess.Popen, timeout: float = 10.0) -> None:
    """SIGINT to the process group led by ``proc.pid`` (it was started with ``start_new_session``), then
    SIGTERM, then SIGKILL; waits for it."""
    for sig, wait in ((signal.SIGINT, timeout), (signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
        if proc.poll() is not None:
            break
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, sig)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(wait)
    # the group's other members (roscore's rosmaster and rosout) go with it
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(5.0)


@contextlib.contextmanager
def started(cmd: list[str], env: dict, log: Path, stop_timeout_s: float = 10.0) -> Iterator[subprocess.Popen]:
    """``cmd`` in its own session (its PID is its process group), output to ``log``; stopped at the end (SIGINT,
    ``stop_timeout_s`` to finish cleanly, then SIGTERM and SIGKILL)."""
    with open(log, "wb") as out:
        proc = subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            yield proc
        finally:
            stop(proc, timeout=stop_timeout_s)


def master_online(master_uri: str) -> bool:
    import rosgraph

    return rosgraph.is_master_online(master_uri=master_uri)


@contextlib.contextmanager
def roscore(tmp_path: Path, timeout_s: float = 30.0) -> Iterator[dict]:
    """A roscore on a free port for this test: yields the environment of its graph; killed by PID at the end,
    nothing left (logs under ``tmp_path``)."""
    require_ros()
    port = free_port()
    uri = f"http://127.0.0.1:{port}"
    home = tmp_path / "ros_home"
    home.mkdir(exist_ok=True)
    env = ros_env(uri, home)
    with started(["roscore", "-p", str(port)], env, tmp_path / "roscore.log") as proc:
        deadline = time.monotonic() + timeout_s
        while not master_online(uri):
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"roscore on port {port} did not come up: "
                                   f"{(tmp_path / 'roscore.log').read_text(errors='replace')[-2000:]}")
            time.sleep(0.1)
        yield env


def raw_bag_messages(bag_path: Path, topics: list[str]) -> Iterator[tuple[str, str, str, str, bytes, int]]:
    """A ROS 1 bag's messages as a subscriber receives them: ``(topic, type 'pkg/Name', md5sum, message definition,
    serialized bytes, receive time ns)``, in bag order."""
    from rosbags.rosbag1 import Reader

    with Reader(bag_path) as reader:
        conns = [c for c in reader.connections if c.topic in topics]
        for conn, t_ns, raw in reader.messages(connections=conns):
            pkg, _, name = conn.msgtype.split("/")
            yield conn.topic, f"{pkg}/{name}", conn.digest, conn.msgdef.data, bytes(raw), int(t_ns)


def python() -> str:
    return sys.executable
