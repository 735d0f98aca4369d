"""``semslam info``: text and --json output against known file contents."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from semslam.cli.main import main
from semslam.cloud import PointCloud
from semslam.io import write_point_cloud

IO = Path(__file__).resolve().parents[1] / "data" / "io"


@pytest.mark.parametrize("where", ["before", "after"])
def test_info_json_on_organised_golden_file(capsys, where):
    path = str(IO / "src_fields.pcd")
    argv = ["--json", "info", path] if where == "before" else ["info", path, "--json"]
    assert main(argv) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["format"] == "pcd" and info["encoding"] == "binary"
    assert (info["points"], info["valid_points"], info["nan_points"]) == (12, 10, 2)
    assert (info["width"], info["height"], info["organized"]) == (4, 3, True)
    assert info["fields"][0] == {"name": "x", "size": 4, "type": "F", "count": 1}
    assert {"name": "hist", "size": 4, "type": "F", "count": 5} in info["fields"]
    assert {"name": "time", "size": 8, "type": "F", "count": 1} in info["fields"]
    assert info["viewpoint"] == {"xyz_m": [1.0, 2.0, 3.0], "quat_wxyz": [0.0, 1.0, 0.0, 0.0]}
    xyz = np.load(IO / "expected.npz")
    pts = np.stack([xyz[f"fields/{c}"] for c in "xyz"], 1).astype(np.float64)
    np.testing.assert_array_equal(info["bounds"]["min_xyz_m"], np.nanmin(pts, axis=0))
    np.testing.assert_array_equal(info["bounds"]["max_xyz_m"], np.nanmax(pts, axis=0))


def test_info_text_and_padding(capsys):
    assert main(["info", str(IO / "pad_binary.pcd")]) == 0
    out = capsys.readouterr().out
    assert "3 (3 valid, 0 NaN)" in out
    assert "x F4, _ U1x2, y F4, z F4, _ F4" in out
    assert "binary" in out and "3 x 1" in out
    assert "x [0.25, 2.25] y [0, 4] z [-2, 0] m" in out


def test_info_signature_file_and_ply_npy(capsys, tmp_path):
    assert main(["--json", "info", str(IO / "pcl_vfh_binary_compressed.pcd")]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["fields"] == [{"name": "vfh", "size": 4, "type": "F", "count": 308}]
    assert info["bounds"] is None and info["encoding"] == "binary_compressed"
    cloud = PointCloud(np.array([[0.0, 1, 2], [3, 4, 5], [-1, 0, 9]]))
    write_point_cloud(tmp_path / "c.ply", cloud, encoding="binary_big_endian")
    write_point_cloud(tmp_path / "c.npy", cloud)
    for name, enc, size in (("c.ply", "binary_big_endian", 4), ("c.npy", "npy float64", 8)):
        assert main(["info", str(tmp_path / name), "--json"]) == 0
        info = json.loads(capsys.readouterr().out)
        assert info["encoding"] == enc and info["points"] == 3
        assert [f["name"] for f in info["fields"]] == ["x", "y", "z"] and info["fields"][0][
            "size"
        ] == size
        assert info["bounds"] == {"min_xyz_m": [-1.0, 0.0, 2.0], "max_xyz_m": [3.0, 4.0, 9.0]}


def test_info_errors_exit_1(capsys, tmp_path):
    """Catches a traceback or a multi-line message on a missing or truncated file (only the start of stderr
    was checked), or a message that does not name the file and what is wrong with it."""
    assert main(["info", str(tmp_path / "missing.pcd")]) == 1
    line = _one_line_error(capsys)
    assert "missing.pcd" in line and "no such file" in line
    (tmp_path / "t.pcd").write_bytes(b"VERSION 0.7\nFIELDS x\n")
    assert main(["info", str(tmp_path / "t.pcd")]) == 1
    line = _one_line_error(capsys)
    assert "t.pcd" in line and "no DATA line" in line


def _one_line_error(capsys) -> str:
    """The CLI's error contract: stderr is exactly one line, ``semslam: error: ...`` (no traceback)."""
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("semslam: error:"), lines
    return lines[0]


def test_fifo_and_devices_are_refused_at_once(tmp_path, capsys):
    """A FIFO hung `info`/`segment` forever, /dev/urandom read without end, /dev/zero read 7.4 GB: a point-cloud
    path must be a regular file (after symlinks)."""
    import os

    import pytest

    if not hasattr(os, "mkfifo") or not os.path.exists("/dev/urandom"):
        pytest.skip("needs os.mkfifo and /dev/urandom")
    os.mkfifo(tmp_path / "f.pcd")
    (tmp_path / "r.pcd").symlink_to("/dev/urandom")
    (tmp_path / "z.npy").symlink_to("/dev/zero")
    for name in ("f.pcd", "r.pcd", "z.npy"):
        for cmd in ("info", "segment"):
            assert main([cmd, str(tmp_path / name)]) == 1
            lines = capsys.readouterr().err.splitlines()
            assert len(lines) == 1 and name in lines[0] and "not a regular file" in lines[0], lines
