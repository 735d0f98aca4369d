"""The venv reaches Debian's rospy through a directory of links to the ROS modules only: numpy, yaml... stay the
venv's."""

from __future__ import annotations

import subprocess
import sys

from tests._support.ros1 import require_ros


def test_the_bridge_links_ros_modules_but_never_the_venvs_own(tmp_path):
    require_ros()
    from semslam.run.ros1.bridge import DIST_PACKAGES, bridge_modules, install_bridge

    mods = bridge_modules()
    assert {"rospy", "genpy", "rosgraph", "std_msgs", "nav_msgs", "visualization_msgs"} <= set(mods)
    assert not {"numpy", "yaml", "scipy"} & set(mods)  # the venv has them: never linked
    out = install_bridge(tmp_path, write_pth=False)
    assert sorted(p.name for p in out.iterdir()) == sorted(mods)
    assert all(p.is_symlink() and p.resolve().parent == DIST_PACKAGES.resolve() for p in out.iterdir())
    code = ("import sys; sys.path.append(sys.argv[1]); import rospy, numpy, yaml, nav_msgs.msg; "
            "print(rospy.__file__); print(numpy.__file__); print(yaml.__file__)")
    res = subprocess.run([sys.executable, "-c", code, str(out)], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    rospy_file, numpy_file, yaml_file = res.stdout.split()
    assert rospy_file.startswith((str(out), sys.prefix))  # this bridge, or the venv's own (its .pth)
    assert numpy_file.startswith(sys.prefix) and yaml_file.startswith(sys.prefix)
