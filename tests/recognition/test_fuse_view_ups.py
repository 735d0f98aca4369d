"""Fusion when the sensors were not all held the same way: one up direction per view (``CLASS/up.csv``).

A camera pitched differently from view to view (or a vehicle's attitude) has a different up in each sensor
frame; one ``--up`` for all views cannot align them. Made exactly from the committed real valve views: the same
points seen by cameras pitched by known angles (frames 1 and 2 of one setting show the same pose)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from semslam.cli.main import main
from semslam.cloud import PointCloud
from semslam.errors import DatabaseError
from semslam.io import read_point_cloud, write_point_cloud
from semslam.recognition.fuse import fuse_class_views, read_up_csv
from semslam.recognition.storage import load_database

SUBSET = Path(__file__).parents[1] / "data" / "real_valves"
LEVEL_UP = np.array([0.0, -1.0, 0.0])
PITCH_DEG = {"pitch000_yaw000_30cm_1": 0.0, "pitch000_yaw000_30cm_2": 25.0, "pitch000_yaw030_30cm_1": -15.0,
             "pitch000_yaw030_30cm_2": 10.0}


def pitched(deg: float) -> np.ndarray:
    """Axes (columns) of a camera pitched down by ``deg`` in the level camera's frame (x right, y down, z fwd)."""
    p = np.radians(deg)
    return np.array([[1.0, 0.0, 0.0], [0.0, np.cos(p), np.sin(p)], [0.0, -np.sin(p), np.cos(p)]])


def angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


@pytest.fixture(scope="module")
def views() -> dict:
    """view id -> (cloud in its pitched camera's frame, that camera's up)."""
    out = {}
    for vid, deg in PITCH_DEG.items():
        R = pitched(deg)
        level = read_point_cloud(SUBSET / "ball_valve" / f"{vid}.pcd").points_xyz_m
        out[vid] = (PointCloud(level @ R), R.T @ LEVEL_UP)  # x_cam = R^T x_level, row by row
    return out


def test_per_view_up_aligns_views_from_cameras_pitched_differently(views):
    ids = list(PITCH_DEG)
    items = [(v, views[v][0]) for v in ids]
    out, rep = fuse_class_views("ball_valve", items, up_sensor={v: views[v][1] for v in ids}, refine_rounds=1)
    assert rep.poses == "estimated (upright registration)" and not rep.doubtful
    np.testing.assert_allclose(rep.up_object, views[ids[0]][1], atol=0.02)  # the first view's frame holds the object
    # frames 1 and 2 of the yaw-0 setting show the same pose: the fused rotation between them undoes the pitch
    T = {}
    for vid, cloud in out:
        src = views[vid][0].points_xyz_m
        dst = cloud.points_xyz_m
        T[vid] = _rigid(src, dst)
    R1, R2 = pitched(PITCH_DEG[ids[0]]), pitched(PITCH_DEG[ids[1]])
    expected = R1.T @ R2  # maps camera-2 coordinates to camera-1 coordinates (both see the same level scene)
    assert angle_deg(T[ids[0]][:3, :3].T @ T[ids[1]][:3, :3] @ expected.T) < 3.0
    # every view's up lands on the object's up
    for vid in ids:
        u = T[vid][:3, :3] @ views[vid][1]
        assert np.degrees(np.arccos(np.clip(u @ np.asarray(rep.up_object), -1, 1))) < 2.0, vid


def test_one_up_for_differently_pitched_views_cannot_align_them(views):
    """The oracle of the test above is not vacuous: the same views fused with one level up miss the pitch."""
    ids = list(PITCH_DEG)
    out, _ = fuse_class_views("ball_valve", [(v, views[v][0]) for v in ids], up_sensor=LEVEL_UP, refine_rounds=1)
    T = {vid: _rigid(views[vid][0].points_xyz_m, c.points_xyz_m) for vid, c in out}
    expected = pitched(PITCH_DEG[ids[0]]).T @ pitched(PITCH_DEG[ids[1]])
    assert angle_deg(T[ids[0]][:3, :3].T @ T[ids[1]][:3, :3] @ expected.T) > 15.0


