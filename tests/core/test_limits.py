"""Plausibility ranges (semslam.limits) and bounded work (issue 31, items 2 and 3): every case measured on main is
a one-line error naming where the value came from and its range, or a counted rejection; nothing hangs."""

from __future__ import annotations

import math
import signal
import time
from dataclasses import fields
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from semslam.dataset import (AttitudeLog, Dataset, DepthLog, DvlLog, VehicleDescription, read_dataset,
                             read_vehicle_toml, write_dataset)
from semslam.dataset.rosbag import BagDecoder, TopicMap
from semslam.dataset.vehicle import _SECTIONS as VEHICLE_SECTIONS
from semslam.errors import BagError, ConfigError, DatasetError, SlamError
from semslam.limits import LIMITS, PlausibilityError, check, limits_markdown
from semslam.slam import SlamConfig
from semslam.slam.config import _SECTIONS as SLAM_SECTIONS
from semslam.slam.session import SlamSession

ROOT = Path(__file__).resolve().parents[2]


def _one_line(exc: BaseException, *words: str) -> str:
    msg = str(exc)
    assert "\n" not in msg, msg
    for w in words:
        assert w in msg, (w, msg)
    return msg


# ------------------------------------------------------------------ the table and the checker


def test_checker_accepts_the_range_and_names_where_range_and_value_outside_it():
    assert check("vehicle.dvl.noise_abs_mps", 0.001, "x") == 0.001
    assert check("vehicle.dvl.noise_abs_mps", 1e-4, "x") == 1e-4  # closed range: the bounds are in
    assert check("vehicle.scanner.line_count", 100.0, "x") == 100 and isinstance(check("vehicle.scanner.line_count",
                                                                                       100.0, "x"), int)
    with pytest.raises(DatasetError) as exc:
        check("vehicle.extrinsic.xyz_m", 600.0, "The vehicle file 'v.toml' key 'scanner.xyz_m[0]'", error=DatasetError)
    assert isinstance(exc.value, PlausibilityError)  # both families: the caller's and the plausibility one
    _one_line(exc.value, "'v.toml'", "'scanner.xyz_m[0]'", "[-20, 20] m", "millimetres", "Got 600.0")
    for bad in (float("nan"), float("inf"), 1e300, -1e-3):
        with pytest.raises(PlausibilityError, match="must be in"):
            check("vehicle.dvl.noise_abs_mps", bad, "x")
    for bad in (True, "0.1", None):
        with pytest.raises(PlausibilityError, match="must be a number"):
            check("vehicle.dvl.noise_abs_mps", bad, "x")
    with pytest.raises(PlausibilityError, match="whole number"):
        check("vehicle.scanner.line_count", 2.5, "x")
    # the unit hint only when the value is too large (a negative range is not a unit mistake)
    assert "degrees" in str(pytest.raises(PlausibilityError, check, "vehicle.scanner.fov_rad", 50.0, "x").value)
    assert "degrees" not in str(pytest.raises(PlausibilityError, check, "vehicle.scanner.fov_rad", 0.0, "x").value)


def test_every_number_of_the_vehicle_file_and_the_slam_config_has_a_range():
    """One table for every physical quantity: a new setting without a range fails here."""
    missing = []
    for sec, cls in VEHICLE_SECTIONS.items():
        for f in fields(cls):
            if f.name.startswith("T_"):
                continue  # the extrinsic: vehicle.extrinsic.*
            if f"vehicle.{sec}.{f.name}" not in LIMITS:
                missing.append(f"vehicle.{sec}.{f.name}")
    for sec, cls in SLAM_SECTIONS.items():
        for f in fields(cls):
            if f.type in ("float", "int", "float | tuple") and f"slam.{sec}.{f.name}" not in LIMITS:
                missing.append(f"slam.{sec}.{f.name}")
    assert missing == []
    for key, lim in LIMITS.items():
        assert lim.lo < lim.hi and lim.unit and lim.what, key
    # the defaults are plausible
    VehicleDescription.from_dict(VehicleDescription.girona500().to_dict())
    SlamConfig.from_dict(SlamConfig().to_dict())


