"""PLY (plyfile: ascii, binary little/big endian) and NPY point clouds."""

from __future__ import annotations

import numpy as np
import plyfile
import pytest

from semslam.cloud import PointCloud
from semslam.errors import PcdError
from semslam.io import read_point_cloud, write_point_cloud


def _cloud(n: int = 40, seed: int = 0) -> PointCloud:
    rng = np.random.default_rng(seed)
    return PointCloud(
        rng.normal(size=(n, 3)).astype(np.float32),
        rng.normal(size=(n, 3)).astype(np.float32),
        rng.uniform(0, 255, n).astype(np.float32),
        frame_id="scanner",
        fields={
            "red": rng.integers(0, 256, n, dtype=np.uint8),
            "label": rng.integers(-5, 5, n, dtype=np.int32),
            "curvature": rng.uniform(0, 1, n).astype(np.float32),
        },
    )


@pytest.mark.parametrize(
    "encoding", ["ascii", "binary_little_endian", "binary_big_endian", "binary"]
)
def test_ply_round_trip(tmp_path, encoding):
    cloud = _cloud()
    path = tmp_path / "c.ply"
    write_point_cloud(path, cloud, encoding=encoding)
    ply = plyfile.PlyData.read(str(path))  # an independent reader sees the same vertices
    assert ply.text == (encoding == "ascii")
    assert np.array_equal(ply["vertex"]["x"], cloud.points_xyz_m[:, 0].astype(np.float32))
    assert np.array_equal(ply["vertex"]["nz"], cloud.normals_xyz[:, 2].astype(np.float32))
    back = read_point_cloud(path, frame_id="scanner")
    assert np.array_equal(back.points_xyz_m, cloud.points_xyz_m)
    assert np.array_equal(back.normals_xyz, cloud.normals_xyz)
    assert np.array_equal(back.intensity, cloud.intensity)
    assert set(back.fields) == {"red", "label", "curvature"}
    for k, v in cloud.fields.items():
        assert back.fields[k].dtype == v.dtype and np.array_equal(back.fields[k], v)


def test_ply_mesh_vertices_and_normal_names(tmp_path):
    vertex = np.array(
        [(0, 0, 0, 0, 0, 1), (1, 0, 0, 0, 0, 1), (0, 1, 0, 0, 0, 1), (np.nan, 0, 0, 0, 0, 1)],
        dtype=[
            ("x", "f4"),
            ("y", "f4"),
            ("z", "f4"),
            ("normal_x", "f4"),
            ("normal_y", "f4"),
            ("normal_z", "f4"),
        ],
    )
    face = np.array([([0, 1, 2],)], dtype=[("vertex_indices", "i4", (3,))])
    path = tmp_path / "mesh.ply"
    plyfile.PlyData(
        [plyfile.PlyElement.describe(vertex, "vertex"), plyfile.PlyElement.describe(face, "face")]
    ).write(str(path))
    cloud = read_point_cloud(path)
    assert cloud.n_points == 3 and cloud.fields == {}
    assert np.array_equal(cloud.normals_xyz, np.tile([0.0, 0.0, 1.0], (3, 1)))
    with pytest.raises(PcdError, match="mesh.ply.*1 point"):
        read_point_cloud(path, drop_nan=False)


def test_ply_errors(tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1\n")
    with pytest.raises(PcdError, match="bad.ply"):
        read_point_cloud(bad)
    noxyz = tmp_path / "noxyz.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(np.zeros(2, [("u", "f4")]), "vertex")]).write(
        str(noxyz)
    )
    with pytest.raises(PcdError, match="noxyz.ply.*no x, y, z"):
        read_point_cloud(noxyz)
    other = tmp_path / "other.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(np.zeros(2, [("x", "f4")]), "point")]).write(
        str(other)
    )
    with pytest.raises(PcdError, match="other.ply.*no 'vertex'"):
        read_point_cloud(other)
    (tmp_path / "empty.ply").write_bytes(b"")
    with pytest.raises(PcdError, match="empty.ply.*empty"):
        read_point_cloud(tmp_path / "empty.ply")
    truncated = tmp_path / "trunc.ply"
    write_point_cloud(truncated, _cloud())
    truncated.write_bytes(truncated.read_bytes()[:-10])
    with pytest.raises(PcdError, match="trunc.ply"):
        read_point_cloud(truncated)
    multi = PointCloud(np.zeros((2, 3)), fields={"vfh": np.zeros((2, 308), np.float32)})
    with pytest.raises(PcdError, match="'vfh'.*use .pcd"):
        write_point_cloud(tmp_path / "m.ply", multi)
    with pytest.raises(PcdError, match="encoding"):
        write_point_cloud(tmp_path / "m.ply", PointCloud(np.zeros((2, 3))), encoding="zip")


def test_npy_round_trip_and_errors(tmp_path):
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(20, 3))
    plain = tmp_path / "p.npy"
    write_point_cloud(plain, PointCloud(pts))
    assert np.load(plain).shape == (20, 3)
    assert np.array_equal(read_point_cloud(plain).points_xyz_m, pts)  # float64, exact
    nrm = rng.normal(size=(20, 3))
    write_point_cloud(tmp_path / "n.npy", PointCloud(pts, nrm))
    back = read_point_cloud(tmp_path / "n.npy")
    assert np.array_equal(back.normals_xyz, nrm) and np.array_equal(back.points_xyz_m, pts)
    np.save(tmp_path / "nan.npy", np.array([[0, 0, 0], [np.nan, 1, 2]]))
    assert read_point_cloud(tmp_path / "nan.npy").n_points == 1
    np.save(tmp_path / "bad.npy", np.zeros((4, 4)))
    with pytest.raises(PcdError, match=r"bad.npy.*\(N, 3\) or \(N, 6\).*\(4, 4\)"):
        read_point_cloud(tmp_path / "bad.npy")
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}]), allow_pickle=True)
    with pytest.raises(PcdError, match="obj.npy"):
        read_point_cloud(tmp_path / "obj.npy")
    (tmp_path / "junk.npy").write_bytes(b"not numpy at all")
    with pytest.raises(PcdError, match="junk.npy"):
        read_point_cloud(tmp_path / "junk.npy")
    with pytest.raises(PcdError, match="x.npy.*intensity"):
        write_point_cloud(tmp_path / "x.npy", PointCloud(pts, intensity=np.ones(20)))
    assert not (tmp_path / "x.npy").exists()
