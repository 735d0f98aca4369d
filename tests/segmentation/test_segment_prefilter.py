"""The segmentation's prefilter (invalid origin points, working range) and its "auto" lengths, in
SegmentationConfig, the pipeline and the CLIs (issue #16, item 4); bad values name the argument."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.cli.main import main
from semslam.cloud import PointCloud
from semslam.errors import InputError, SemslamError
from semslam.io import write_point_cloud
from semslam.segmentation import SegmentationConfig, segment_scene
from semslam.segmentation.prefilter import resolve_lengths, valid_return_mask


def _scene(seed: int = 0) -> np.ndarray:
    """Two 4 cm boxes' faces sampled every 2 mm at 0.4 m, 30 invalid points at the origin, a far wall."""
    rng = np.random.default_rng(seed)
    g = np.arange(0.0, 0.04, 0.002)
    face = np.array([[x, y, 0.0] for x in g for y in g])
    a = face + [-0.05, 0.0, 0.40]
    b = face + [0.05, 0.0, 0.42]
    wall = np.c_[rng.uniform(-0.5, 0.5, (3000, 2)), np.full(3000, 1.5)]
    pts = np.vstack([a, b, np.zeros((30, 3)), wall])
    return pts[rng.permutation(len(pts))]


def test_origin_and_range_are_left_out_and_indices_map_to_the_input():
    pts = _scene()
    cfg = SegmentationConfig(drop_origin=True, max_range_m=1.0, voxel_leaf_m="auto", cluster_tolerance_m="auto",
                             max_planes=0, min_cluster_size=20)
    res = segment_scene(PointCloud(pts), cfg, seed=0)
    assert res.n_input_points == len(pts) and len(res.kept_indices) == 800
    assert "30 at the sensor origin" in res.notes[0] and "3000 outside the working range" in res.notes[0]
    assert res.resolved["spacing_m"] == pytest.approx(0.002, rel=0.05)
    assert res.resolved["cluster_tolerance_m"] == pytest.approx(4 * res.resolved["voxel_leaf_m"])
    assert res.cluster_sizes and len(res.clusters) == 2
    for k in range(2):
        idx = res.input_indices(k)
        assert len(idx) == 400 and np.all(np.abs(pts[idx, 2] - 0.41) < 0.011)
    d = res.to_dict()
    assert d["n_kept_points"] == 800 and d["resolved"]["voxel_leaf_m"] == res.resolved["voxel_leaf_m"]


def test_defaults_keep_every_point_and_measure_nothing():
    pts = _scene()
    res = segment_scene(PointCloud(pts), SegmentationConfig(), seed=0)
    assert res.kept_indices is None and res.resolved == {"voxel_leaf_m": 0.005, "cluster_tolerance_m": 0.02,
                                                         "spacing_m": None}
    assert valid_return_mask(pts[pts.any(axis=1)], np.zeros(3)) is None


def test_resolve_lengths_without_a_grid_and_on_too_few_points():
    grid = np.array([[x, y, 0.0] for x in np.arange(0, 0.1, 0.01) for y in np.arange(0, 0.1, 0.01)])
    leaf, tol, s = resolve_lengths(grid, None, "auto")
    assert leaf is None and s == pytest.approx(0.01) and tol == pytest.approx(0.04)
    assert resolve_lengths(grid[:3], "auto", "auto") == (0.005, 0.02, None)


def test_pipeline_border_and_indices_with_origin_points():
    from semslam.pipeline._scan_helpers import _input_indices

    pts = _scene(1)
    cfg = SegmentationConfig(drop_origin=True, max_range_m=1.0, voxel_leaf_m="auto", cluster_tolerance_m="auto",
                             max_planes=0, min_cluster_size=20)
    res = segment_scene(PointCloud(pts), cfg, seed=0)
    for k in range(res.n_clusters):
        np.testing.assert_array_equal(_input_indices(res, k), res.input_indices(k))


@pytest.mark.parametrize("kw, name", [
    ({"voxel_leaf_m": "automatic"}, "voxel_leaf_m"),
    ({"voxel_leaf_m": -0.1}, "voxel_leaf_m"),
    ({"cluster_tolerance_m": "x"}, "cluster_tolerance_m"),
    ({"cluster_tolerance_m": None}, "cluster_tolerance_m"),
    ({"max_range_m": 0.0}, "max_range_m"),
    ({"max_range_m": 0.3, "min_range_m": 0.5}, "max_range_m"),
    ({"min_range_m": -1.0}, "min_range_m"),
    ({"drop_origin": "yes"}, "drop_origin"),
])
def test_bad_config_values_name_the_argument(kw, name):
    with pytest.raises(InputError, match=name) as err:
        SegmentationConfig(**kw)
    assert isinstance(err.value, SemslamError) and "Got" in str(err.value)


@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "frame.pcd"
    write_point_cloud(path, PointCloud(_scene()))
    return path


def test_segment_cli_with_range_and_auto(scene_file, capsys):
    assert main(["segment", str(scene_file), "--max-range", "1", "--voxel", "auto", "--cluster-tolerance", "auto",
                 "--max-planes", "0", "--min-cluster-size", "20"]) == 0
    out = capsys.readouterr().out
    assert "2 clusters: " in out and "auto: point spacing 2.00 mm" in out and "30 at the sensor origin" in out
    assert main(["segment", str(scene_file), "--keep-origin-points", "--max-planes", "0", "--json"]) == 0
    assert "at the sensor origin" not in capsys.readouterr().out


@pytest.mark.parametrize("command", ["segment", "recognize"])
@pytest.mark.parametrize("argv, option", [
    (["--max-range", "-1"], "--max-range"),
    (["--max-range", "far"], "--max-range"),
    (["--min-range", "nan"], "--min-range"),
    (["--voxel", "autox"], "--voxel"),
    (["--cluster-tolerance", "fine"], "--cluster-tolerance"),
])
def test_cli_bad_values_name_the_option(scene_file, capsys, command, argv, option):
    extra = ["--db", "builtin"] if command == "recognize" else []
    assert main([command, str(scene_file), *extra, *argv]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and option in err and argv[-1] in err


def test_recognize_cli_bad_max_planes(scene_file, capsys):
    assert main(["recognize", str(scene_file), "--db", "builtin", "--max-planes", "-1"]) == 1
    assert "--max-planes" in capsys.readouterr().err