def test_docs_limits_md_is_the_generated_table():
    """docs/limits.md is limits_markdown() (regenerate: python -c "from semslam.limits import limits_markdown;
    open('docs/limits.md', 'w').write(limits_markdown())")."""
    text = limits_markdown()
    for key, lim in LIMITS.items():
        assert f"| `{key}` | [{lim.lo:g}, {lim.hi:g}] | {lim.unit} |" in text
    assert (ROOT / "docs" / "limits.md").read_text(encoding="utf-8") == text


# ------------------------------------------------------------------ the SLAM config


@pytest.mark.parametrize("section, key, value, words", [
    ("output", "history_rate_hz", 1e9, ("'history_rate_hz'", "[0.001, 100] Hz", "Got 1000000000.0")),
    ("motion", "max_predict_dt_s", 1e-9, ("'max_predict_dt_s'", "[0.001, 10] s", "Got 1e-09")),
    ("motion", "velocity_rw_mps_per_sqrt_s", 1e300, ("'velocity_rw_mps_per_sqrt_s'", "[0, 10] m/s/sqrt(s)", "1e+300")),
    ("motion", "velocity_rw_mps_per_sqrt_s", [0.02, 1e300, 0.01],
     ("'velocity_rw_mps_per_sqrt_s' field of MotionConfig (element 1)", "1e+300")),
    ("motion", "unaided_velocity_rw_mps_per_sqrt_s", 1e300, ("'unaided_velocity_rw_mps_per_sqrt_s'", "1e+300")),
    ("initialisation", "initial_position_sigma_m", 1e300, ("'initial_position_sigma_m'", "[1e-06, 1000] m")),
    ("map", "dense_max_landmarks", 100_000, ("'dense_max_landmarks'", "[0, 500]", "Got 100000")),
    ("output", "smoother_max_mb", 1e12, ("'smoother_max_mb'", "MB")),
])
def test_config_value_outside_its_range_is_one_line_naming_the_file_key_and_range(section, key, value, words):
    """history_rate_hz = 1e9 took 2.5 GB in 60 s, max_predict_dt_s = 1e-9 hung the CPU, a random walk of 1e300
    raised LinAlgError: now refused before any work."""
    t = time.perf_counter()
    with pytest.raises(ConfigError) as exc:
        SlamConfig.from_dict({section: {key: value}}, source="the --config file 'slam.toml'")
    assert time.perf_counter() - t < 1.0
    assert isinstance(exc.value, PlausibilityError)
    _one_line(exc.value, "'slam.toml'", *words)


def test_config_at_the_range_bounds_is_accepted():
    cfg = SlamConfig.from_dict({"output": {"history_rate_hz": 100.0}, "motion": {"max_predict_dt_s": 1e-3,
                                                                               "velocity_rw_mps_per_sqrt_s": 0.0}})
    assert cfg.output.history_rate_hz == 100.0 and cfg.motion.max_predict_dt_s == 1e-3
    with pytest.raises(ConfigError, match="history_rate_hz"):
        SlamConfig().updated(history_rate_hz=100.001)


# ------------------------------------------------------------------ the vehicle file

_MOUNT = "[scanner]\nxyz_m = [0.6, 0.0, 0.3]\nrpy_rad = [0.0, 0.0, 1.5708]\n"