def test_up_csv_in_the_views_folder_and_the_cli(tmp_path, views):
    d = tmp_path / "views" / "ball_valve"
    d.mkdir(parents=True)
    rows = []
    for vid, (cloud, up) in views.items():
        write_point_cloud(d / f"{vid}.pcd", cloud)
        rows.append(f"{vid},{up[0]:.12g},{3 * up[1]:.12g},{3 * up[2]:.12g}")  # any length
    (d / "up.csv").write_text("view,x,y,z\n" + "\n".join(rows) + "\n")
    out = tmp_path / "db.npz"
    # --up is given too: the class's own up.csv wins
    assert main(["db", "build", str(tmp_path / "views"), "--fuse", "--up", "1,0,0", "--out", str(out),
                 "--esf-samples", "2000"]) == 0
    fusion = load_database(out).params["fusion"]["ball_valve"]
    assert not fusion["doubtful"] and fusion["poses"] == "estimated (upright registration)"
    first = sorted(views)[0]  # the views are taken in name order; the first one's frame holds the object
    np.testing.assert_allclose(fusion["up_object"], views[first][1], atol=0.02)


def test_up_csv_bad_inputs(tmp_path):
    f = tmp_path / "up.csv"
    ids = ["a", "b"]
    cases = [
        ("view,x,y,z\na,0,-1,0\n", r"up.csv.*no row for the view\(s\) b"),
        ("view,x,y,z\na,0,-1,0\nb,0,0,0\n", r"Line 3 .*view 'b'.*zero direction"),
        ("view,x,y,z\na,0,-1,0\nb,0,nan,0\n", r"Line 3 .*NaN or infinity"),
        ("view,x,y,z\na,0,-1,0\nb,0,-1\n", r"Line 3 .*3 fields; expected 4"),
        ("view,x,y,z\na,0,-1,0\nb,0,up,0\n", r"Line 3 .*not a number"),
        ("view,x,y,z\na,0,-1,0\na,0,-1,0\nb,0,-1,0\n", r"gives view 'a' twice"),
        ("view,x,y,z\na,0,-1,0\nb,0,-1,0\nc,0,-1,0\n", r"names view\(s\) c that are not in its folder"),
        ("view,up\na,0\n", r"must start with the header view,x,y,z"),
        ("", r"is empty"),
    ]
    for text, pattern in cases:
        f.write_text(text)
        with pytest.raises(DatabaseError, match=pattern):
            read_up_csv(f, ids)
    f.write_bytes(b"view,x,y,z\na,0,\xe9,0\n")
    with pytest.raises(DatabaseError, match="Cannot read the up file"):
        read_up_csv(f, ids)
    f.unlink()
    f.mkdir()
    with pytest.raises(DatabaseError, match="not a regular file"):
        read_up_csv(f, ids)
    # tiny and huge components are directions too
    g = tmp_path / "ok.csv"
    g.write_text("view,x,y,z\na,0,-1e-320,0\nb,1e308,-1e308,0\n")
    ups = read_up_csv(g, ids)
    np.testing.assert_allclose(ups["a"], [0, -1, 0])
    np.testing.assert_allclose(ups["b"], [np.sqrt(0.5), -np.sqrt(0.5), 0])
    with pytest.raises(DatabaseError, match=r"view 'b' of class 'k'.*3 finite numbers"):
        fuse_class_views("k", [("a", PointCloud(np.random.default_rng(0).normal(size=(50, 3))))] * 1 +
                         [("b", PointCloud(np.random.default_rng(1).normal(size=(50, 3))))],
                         up_sensor={"a": [0, -1, 0], "b": [0, 0, 0]})
    with pytest.raises(DatabaseError, match=r"No up direction for the view\(s\) b"):
        fuse_class_views("k", [("a", PointCloud(np.zeros((5, 3)))), ("b", PointCloud(np.zeros((5, 3))))],
                         up_sensor={"a": [0, -1, 0]})


def _rigid(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least-squares rigid transform taking the points ``a`` onto the corresponding points ``b``."""
    ca, cb = a.mean(0), b.mean(0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, cb - R @ ca
    return T
