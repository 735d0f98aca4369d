"""segment_scene and ``semslam segment``: a synthetic tank scene with known objects, bad input, the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from semslam.cli.main import main
from semslam.cloud import PointCloud
from semslam.errors import InputError
from semslam.segmentation import SegmentationConfig, segment_scene
from tests._support.scenes import tank_scene


def test_segment_scene_finds_the_objects():
    cloud, labels = tank_scene()
    res = segment_scene(cloud, SegmentationConfig(voxel_leaf_m=0.01, min_cluster_size=30), seed=0)
    assert len(res.planes) == 1
    np.testing.assert_allclose(
        res.planes[0].coefficients, [0, 0, -1, 2.0], atol=2e-3
    )  # scanner on + side
    assert res.n_clusters == 2 and res.cluster_sizes == sorted(res.cluster_sizes, reverse=True)
    assert (
        res.segmented_cloud.n_points < cloud.n_points and res.segmented_cloud.frame_id == "scanner"
    )
    for i, want in enumerate([1, 2]):  # the box is larger than the ball
        inputs = res.input_indices(i)
        # voxels mix a few floor points near the box's base; the cluster is the object
        assert np.mean(labels[inputs] == want) > 0.97
        assert np.count_nonzero(labels[inputs] == want) > 0.9 * np.count_nonzero(labels == want)
        np.testing.assert_array_equal(
            res.clusters[i].points_xyz_m, res.segmented_cloud.points_xyz_m[res.cluster_indices[i]]
        )
    assert set(res.timings_ms) == {"voxel", "planes", "clusters", "total"} and res.notes == []
    again = segment_scene(cloud, SegmentationConfig(voxel_leaf_m=0.01, min_cluster_size=30), seed=0)
    assert again.cluster_sizes == res.cluster_sizes  # seeded: reproducible


def test_without_voxel_grid_indices_are_into_the_input():
    cloud, labels = tank_scene(1)
    res = segment_scene(
        cloud, SegmentationConfig(voxel_leaf_m=None, min_cluster_size=100, max_cluster_size=None)
    )
    assert res.segmented_cloud is cloud and res.point_voxel is None
    assert res.n_clusters == 2
    assert np.all(labels[res.cluster_indices[0]] == 1) and np.all(
        labels[res.cluster_indices[1]] == 2
    )
    np.testing.assert_array_equal(res.input_indices(1), res.cluster_indices[1])


def test_degenerate_scenes_give_empty_results_that_say_why():
    res = segment_scene(PointCloud(np.zeros((0, 3))))
    assert res.n_clusters == 0 and "empty input" in res.notes[0]
    flat = np.c_[np.random.default_rng(0).uniform(size=(500, 2)), np.zeros(500)]
    res = segment_scene(PointCloud(flat), SegmentationConfig(voxel_leaf_m=None))
    assert res.n_clusters == 0 and "no points left after plane removal" in res.notes[-1]
    line = np.c_[np.linspace(0, 1, 200), np.zeros(200), np.zeros(200)]
    res = segment_scene(PointCloud(line), SegmentationConfig(voxel_leaf_m=None))
    assert res.planes == [] and "collinear" in res.notes[0] and res.cluster_sizes == [200]
    res = segment_scene(
        PointCloud(np.ones((40, 3))), SegmentationConfig(voxel_leaf_m=0.01, min_cluster_size=1)
    )
    assert "at least 3 points" in res.notes[0] and res.cluster_sizes == [1]
    scattered = np.random.default_rng(1).uniform(-10, 10, (300, 3))
    res = segment_scene(PointCloud(scattered), SegmentationConfig(voxel_leaf_m=None))
    assert res.n_clusters == 0 and "no cluster of 50 to 25000 points" in res.notes[-1]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"voxel_leaf_m": 0.0}, "voxel_leaf_m"),
        ({"distance_threshold_m": -1}, "distance_threshold_m"),
        ({"max_planes": -1}, "max_planes"),
        ({"min_cluster_size": 10, "max_cluster_size": 5}, "max_cluster_size"),
        ({"plane_confidence": 1.5}, "plane_confidence"),
        ({"min_plane_inliers": 2}, "min_plane_inliers"),
    ],
)
def test_config_is_validated(kwargs, match):
    with pytest.raises(InputError, match=match):
        SegmentationConfig(**kwargs)


def test_segment_scene_rejects_wrong_types():
    with pytest.raises(InputError, match="PointCloud"):
        segment_scene(np.zeros((10, 3)))
    with pytest.raises(InputError, match="SegmentationConfig"):
        segment_scene(PointCloud(np.zeros((3, 3))), {"voxel_leaf_m": 0.01})


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    from semslam.io import write_point_cloud

    path = tmp_path_factory.mktemp("scene") / "tank.pcd"
    write_point_cloud(path, tank_scene()[0])
    return path


def test_cli_json_and_out(scene_file, tmp_path, capsys):
    out = tmp_path / "clusters"
    code = main(
        [
            "segment",
            str(scene_file),
            "--voxel",
            "0.01",
            "--min-cluster-size",
            "30",
            "--seed",
            "3",
            "--out",
            str(out),
            "--json",
        ]
    )
    assert code == 0
    payload = json.loads(capsys.readouterr().out)
    assert len(payload["planes"]) == 1 and payload["planes"][0]["n_inliers"] > 5000
    np.testing.assert_allclose(payload["planes"][0]["coefficients"], [0, 0, -1, 2.0], atol=2e-3)
    sizes = payload["cluster_sizes"]
    assert len(sizes) == 2 and sizes == sorted(sizes, reverse=True)
    assert set(payload["timings_ms"]) == {"voxel", "planes", "clusters", "total"}
    assert payload["seed"] == 3 and payload["config"]["voxel_leaf_m"] == 0.01
    from semslam.io import read_point_cloud

    written = [read_point_cloud(f) for f in payload["files"]]
    assert [c.n_points for c in written] == sizes
    assert json.loads((out / "segmentation.json").read_text())["cluster_sizes"] == sizes
    # a second run with fewer clusters never leaves the first run's stale cluster files beside its own
    (out / "cluster_007.pcd").write_bytes(b"stale")
    assert main(["segment", str(scene_file), "--voxel", "0.01", "--min-cluster-size", "30", "--out", str(out),
                 "--max-cluster-size", "0", "--json"]) == 1  # an earlier run: refused without --overwrite
    capsys.readouterr()
    assert main(["segment", str(scene_file), "--voxel", "0.01", "--min-cluster-size", "30", "--out", str(out),
                 "--overwrite", "--json"]) == 0
    capsys.readouterr()
    assert sorted(p.name for p in out.glob("cluster_*.pcd")) == ["cluster_000.pcd", "cluster_001.pcd"]


def test_cli_text_output(scene_file, capsys):
    assert main(["segment", str(scene_file), "--voxel", "0", "--max-cluster-size", "0"]) == 0
    text = capsys.readouterr().out
    assert "plane 0:" in text and "2 clusters:" in text and "time: voxel" in text


@pytest.mark.parametrize(
    "argv, match",
    [
        (["--voxel", "-1"], "--voxel"),
        (["--cluster-tolerance", "0"], "cluster_tolerance_m"),
        (["--min-cluster-size", "10", "--max-cluster-size", "5"], "max_cluster_size"),
        (["--seed", "-1"], "--seed"),
    ],
)
def test_cli_bad_options_exit_1(scene_file, capsys, argv, match):
    """Catches a bad option value accepted (exit 0), a traceback or a multi-line message (only the start of
    stderr was checked), or a message not naming the option and the bad value."""
    assert main(["segment", str(scene_file), *argv]) == 1
    line = _one_line_error(capsys)
    assert match in line and argv[-1] in line


def test_cli_missing_file(tmp_path, capsys):
    """Catches a missing input escaping as a traceback (which also ends in a non-zero status) or an error
    that does not name the file."""
    assert main(["segment", str(tmp_path / "nope.pcd")]) == 1
    line = _one_line_error(capsys)
    assert "nope.pcd" in line and "no such file" in line


def _one_line_error(capsys) -> str:
    """The CLI's error contract: stderr is exactly one line, ``semslam: error: ...`` (no traceback)."""
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("semslam: error:"), lines
    return lines[0]