@pytest.mark.parametrize("name, text, words", [
    ("millimetres", "[scanner]\nxyz_m = [600.0, 0.0, 300.0]\nrpy_rad = [0.0, 0.0, 0.0]\n",
     ("'scanner.xyz_m[0]'", "[-20, 20] m", "millimetres", "Got 600.0")),
    ("huge", "[scanner]\nxyz_m = [0.6, 1e300, 0.3]\n", ("'scanner.xyz_m[1]'", "Got 1e+300")),
    ("matrix", "[scanner]\nmatrix = [[1,0,0,600],[0,1,0,0],[0,0,1,300],[0,0,0,1]]\n",
     ("'scanner.matrix' translation [0]", "[-20, 20] m", "600.0")),
    ("dvl_mount", _MOUNT + "[dvl]\nxyz_m = [-300.0, 0.0, 400.0]\n", ("'dvl.xyz_m[0]'", "-300.0")),
    ("degrees", "[scanner]\nxyz_m = [0, 0, 0]\nrpy_rad = [0.0, 0.0, 90.0]\n",
     ("'scanner.rpy_rad[2]'", "degrees given for radians", "90.0")),
    ("ranges", _MOUNT + "min_range_m = 5.0\nmax_range_m = 4.0\n",
     ("'scanner.min_range_m' must be below 'scanner.max_range_m'", "5.0 >= 4.0")),
    ("zero_dvl_noise", _MOUNT + "[dvl]\nnoise_abs_mps = 0.0\nnoise_rel = 0.0\n",
     ("'dvl.noise_abs_mps'", "[0.0001, 1] m/s", "Got 0.0")),
    ("pressure_kpa", _MOUNT + "[depth]\natmospheric_pressure_pa = 101.325\n",
     ("'depth.atmospheric_pressure_pa'", "[50000, 200000] Pa", "101.325")),
    ("empty", "", ("is empty", "'scanner.xyz_m'", "'scanner.matrix'", "girona500")),
    ("only_name", "format_version = 1\nname = \"auv\"\n", ("is empty", "'scanner.xyz_m'")),
    ("no_extrinsic", "[scanner]\nline_count = 100\n[dvl]\nnoise_abs_mps = 0.001\n",
     ("has no scanner extrinsic", "'scanner.xyz_m'", "'scanner.matrix'")),
])
def test_vehicle_file_implausible_or_incomplete_is_one_line_naming_the_file_and_key(tmp_path, name, text, words):
    f = tmp_path / f"{name}.toml"
    f.write_text(text)
    with pytest.raises(DatasetError) as exc:
        read_vehicle_toml(f)
    _one_line(exc.value, str(f), *words)


def test_vehicle_file_with_a_scanner_at_the_origin_and_defaults_elsewhere_reads(tmp_path):
    f = tmp_path / "v.toml"
    f.write_text("[scanner]\nxyz_m = [0, 0, 0]\n")
    v = read_vehicle_toml(f)
    np.testing.assert_array_equal(v.T_vehicle_scanner.matrix, np.eye(4))
    assert v.to_dict()["dvl"] == VehicleDescription.girona500().to_dict()["dvl"]
    f.write_text(_MOUNT)
    np.testing.assert_allclose(read_vehicle_toml(f).T_vehicle_scanner.matrix[:3, 3], [0.6, 0.0, 0.3])


# ------------------------------------------------------------------ bags: topic map and decoder


def test_topic_map_integer_frame_id_and_shared_topic_are_one_line_errors():
    """An integer frames.vehicle_frame_id raised AttributeError; DVL and depth on one topic dropped the DVL."""
    with pytest.raises(DatasetError) as exc:
        TopicMap.from_dict({"topics": {"attitude": "/imu"}, "frames": {"vehicle_frame_id": 7}}, source="topic map 't'")
    _one_line(exc.value, "frames.vehicle_frame_id", "non-empty string", "Got 7")
    with pytest.raises(DatasetError, match="frames.vehicle_frame_id"):
        TopicMap(attitude="/imu", vehicle_frame_id="/")
    with pytest.raises(DatasetError) as exc:
        TopicMap.from_dict({"topics": {"attitude": "/imu", "dvl": "/nav/odom", "depth": "/nav/odom"}})
    _one_line(exc.value, "topics.dvl", "topics.depth", "'/nav/odom'", "one sensor per topic")
    assert TopicMap.from_dict({"topics": {"attitude": "/imu", "dvl": "/dvl"}}).dvl == "/dvl"


def _imu(w, x, y, z):
    return SimpleNamespace(orientation=SimpleNamespace(w=w, x=x, y=y, z=z))


def test_bag_decoder_refuses_an_implausible_pressure_depth_or_quaternion_naming_the_topic():
    """A pressure of 1e300 Pa raised LinAlgError in the filter; a quaternion of norm 1e300 was accepted."""
    dec = BagDecoder(TopicMap(attitude="/imu", depth="/pressure", attitude_frame="ned"), VehicleDescription.girona500())
    d = VehicleDescription.girona500().depth
    p = d.atmospheric_pressure_pa + 10.0 * d.water_density_kg_m3 * 9.80665
    assert dec.depth(SimpleNamespace(fluid_pressure=p), "sensor_msgs/msg/FluidPressure") == pytest.approx(10.0)
    for bad in (1e300, -5.0, float("inf")):
        with pytest.raises(BagError) as exc:
            dec.depth(SimpleNamespace(fluid_pressure=bad), "sensor_msgs/msg/FluidPressure")
        _one_line(exc.value, "'/pressure'", "fluid_pressure", "[0, 1.2e+08] Pa")
    pose = SimpleNamespace(pose=SimpleNamespace(position=SimpleNamespace(z=1e300)))
    with pytest.raises(BagError, match=r"'/pressure'.*depth.*\[-100, 11000\] m"):
        dec.depth(pose, "geometry_msgs/msg/PoseStamped")
    s = math.sqrt(0.5)
    np.testing.assert_allclose(dec.attitude(_imu(s, 0.0, 0.0, s)), [0.0, 0.0, math.pi / 2], atol=1e-12)
    for q in ((1e300, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), (2.0, 0.0, 0.0, 0.0)):
        with pytest.raises(BagError) as exc:
            dec.attitude(_imu(*q))
        _one_line(exc.value, "'/imu'", "quaternion's norm", "[0.9, 1.1]")


