"""Model databases rendered by the sensor that will look for the objects (semslam.simulation.model_database)."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from semslam.dataset import VehicleDescription, write_vehicle_toml
from semslam.errors import InputError, SemslamError
from semslam.geometry import RigidTransform
from semslam.simulation import builtin_objects
from semslam.simulation.config import ScannerConfig
from semslam.simulation.model_database import scanner_from_vehicle, sensor_database, sensor_view_clouds


@pytest.fixture(scope="module")
def tee():
    return {"reducing_tee": builtin_objects()["reducing_tee"]}


def _vehicle(**scanner) -> VehicleDescription:
    v = VehicleDescription.girona500()
    return dataclasses.replace(v, scanner=dataclasses.replace(v.scanner, **scanner))


def test_the_simulators_vehicle_file_gives_the_simulators_scanner(tmp_path):
    default = ScannerConfig()
    T = RigidTransform.from_xyz_rpy(default.T_vehicle_scanner_xyz_m, default.T_vehicle_scanner_rpy_rad)
    path = tmp_path / "vehicle.toml"
    write_vehicle_toml(_vehicle(T_vehicle_scanner=T, line_count=default.n_lines, fov_rad=default.sweep_fov_rad,
                                rate_hz=default.scan_rate_hz, min_range_m=default.min_range_m,
                                max_range_m=default.max_range_m), path)
    assert scanner_from_vehicle(path) == default


def test_a_vehicles_scanner_sets_mounting_field_of_view_lines_and_range():
    T = RigidTransform.from_xyz_rpy((0.2, -0.1, 0.4), (0.0, math.radians(10.0), 0.0))
    sc = scanner_from_vehicle(_vehicle(T_vehicle_scanner=T, line_count=200, fov_rad=math.radians(30.0), rate_hz=5.0,
                                       min_range_m=0.5, max_range_m=6.0))
    assert sc.n_lines == 200 and sc.scan_rate_hz == 5.0 and (sc.min_range_m, sc.max_range_m) == (0.5, 6.0)
    assert sc.sweep_fov_rad == pytest.approx(math.radians(30.0)) and sc.line_fov_rad == sc.sweep_fov_rad
    np.testing.assert_allclose(sc.T_vehicle_scanner_xyz_m, (0.2, -0.1, 0.4), atol=1e-12)
    np.testing.assert_allclose(sc.T_vehicle_scanner_rpy_rad, (0.0, math.radians(10.0), 0.0), atol=1e-12)
    assert scanner_from_vehicle(_vehicle(line_count=0)).n_lines == ScannerConfig().n_lines  # unknown: the default
    with pytest.raises(InputError, match="vehicle"):
        scanner_from_vehicle(42)


def test_a_vehicles_triangulation_camera_sets_the_rendered_baseline(tmp_path):
    """`scanner.camera_xyz_m` of a vehicle file is the rendering scanner's camera (the simulator's lies along the
    scanner's x axis: another direction is refused, naming the key); the key absent: the simulator's 0.3 m."""
    assert scanner_from_vehicle(_vehicle()).baseline_m == ScannerConfig().baseline_m
    assert scanner_from_vehicle(_vehicle(camera_xyz_m=(0.15, 0.0, 0.0))).baseline_m == 0.15
    with pytest.raises(InputError, match="camera_xyz_m"):
        scanner_from_vehicle(_vehicle(camera_xyz_m=(0.0, 0.2, 0.0)))
    # the file round trip: written when set, left out when not (TOML has no null)
    path = tmp_path / "vehicle.toml"
    write_vehicle_toml(_vehicle(camera_xyz_m=(0.25, 0.0, 0.01)), path)
    assert "camera_xyz_m = [" in path.read_text()
    from semslam.dataset import read_vehicle_toml

    assert read_vehicle_toml(path).scanner.camera_xyz_m == (0.25, 0.0, 0.01)
    write_vehicle_toml(_vehicle(), path)
    assert "camera_xyz_m" not in path.read_text() and read_vehicle_toml(path).scanner.camera_xyz_m is None


def test_laser_views_whole_and_cut_are_reproducible(tee):
    views, classes = sensor_view_clouds(tee, sensor="laser", seed=4, laser_views=6, laser_cut_views=3)
    ids = [v[1] for v in views]
    assert len(ids) == 9 and sum(i.endswith("_cut") for i in ids) == 3 and set(classes) == {"reducing_tee"}
    again, _ = sensor_view_clouds(tee, sensor="laser", seed=4, laser_views=6, laser_cut_views=3)
    for (_, _, a), (_, _, b) in zip(views, again):
        np.testing.assert_array_equal(a.points_xyz_m, b.points_xyz_m)
    both, _ = sensor_view_clouds(tee, sensor="kinect+laser", seed=4, n_views=2, laser_views=6, laser_cut_views=3)
    assert len(both) == 11 and sum("_laser_hdg" in v[1] for v in both) == 9
    with pytest.raises(SemslamError, match="sensor"):
        sensor_view_clouds(tee, sensor="sonar")


def test_a_narrower_scanner_renders_other_views(tee):
    wide, _ = sensor_view_clouds(tee, seed=1, laser_views=4, laser_cut_views=0)
    narrow_scanner = dataclasses.replace(ScannerConfig(), points_per_line=160, n_lines=160)
    narrow, _ = sensor_view_clouds(tee, seed=1, laser_views=4, laser_cut_views=0, scanner=narrow_scanner)
    # half the lines and half the points a line over the same field of view: about a quarter of the points
    ratio = sum(v[2].n_points for v in narrow) / sum(v[2].n_points for v in wide)
    assert 0.15 < ratio < 0.4


def test_sensor_database_records_views_pose_views_and_resting_up():
    objects = builtin_objects()
    two = {k: objects[k] for k in ("reducing_tee", "reducing_socket")}
    db = sensor_database(two, seed=0, laser_views=3, laser_cut_views=1, n_model_views=2)
    assert db.n_views == 8 and all(len(db.pose_views(k)) == 2 for k in two)
    # the socket rests on one face: its up is recorded; the tee lies on either face: both ways up
    np.testing.assert_allclose(db.up_object("reducing_socket"), [0.0, 0.0, 1.0], atol=1e-9)
    assert db.up_object("reducing_tee") is None and len(db.up_objects("reducing_tee")) == 2
    assert db.scanner_camera_xyz_m == (ScannerConfig().baseline_m, 0.0, 0.0)  # the laser views' camera
    kinect = sensor_database(two, sensor="kinect", seed=0, n_views=1, n_model_views=0)
    assert kinect.scanner_camera_xyz_m is None and "scanner_camera_xyz_m" not in kinect.params


def test_db_build_with_a_vehicle_file_renders_its_laser(tmp_path, capsys):
    from semslam.cli.main import main
    from semslam.recognition import load_database

    vehicle = tmp_path / "vehicle.toml"
    write_vehicle_toml(_vehicle(line_count=160, camera_xyz_m=(0.25, 0.0, 0.0)), vehicle)
    out = tmp_path / "db.npz"
    assert main(["--json", "db", "build", "--builtin", "--vehicle", str(vehicle), "--laser-views", "2",
                 "--laser-cut-views", "0", "--model-views", "0", "--out", str(out)]) == 0
    assert json.loads(capsys.readouterr().out)["sensor"] == "laser"  # the vehicle file implies the laser
    db = load_database(out)
    assert all("_laser_hdg" in str(v) for v in db.view_ids) and db.n_views == 2 * len(db.classes)
    assert db.scanner_camera_xyz_m == (0.25, 0.0, 0.0)  # the vehicle's camera, through the saved file
    assert main(["db", "build", "--builtin", "--vehicle", str(vehicle), "--sensor", "kinect",
                 "--out", str(tmp_path / "x.npz")]) == 1
    err = capsys.readouterr().err
    assert "--vehicle" in err and "--sensor kinect" in err and len(err.strip().splitlines()) == 1
    assert main(["db", "build", "--builtin", "--vehicle", str(tmp_path / "missing.toml"),
                 "--out", str(tmp_path / "y.npz")]) == 1
    err = capsys.readouterr().err
    assert "missing.toml" in err and len(err.strip().splitlines()) == 1


def test_the_catalogue_benchmarks_laser_database_is_the_one_db_build_makes(tee):
    """benchmarks/catalogue.py --db-sensor laser measures the user's database (session 24: it had built its own,
    without border-cut views, with 8 pose-model views and no scanner camera)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "benchmarks" / "catalogue.py"
    spec = importlib.util.spec_from_file_location("catalogue_benchmark", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    ours = bench.build_db(tee, 3, sensor="laser", laser_views=2, laser_cut_views=1)
    users = sensor_database(tee, sensor="laser", seed=3, laser_views=2, laser_cut_views=1)
    assert list(ours.view_ids) == list(users.view_ids) and any("_cut" in str(v) for v in ours.view_ids)
    assert np.array_equal(ours.esf, users.esf) and np.array_equal(ours.points_xyz_m, users.points_xyz_m)
    assert ours.scanner_camera_xyz_m == users.scanner_camera_xyz_m is not None
    assert np.array_equal(ours.model_points_xyz_m, users.model_points_xyz_m)
    assert len(ours.model_labels) == len(users.model_labels) > 8  # 16 pose-model views (or both rests' 2 x 8)