def _sha(a) -> str:
    import hashlib

    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def test_matches_golden_of_previous_implementation():
    """Bit-identical to the sort-based implementation before the latency pass (golden fingerprints
    from tests/data/segmentation/make_scene_golden.py): voxel centroids and order, intensity means,
    point -> voxel map, plane inliers, cluster partitions and order, input indices."""
    from pathlib import Path

    from semslam.segmentation import voxel_grid

    golden = json.loads(
        (Path(__file__).parents[1] / "data" / "segmentation" / "segment_scene_golden.json").read_text()
    )
    for case in golden["cases"]:
        cloud, _ = tank_scene(case["scene_seed"])
        if "config" not in case:
            g = voxel_grid(
                cloud.points_xyz_m, case["voxel_leaf_m"], pcl_rounding=case["pcl_rounding"]
            )
            assert g.n_voxels == case["n_voxels"]
            assert _sha(g.points_xyz_m) == case["centroids_sha"]
            assert _sha(g.point_voxel) == case["point_voxel_sha"]
            assert _sha(g.counts) == case["counts_sha"]
            continue
        r = segment_scene(cloud, SegmentationConfig(**case["config"]), seed=case["seed"])
        assert r.segmented_cloud.n_points == case["n_segmented"]
        assert _sha(r.segmented_cloud.points_xyz_m) == case["centroids_sha"]
        assert _sha(r.segmented_cloud.intensity) == case["intensity_sha"]
        if case["point_voxel_sha"] is None:
            assert r.point_voxel is None
        else:
            assert _sha(r.point_voxel) == case["point_voxel_sha"]
        assert len(r.planes) == len(case["planes"])
        for plane, want in zip(r.planes, case["planes"]):
            assert plane.n_inliers == want["n_inliers"]
            assert (plane.n_iterations, plane.n_scored) == (want["n_iterations"], want["n_scored"])
            np.testing.assert_allclose(plane.coefficients, want["coefficients"], rtol=0, atol=1e-12)
            np.testing.assert_allclose(plane.rmse_m, want["rmse_m"], rtol=1e-12)
        assert r.n_after_planes == case["n_after_planes"]
        assert r.cluster_sizes == case["cluster_sizes"]
        assert [_sha(c) for c in r.cluster_indices] == case["clusters_sha"]
        assert [_sha(r.input_indices(k)) for k in range(r.n_clusters)] == case["input_indices_sha"]


@pytest.mark.parametrize("leaf", [0.01, 0.03])
def test_input_indices_against_brute_force(leaf):
    # small clusters take the per-voxel gather path, large ones (the floor with max_planes=0) the mask
    cloud, _ = tank_scene(2)
    for cfg in (
        SegmentationConfig(voxel_leaf_m=leaf, min_cluster_size=1, max_cluster_size=None),
        SegmentationConfig(
            voxel_leaf_m=leaf, max_planes=0, min_cluster_size=1, max_cluster_size=None
        ),
    ):
        res = segment_scene(cloud, cfg, seed=0)
        assert res.n_clusters >= 1
        covered = np.zeros(cloud.n_points, int)
        for k in range(res.n_clusters):
            want = np.flatnonzero(np.isin(res.point_voxel, res.cluster_indices[k]))
            got = res.input_indices(k)
            assert got.dtype == np.int64
            np.testing.assert_array_equal(got, want)
            covered[got] += 1
        assert covered.max() == 1  # clusters are disjoint in the input too