# ------------------------------------------------------------------ bounded work: stamps


def _feed(session, n=50, dt=0.1):
    for k in range(n):
        t = k * dt
        session.add_attitude(t, [0.0, 0.0, 0.0])
        session.add_dvl(t, [0.2, 0.0, 0.0])
        session.add_depth(t, 3.0)


def test_an_attitude_stamp_at_2_pow_31_s_is_an_error_not_a_hang():
    """One IMU stamp at 2^31 s made the session predict and record history up to it: memory past 1.5 GB and no
    end (SlamSession._predict_to / _history_before were bounded by the stamp, not by the data)."""
    s = SlamSession(VehicleDescription.girona500(), mode="dr")
    _feed(s)
    t = time.perf_counter()
    with pytest.raises(SlamError) as exc:
        s.add_attitude(2.0 ** 31, [0.0, 0.0, 0.0])
    assert time.perf_counter() - t < 1.0
    assert isinstance(exc.value, PlausibilityError)
    _one_line(exc.value, "attitude stamp 2147483648.0", "after 4.9", "[0, 3600] s")
    # the first attitude far after the start (a DVL sample started the session) is the same gap
    s = SlamSession(VehicleDescription.girona500(), mode="dr", start_stamp_s=0.0)
    s.add_dvl(0.0, [0.2, 0.0, 0.0])
    with pytest.raises(SlamError, match=r"after 0.0 s"):
        s.add_attitude(2.0 ** 31, [0.0, 0.0, 0.0])
    # a gap within the limit is bounded work: predicted through
    s = SlamSession(VehicleDescription.girona500(), mode="dr", config=SlamConfig().updated(smooth=False))
    _feed(s, 5)
    s.add_attitude(100.0, [0.0, 0.0, 0.0])
    assert s.finish().stamps_s[-1] == pytest.approx(100.0)


def test_an_ahrs_csv_row_at_2_pow_31_s_is_an_error_not_a_hang(tmp_path):
    from semslam.run import run_slam

    ta = np.arange(0.0, 3.0, 0.1)
    dvl = DvlLog(ta, np.tile([0.2, 0.0, 0.0], (len(ta), 1)), np.ones(len(ta), bool))
    ds = Dataset(VehicleDescription.girona500(), dvl,
                 AttitudeLog(ta, np.zeros((len(ta), 3))), DepthLog(ta, np.full(len(ta), 3.0)))
    d = write_dataset(ds, tmp_path / "m")
    lines = (d / "ahrs.csv").read_text().splitlines()
    lines[-1] = "2147483648.0," + lines[-1].split(",", 1)[1]
    (d / "ahrs.csv").write_text("\n".join(lines) + "\n")
    mission = read_dataset(d)

    def hang(signum, frame):
        raise TimeoutError("run_slam still predicting towards the 2^31 s stamp after 20 s")

    previous = signal.signal(signal.SIGALRM, hang)  # a regression fails here instead of hanging the suite
    signal.alarm(20)
    try:
        with pytest.raises(SlamError, match=r"attitude stamp 2147483648\.0.*\[0, 3600\] s"):
            run_slam(mission, mode="dr")
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def test_implausible_dvl_and_depth_samples_are_skipped_and_counted():
    """A depth of 1e300 m (or a DVL velocity of 1e300 m/s) was gated, then accepted after five in a row. Now
    skipped and counted: the run is exactly the run without those samples."""
    def run(corrupt: bool):
        s = SlamSession(VehicleDescription.girona500(), mode="dr", config=SlamConfig().updated(smooth=False),
                        initial_position_ned_m=[0.0, 0.0, 3.0], initial_velocity_body_mps=[0.2, 0.0, 0.0])
        for k in range(50):
            t = k * 0.1
            s.add_attitude(t, [0.0, 0.0, 0.0])
            bad = 20 <= k < 30
            if corrupt or not bad:
                s.add_dvl(t, [1e300, 0.0, 0.0] if bad else [0.2, 0.0, 0.0])
                s.add_depth(t, -1e300 if bad else 3.0)
        return s.finish()

    res, ref = run(True), run(False)
    assert res.metrics["skipped_implausible"] == {"dvl": 10, "depth": 10}
    assert ref.metrics["skipped_implausible"] == {"dvl": 0, "depth": 0}
    np.testing.assert_array_equal(res.position_ned_m, ref.position_ned_m)
    np.testing.assert_allclose(res.position_ned_m[-1], [0.2 * res.stamps_s[-1], 0.0, 3.0], atol=0.01)


