"""How a virtual environment reaches Debian's ROS 1 (``apt install python3-rospy ...``) without Debian's numpy.

Debian 12 ships rospy and the message packages as modules of its own Python 3.11 in
``/usr/lib/python3/dist-packages``. Putting that whole directory on ``sys.path`` would let Debian's numpy,
scipy, yaml... shadow or mix with the venv's. Instead the bridge is a directory of symlinks to only the ROS
packages' top-level modules and the pure-Python dependencies they pull in (found with ``dpkg-query`` from the
ROS packages' ``Depends``), leaving out every module the venv itself can already import (so numpy, yaml,
setuptools' pkg_resources... always come from the venv); a ``.pth`` file in the venv's site-packages appends
the directory to ``sys.path`` (after site-packages: the venv always wins).

``python -m semslam.run.ros1.bridge`` writes it (``make`` does, when ROS is installed);
:func:`ensure_rospy` builds it lazily when the node starts in an environment without it. Nothing here imports
rospy: that is the node's business (:mod:`semslam.run.ros1.node`).
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
import sysconfig
from pathlib import Path

from ...errors import SemslamError

__all__ = ["DIST_PACKAGES", "ROS_PACKAGES", "RosUnavailableError", "bridge_dir", "bridge_modules", "ensure_rospy",
           "install_bridge"]

DIST_PACKAGES = Path("/usr/lib/python3/dist-packages")
#: the Debian packages the node needs (their Python dependencies are followed with dpkg-query)
ROS_PACKAGES = ("python3-rospy", "python3-rosbag", "python3-sensor-msgs", "python3-nav-msgs",
                "python3-geometry-msgs", "python3-visualization-msgs", "python3-tf2-ros", "python3-diagnostic-msgs")
#: apt's one line for users (also what .ci/run installs)
APT_LINE = "sudo apt-get install ros-core " + " ".join(ROS_PACKAGES)
#: the modules to link when dpkg-query is unavailable (a Debian 12 install's closure, measured)
_FALLBACK = ("actionlib", "actionlib_msgs", "catkin", "catkin_pkg", "dateutil", "diagnostic_msgs", "distro",
             "docutils", "em.py", "genmsg", "genpy", "geometry_msgs", "gnupg.py", "nav_msgs", "Cryptodome",
             "pyparsing", "roman.py", "rosbag", "roscpp", "rosgraph", "rosgraph_msgs", "roslib", "roslz4", "rospkg",
             "rospy", "sensor_msgs", "six.py", "std_msgs", "tf2_py", "tf2_msgs", "tf2_ros", "visualization_msgs",
             "_yaml", "yaml")
PTH_NAME = "semslam-ros1.pth"


class RosUnavailableError(SemslamError):
    """ROS 1 (rospy, roscore) is not installed where semslam can reach it."""


def _dpkg_closure(roots=ROS_PACKAGES) -> list[str] | None:
    """Top-level entries of ``DIST_PACKAGES`` installed by ``roots`` and their python3-* dependencies
    (None when dpkg is unavailable or a root is not installed). One dpkg-query for the whole database, the file
    lists read from dpkg's own ``info/*.list``."""
    try:
        q = subprocess.run(["dpkg-query", "-W", "-f=${Package}\t${db:Status-Status}\t${Depends}\n"],
                           capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return None
    if q.returncode != 0:
        return None
    depends: dict[str, str] = {}
    for line in q.stdout.splitlines():
        parts = line.split("\t")
        if len(parts) == 3 and parts[1] == "installed":
            depends[parts[0]] = parts[2]
    if any(r not in depends for r in roots):
        return None
    seen: set[str] = set()
    stack = list(roots)
    tops: set[str] = set()
    pattern = re.compile(rf"^{re.escape(str(DIST_PACKAGES))}/([^/]+)$")
    while stack:
        pkg = stack.pop()
        if pkg in seen or pkg not in depends:
            continue
        seen.add(pkg)
        for alt in depends[pkg].split(","):
            name = alt.strip().split("|")[0].strip().split(" ")[0].split(":")[0] if alt.strip() else ""
            if name.startswith("python3-"):
                stack.append(name)
        for line in _package_files(pkg):
            m = pattern.match(line)
            if m and not m.group(1).endswith((".egg-info", ".dist-info", ".pth")):
                tops.add(m.group(1))
    return sorted(tops)


def _package_files(pkg: str) -> list[str]:
    info = Path("/var/lib/dpkg/info")
    for name in (f"{pkg}.list", *(p.name for p in info.glob(f"{pkg}:*.list"))):
        try:
            return (info / name).read_text(encoding="utf-8", errors="replace").splitlines()
        except OSError:
            continue
    try:
        return subprocess.run(["dpkg", "-L", pkg], capture_output=True, text=True, timeout=30).stdout.splitlines()
    except (OSError, subprocess.SubprocessError):
        return []


def _venv_has(entry: str) -> bool:
    """Whether the running interpreter (without the bridge) already imports the module ``entry`` names."""
    name = entry.removesuffix(".py").split(".")[0]
    try:
        spec = importlib.util.find_spec(name)
    except (ImportError, ValueError):
        return False
    if spec is None:
        return False
    origin = spec.origin or (list(spec.submodule_search_locations or [""])[0])
    return not str(origin).startswith((str(DIST_PACKAGES), str(bridge_dir())))


def bridge_modules() -> list[str]:
    """The entries of ``DIST_PACKAGES`` to link: the ROS closure minus what the venv has."""
    tops = _dpkg_closure()
    if tops is None:
        tops = [t for t in _FALLBACK if (DIST_PACKAGES / t).exists()
                or any(DIST_PACKAGES.glob(f"{t}.cpython-*.so"))]
    # a C extension module of Debian's CPython 3.11 (e.g. _yaml.cpython-311-x86_64-linux-gnu.so) comes with it
    return [t for t in tops if not _venv_has(t)]


def bridge_dir(prefix: str | os.PathLike | None = None) -> Path:
    """Where the links live: ``<venv>/ros1-bridge``."""
    return Path(sys.prefix if prefix is None else prefix) / "ros1-bridge"


def install_bridge(prefix: str | os.PathLike | None = None, *, write_pth: bool = True) -> Path:
    """(Re)create the bridge directory of symlinks and, with ``write_pth``, the ``.pth`` that appends it to
    ``sys.path`` of every start of this interpreter. Returns the directory. Raises
    :class:`RosUnavailableError` when Debian's rospy is not installed."""
    if not (DIST_PACKAGES / "rospy" / "__init__.py").is_file():
        raise RosUnavailableError(f"Debian's rospy was not found in {DIST_PACKAGES}: install ROS 1 with "
                                  f"`{APT_LINE}`.")
    if sys.version_info[:2] != (3, 11):
        raise RosUnavailableError(f"Debian 12's rospy is built for Python 3.11. Got Python "
                                  f"{sys.version_info[0]}.{sys.version_info[1]} instead.")
    out = bridge_dir(prefix)
    tmp = out.with_name(out.name + f".tmp{os.getpid()}")
    tmp.mkdir(parents=True, exist_ok=False)
    for entry in bridge_modules():
        (tmp / entry).symlink_to(DIST_PACKAGES / entry)
    if out.exists():
        for p in out.iterdir():
            p.unlink()
        out.rmdir()
    tmp.rename(out)
    if write_pth:
        site = Path(sysconfig.get_paths()["purelib"])
        (site / PTH_NAME).write_text(str(out) + "\n", encoding="utf-8")
    return out


def ensure_rospy() -> None:
    """Make ``import rospy`` work: nothing when it already does, else the bridge (built when missing, appended
    to ``sys.path`` for this process). Raises :class:`RosUnavailableError` with the apt line otherwise."""
    if importlib.util.find_spec("rospy") is not None:
        return
    out = bridge_dir()
    if not (out / "rospy").exists():
        try:
            out = install_bridge(write_pth=False)
        except OSError:  # a read-only environment: a per-user copy
            out = install_bridge(Path.home() / ".cache" / "semslam", write_pth=False)
    if str(out) not in sys.path:
        sys.path.append(str(out))
    importlib.invalidate_caches()
    if importlib.util.find_spec("rospy") is None:
        raise RosUnavailableError(f"rospy cannot be imported even through {out}: install ROS 1 with `{APT_LINE}`.")


def main(argv: list[str] | None = None) -> int:
    """``python -m semslam.run.ros1.bridge [--if-present]``: write the bridge and the .pth into this venv."""
    args = sys.argv[1:] if argv is None else argv
    if "--if-present" in args and not (DIST_PACKAGES / "rospy").exists():
        return 0
    try:
        out = install_bridge()
    except SemslamError as err:
        print(f"semslam: error: {err}", file=sys.stderr)
        return 1
    print(f"ROS 1 bridge: {out} ({len(list(out.iterdir()))} modules)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
