"""``semslam describe`` end to end on a bun0 PCD written to a temporary directory."""

from __future__ import annotations

import json

import numpy as np
import pytest

from semslam.cli.main import main
from semslam.cloud import PointCloud
from semslam.io import write_point_cloud


def golden(test_data, name):
    for line in (test_data / "descriptors" / "pcl-1.13.txt").read_text().splitlines():
        if line.startswith(name + " "):
            return np.array(line.split()[1:], dtype=float)
    raise KeyError(name)


@pytest.fixture(scope="module")
def bun0_files(test_data, tmp_path_factory):
    d = np.load(test_data / "descriptors" / "bun0.npy").astype(np.float64)
    tmp = tmp_path_factory.mktemp("describe")
    with_normals = tmp / "bun0_normals.pcd"
    xyz_only = tmp / "bun0_xyz.pcd"
    write_point_cloud(with_normals, PointCloud(d[:, :3], d[:, 3:6]))
    write_point_cloud(xyz_only, PointCloud(d[:, :3]))
    return with_normals, xyz_only


def run_json(capsys, *argv):
    assert main(["describe", *map(str, argv), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_esf_pcl_sampler_json(capsys, test_data, bun0_files):
    out = run_json(capsys, bun0_files[1], "--descriptor", "esf", "--sampler", "pcl", "--seed", 12345)
    assert out["descriptor"] == "esf" and out["n_points"] == 397 and out["n_bins"] == 640
    np.testing.assert_array_equal(np.float32(out["bins"]), np.float32(golden(test_data, "ESF_bun0_seed12345")))


def test_vfh_uses_file_normals_unless_told(capsys, test_data, bun0_files):
    out = run_json(capsys, bun0_files[0], "--descriptor", "vfh")
    assert out["normals"] == "file"
    np.testing.assert_allclose(out["bins"], golden(test_data, "VFH_bun0_filenormals_default"), rtol=1e-4, atol=1e-4)
    out = run_json(capsys, bun0_files[0], "--descriptor", "vfh", "--normal-knn", 10)
    assert out["normals"] == "knn=10"
    np.testing.assert_allclose(out["bins"], golden(test_data, "VFH_bun0_k10normals_default"), rtol=1e-4, atol=1e-4)


def test_fpfh_text_output(capsys, bun0_files):
    assert main(["describe", str(bun0_files[1]), "--descriptor", "fpfh", "--normal-radius", "0.01",
                 "--fpfh-radius", "0.02", "--point", "3"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("FPFH of") and "33 bins" in lines[0]
    bins = np.array(lines[1].split(), dtype=float)
    assert bins.shape == (33,) and np.allclose(bins.reshape(3, 11).sum(axis=1), 100.0, rtol=1e-6)


def test_errors_are_one_line(capsys, bun0_files):
    """VFH of a cloud without normals and FPFH without a radius: exit 1 and exactly one stderr line naming the
    option to add; two normal estimators at once: usage error 2 naming both.

    Catches: a multi-line message or a traceback (only ``startswith`` was checked), a message naming the wrong
    option, a contradictory pair of options silently resolved."""
    assert main(["describe", str(bun0_files[1]), "--descriptor", "vfh"]) == 1
    assert "--normal-knn" in _one_line_error(capsys)
    assert main(["describe", str(bun0_files[0]), "--descriptor", "fpfh"]) == 1
    assert "--fpfh-radius" in _one_line_error(capsys)
    with pytest.raises(SystemExit) as exc:
        main(["describe", str(bun0_files[0]), "--normal-knn", "5", "--normal-radius", "0.1"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--normal-knn" in err and "--normal-radius" in err


def _one_line_error(capsys) -> str:
    """The CLI's error contract: stderr is exactly one line, ``semslam: error: ...`` (no traceback)."""
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("semslam: error:"), lines
    return lines[0]