# ------------------------------------------------------------------ the CLI: one line, exit 1


def test_cli_prints_one_line_for_an_implausible_config_vehicle_or_topic_map(tmp_path, capsys):
    from semslam.cli.main import main

    cfg = tmp_path / "slam.toml"
    cfg.write_text("[slam.output]\nhistory_rate_hz = 1e9\n")
    veh = tmp_path / "vehicle.toml"
    veh.write_text("[scanner]\nxyz_m = [600.0, 0.0, 300.0]\nrpy_rad = [0.0, 0.0, 0.0]\n")
    topics = tmp_path / "topics.toml"
    topics.write_text('[topics]\nattitude = "/imu"\n[frames]\nvehicle_frame_id = 3\n')
    cases = [
        (["slam", "synthetic:0", "--config", str(cfg), "--out", str(tmp_path / "run")],
         (str(cfg), "'history_rate_hz'", "[0.001, 100] Hz")),
        (["bag", "export", str(tmp_path / "none.bag"), "--vehicle", str(veh), "--out", str(tmp_path / "m")],
         (str(veh), "'scanner.xyz_m[0]'", "millimetres")),
        (["bag", "export", str(tmp_path / "none.bag"), "--topics", str(topics), "--out", str(tmp_path / "m")],
         (str(topics), "frames.vehicle_frame_id", "Got 3")),
    ]
    for argv, words in cases:
        assert main(argv) == 1, argv
        err = capsys.readouterr().err.strip()
        assert err.startswith("semslam: error: ") and "\n" not in err, err
        for w in words:
            assert w in err, (w, err)
    assert not (tmp_path / "run").exists() and not (tmp_path / "m").exists()


def test_a_run_longer_than_its_history_or_prediction_budget_is_refused_before_the_work(monkeypatch):
    """The work of a run grows with its span times history_rate_hz (memory) and over max_predict_dt_s (CPU):
    both are bounded (budgets lowered here to keep the test fast; the check is the same)."""
    from dataclasses import replace

    monkeypatch.setitem(LIMITS, "stamps.history_epochs", replace(LIMITS["stamps.history_epochs"], hi=100.0))
    s = SlamSession(VehicleDescription.girona500(), mode="dr", config=SlamConfig().updated(smooth=False))
    for t in range(0, 51):
        s.add_attitude(float(t), [0.0, 0.0, 0.0])  # 50 s at 2 Hz: 100 epochs, the budget
    with pytest.raises(SlamError) as exc:
        s.add_attitude(51.0, [0.0, 0.0, 0.0])
    _one_line(exc.value, "history epochs", "51.0", "history_rate_hz = 2", "[0, 100]", "Got 102.0")
    monkeypatch.setitem(LIMITS, "stamps.predict_steps", replace(LIMITS["stamps.predict_steps"], hi=1000.0))
    s = SlamSession(VehicleDescription.girona500(), mode="dr", config=SlamConfig().updated(max_predict_dt_s=0.01),
                    start_stamp_s=0.0)
    s.add_attitude(10.0, [0.0, 0.0, 0.0])  # 1000 steps: the budget
    with pytest.raises(SlamError, match=r"prediction steps.*max_predict_dt_s = 0.01.*Got 1001"):
        s.add_attitude(10.01, [0.0, 0.0, 0.0])
