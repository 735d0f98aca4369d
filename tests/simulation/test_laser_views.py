"""Database views rendered by the missions' laser scanner (semslam.simulation.laser_views)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from semslam.errors import SimulationError
from semslam.recognition import Recognizer, build_database
from semslam.simulation import builtin_objects
from semslam.simulation.laser_views import LaserViewConfig, laser_view, laser_view_clouds


@pytest.fixture(scope="module")
def objects():
    return builtin_objects()


def test_viewpoints_follow_the_config(objects):
    cfg = LaserViewConfig(altitude_m=(1.3, 1.5), cross_track_m=0.2, along_sweep=0.5)
    views, classes, infos = laser_view_clouds({"elbow": objects["elbow"]}, seed=3, n_views=8, config=cfg,
                                              return_info=True)
    assert [v[1] for v in views] == [f"elbow_laser_hdg{45.0 * k:05.1f}" for k in range(8)]
    assert set(classes) == {"elbow"}
    mount = cfg.scanner.T_vehicle_scanner_xyz_m[2]
    for (_, _, cloud), info in zip(views, infos):
        assert 1.3 <= info["altitude_m"] <= 1.5
        assert abs(info["cross_track_m"]) <= 0.2 and abs(info["along_sweep"]) <= 0.5
        assert not info["cut"] and cloud.n_points >= cfg.min_points
        # scanner height above the floor is the altitude minus the mount; the object is ~10 cm tall, so its
        # centre is 0.8-1.25 m away (the offsets add at most ~0.25 m sideways)
        assert 1.3 - mount - 0.15 <= info["range_m"] <= math.hypot(1.5 - mount, 0.2 + 0.5 * 0.5) + 0.01
        # every point lies on the object's side facing the scanner, within the object's bounding sphere
        centre = cloud.points_xyz_m.mean(axis=0)
        assert np.linalg.norm(cloud.points_xyz_m - centre, axis=1).max() < 0.2
        assert np.linalg.norm(cloud.viewpoint_xyz_m - centre) == pytest.approx(info["range_m"], abs=0.1)


def test_same_seed_same_views_and_bad_config(objects):
    a, _ = laser_view(objects["reducing_tee"], 1.0, seed=np.random.default_rng(5))
    b, _ = laser_view(objects["reducing_tee"], 1.0, seed=np.random.default_rng(5))
    c, _ = laser_view(objects["reducing_tee"], 1.0, seed=np.random.default_rng(6))
    np.testing.assert_array_equal(a.points_xyz_m, b.points_xyz_m)
    assert a.n_points != c.n_points or not np.array_equal(a.points_xyz_m, c.points_xyz_m)
    with pytest.raises(SimulationError, match="along_sweep"):
        LaserViewConfig(along_sweep=1.5)
    with pytest.raises(SimulationError, match="altitude_m"):
        LaserViewConfig(altitude_m=(0.5, 0.6))
    with pytest.raises(SimulationError, match="models"):
        laser_view_clouds({}, seed=0)


def test_cut_views_are_kept_only_when_asked(objects):
    cfg = LaserViewConfig(along_sweep=1.0, allow_cut=True)
    _, _, infos = laser_view_clouds({"ball_valve": objects["ball_valve"]}, seed=1, n_views=12, config=cfg,
                                    return_info=True)
    assert any(i["cut"] for i in infos)  # at the swath's edge some views are cut
    _, _, infos = laser_view_clouds({"ball_valve": objects["ball_valve"]}, seed=1, n_views=12,
                                    config=LaserViewConfig(along_sweep=1.0), return_info=True)
    assert not any(i["cut"] for i in infos)


def test_a_laser_database_recognises_held_out_laser_views(objects):
    views, classes = laser_view_clouds(objects, seed=0, n_views=12)
    db = build_database(views, classes, seed=0)
    rec = Recognizer(db, descriptor="esf+vfh", reject_margin=6.0)
    rng = np.random.default_rng(11)
    for label, model in objects.items():
        for heading_deg in (15.0, 195.0):  # half-way between the database's headings, other viewpoints
            cloud, _ = laser_view(model, math.radians(heading_deg), seed=rng)
            match = rec.match(cloud, seed=0)
            assert match.label == label, (label, heading_deg, match.to_dict())


def test_db_build_models_with_the_laser(tmp_path, test_data, capsys):
    from semslam.cli.main import main
    from semslam.recognition import load_database

    out = tmp_path / "laser.npz"
    assert main(["--json", "db", "build", "--models", str(test_data / "models"), "--sensor", "kinect+laser",
                 "--n-views", "3", "--laser-views", "3", "--laser-cut-views", "1", "--model-views", "2",
                 "--out", str(out)]) == 0
    assert '"sensor": "kinect+laser"' in capsys.readouterr().out
    db = load_database(out)
    assert db.n_views == (3 + 3 + 1) * len(db.classes)  # 3 Kinect + 3 whole laser views + 1 cut per class
    ids = [str(v) for v in db.view_ids]
    assert sum("_laser_hdg" in v for v in ids) == 4 * len(db.classes)
    assert sum(v.endswith("_cut") for v in ids) == len(db.classes)
    assert sorted(set(str(lab) for lab in db.labels)) == sorted(db.classes)
    assert all(len(db.pose_views(lab)) == 2 for lab in db.classes)


def test_db_build_sensor_needs_rendered_objects(tmp_path, capsys):
    from semslam.cli.main import main

    (tmp_path / "views" / "a").mkdir(parents=True)
    assert main(["db", "build", str(tmp_path / "views"), "--sensor", "laser", "--out", str(tmp_path / "x.npz")]) == 1
    err = capsys.readouterr().err
    assert "--sensor laser" in err and len(err.strip().splitlines()) == 1
