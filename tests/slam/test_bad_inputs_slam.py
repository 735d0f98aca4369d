"""Bad input to the SLAM and report entry points: each raises a :class:`~semslam.errors.SemslamError` subclass
whose message names the argument (or file), what was expected and the bad value (issue 20, item 4).

Every test is seeded and small: a one-loop synthetic square mission, the Girona 500 description, tiny files.
The eleven bugs these tests found (an input escaping as a raw Python error, or a message without the file) were
fixed in the same change; the tests were strict xfails until then.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from semslam.dataset import VehicleDescription
from semslam.detection import Detection
from semslam.errors import ConfigError, InputError, ReportError, SemslamError, SlamError
from semslam.experiments.montecarlo import run_montecarlo
from semslam.simulation.synthetic import square_dataset
from semslam.geometry import RigidTransform
from semslam.report.build import build_report, load_trajectory_csv
from semslam.slam import SemanticEkf, SlamConfig, SlamSession
from semslam.io.detections import read_detections_jsonl
from semslam.run import run_slam


def _words(*words: str) -> str:
    """A regex matching every word in order (escaped), anything in between."""
    return ".*".join(re.escape(w) for w in words)


@pytest.fixture(scope="module")
def vehicle() -> VehicleDescription:
    return VehicleDescription.girona500()


@pytest.fixture(scope="module")
def dataset():
    return square_dataset(seed=0, loops=1)


# ------------------------------------------------------------------ SlamConfig


def test_from_dict_unknown_section_is_named_with_the_expected_ones():
    """Catches a typo'd section ([motoin]) being ignored silently, the settings in it lost."""
    with pytest.raises(ConfigError, match=_words("Unknown section(s) ['motoin']", "slam.toml", "'motion'")):
        SlamConfig.from_dict({"motoin": {"max_predict_dt_s": 0.1}}, source="slam.toml")


def test_from_dict_unknown_key_is_named_with_its_section():
    with pytest.raises(ConfigError, match=_words("Unknown key(s) ['motion.max_dt']", "slam.toml",
                                                 "'motion.max_predict_dt_s'")):
        SlamConfig.from_dict({"motion": {"max_dt": 0.1}}, source="slam.toml")


def test_from_dict_non_table_input_and_section():
    with pytest.raises(ConfigError, match=_words("slam.toml must be a table of SlamConfig sections", "Got list")):
        SlamConfig.from_dict([1], source="slam.toml")
    with pytest.raises(ConfigError, match=_words("The [map] section of slam.toml must be a table", "Got 3")):
        SlamConfig.from_dict({"map": 3}, source="slam.toml")


@pytest.mark.parametrize("section, key, value, words", [
    ("motion", "max_predict_dt_s", "0.1", ("'max_predict_dt_s'", "MotionConfig", "must be a number", "Got '0.1'")),
    ("motion", "max_predict_dt_s", None, ("'max_predict_dt_s'", "must be a number", "Got None")),
    ("map", "dense_max_landmarks", True, ("'dense_max_landmarks'", "MapConfig", "must be a number", "Got True")),
    ("output", "smooth", "false", ("'smooth'", "OutputConfig", "must be true or false", "Got 'false'")),
    ("output", "history_rate_hz", float("nan"), ("'history_rate_hz'", "must be finite", "Got nan")),
    ("initialisation", "initial_position_sigma_m", float("inf"), ("'initial_position_sigma_m'", "must be finite",
                                                                  "Got inf")),
    ("output", "history_rate_hz", 0, ("'history_rate_hz'", "must be > 0", "Got 0")),
    ("map", "active_radius_m", -1.0, ("'active_radius_m'", "must be > 0", "Got -1.0")),
    ("motion", "max_predict_dt_s", 0.0, ("'max_predict_dt_s'", "must be > 0", "Got 0.0")),
    ("gating", "gate_probability", 1.0, ("gate probabilities", "(0.5, 1)", "Got 1.0")),
    ("gating", "gate_probability", 0.5, ("gate probabilities", "(0.5, 1)", "Got 0.5")),
    ("gating", "sensor_gate_probability", 1.5, ("gate probabilities", "(0.5, 1)", "1.5")),
    ("initialisation", "consensus_min_observations", 0, ("'consensus_min_observations'", ">= 1", "Got 0")),
    ("map", "dense_max_landmarks", -1, ("'dense_max_landmarks'", ">= 0", "Got -1")),
    ("motion", "velocity_rw_mps_per_sqrt_s", [0.1, float("nan"), 0.1],
     ("'velocity_rw_mps_per_sqrt_s'", "three finite numbers >= 0", "nan")),
    ("motion", "velocity_rw_mps_per_sqrt_s", "0.1", ("'velocity_rw_mps_per_sqrt_s'", "a number or three", "'0.1'")),
    ("motion", "velocity_rw_mps_per_sqrt_s", True, ("'velocity_rw_mps_per_sqrt_s'", "a number or three", "True")),
    ("initialisation", "max_fix_age_s", 0.0, ("'max_fix_age_s'", "must be > 0", "0.0")),
])
def test_from_dict_bad_value_names_source_field_expectation_and_value(section, key, value, words):
    """Catches truthy strings ("false" read as True), bools taken as numbers, NaN slipping into the filter and
    non-positive scales; the message must name the file so that the CLI's one line says where to look."""
    with pytest.raises(ConfigError, match=_words("slam.toml", *words)):
        SlamConfig.from_dict({section: {key: value}}, source="slam.toml")


@pytest.mark.parametrize("key, value, words", [
    ("smooth", "false", ("'smooth'", "must be true or false", "Got 'false'")),
    ("history_rate_hz", "2", ("'history_rate_hz'", "must be a number", "Got '2'")),
    ("consensus_min_observations", True, ("'consensus_min_observations'", "must be a number", "Got True")),
    ("initial_position_sigma_m", float("nan"), ("'initial_position_sigma_m'", "must be finite", "Got nan")),
    ("sensor_gate_probability", 1.5, ("gate probabilities", "(0.5, 1)", "1.5")),
    ("candidate_radius_m", 0.0, ("'candidate_radius_m'", "must be > 0", "Got 0.0")),
    ("survey_position_sigma_m", -0.01, ("'survey_position_sigma_m'", "must be > 0", "Got -0.01")),
])
def test_updated_bad_value(key, value, words):
    with pytest.raises(ConfigError, match=_words(*words)):
        SlamConfig().updated(**{key: value})


def test_updated_unknown_setting_lists_the_known_ones():
    with pytest.raises(ConfigError, match=_words("Unknown SlamConfig setting 'smoth'", "'smooth'")):
        SlamConfig().updated(smoth=False)


def test_section_of_the_wrong_type():
    with pytest.raises(ConfigError, match=_words("'map' section of SlamConfig must be a MapConfig", "Got dict")):
        SlamConfig(map={"active_radius_m": 1.0})


@pytest.mark.parametrize("value", ["greedy", "JCBB", None, ["nn"]])
def test_association_not_nn_or_jcbb_is_named(value):
    """Catches an unknown association method falling back to a default silently."""
    with pytest.raises(SemslamError, match=_words("'association'", "'nn', 'jcbb'", f"Got {value!r}")):
        SlamConfig().updated(association=value)


def test_from_dict_bad_association_is_a_config_error_naming_the_source():
    with pytest.raises(ConfigError, match=_words("slam.toml", "'association'", "'nn', 'jcbb'", "Got 'greedy'")):
        SlamConfig.from_dict({"gating": {"association": "greedy"}}, source="slam.toml")


def test_integer_setting_rejects_a_fraction():
    with pytest.raises(ConfigError, match=_words("'consensus_min_observations'", "integer", "2.5")):
        SlamConfig().updated(consensus_min_observations=2.5)


# ------------------------------------------------------------------ SemanticEkf


def test_ekf_p0_of_the_wrong_shape():
    with pytest.raises(SlamError, match=_words("'P0_vehicle'", "SemanticEkf", "shape (6, 6)", "Got (5, 5)")):
        SemanticEkf(np.zeros(3), np.zeros(3), np.eye(5))
    # the yaw-bias state adds a row: a 6x6 prior is now one short
    with pytest.raises(SlamError, match=_words("'P0_vehicle'", "shape (7, 7)", "Got (6, 6)")):
        SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6), yaw_bias=True)


def test_ekf_indices_of_an_unknown_or_absent_block():
    """Catches an absent optional block (yaw_bias without the state) returning indices of another state."""
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6))
    with pytest.raises(SlamError, match=_words("'block'", "SemanticEkf.indices", "position, velocity",
                                               "Got 'nonsense'")):
        ekf.indices("nonsense")
    with pytest.raises(SlamError, match=_words("'block'", "position, velocity.", "Got 'yaw_bias'")):
        ekf.indices("yaw_bias")
    with_bias = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(7), yaw_bias=True)
    assert list(with_bias.indices("yaw_bias")) == [6]
    with pytest.raises(SlamError, match=_words("position, velocity, yaw_bias", "Got 'nonsense'")):
        with_bias.indices("nonsense")


def test_ekf_update_or_inflate_of_a_passive_state():
    """Catches an update silently writing into a compressed (passive) landmark, which would corrupt the map."""
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), np.eye(6))
    (lm,) = ekf.add_prior_landmarks(np.zeros((1, 6)), np.eye(6)[None] * 0.01, ["elbow"])
    assert not ekf.is_active(lm)
    idx = ekf.landmarks[lm].offset + np.arange(3)
    x_before, P_before = ekf.full_state()
    with pytest.raises(SlamError, match=_words("SemanticEkf.update touches a passive state", "set_active_landmarks")):
        ekf.update(idx, np.eye(3), np.ones(3), np.eye(3))
    with pytest.raises(SlamError, match=_words("SemanticEkf.inflate touches a passive state", "set_active_landmarks")):
        ekf.inflate(idx, np.eye(3))
    x_after, P_after = ekf.full_state()
    assert np.array_equal(x_before, x_after) and np.array_equal(P_before, P_after)


# ------------------------------------------------------------------ read_detections_jsonl


def _detection_line(**over) -> str:
    det = Detection(label="elbow", score=1.0, T_sensor_object=RigidTransform(np.eye(4)),
                    covariance_6x6=np.eye(6) * 1e-4, stamp_s=1.0, scan_id=3)
    d = det.to_dict()
    d.update(over)
    return json.dumps(d)


def test_detections_missing_file(tmp_path):
    path = tmp_path / "missing.jsonl"
    with pytest.raises(InputError, match=_words("detections file", str(path), "does not exist")):
        read_detections_jsonl(path)


def test_detections_non_json_line_names_line_and_file(tmp_path):
    path = tmp_path / "dets.jsonl"
    path.write_text(_detection_line() + "\n\n{oops\n")
    with pytest.raises(InputError, match=_words("Line 3 of", str(path), "is not JSON")):
        read_detections_jsonl(path)


@pytest.mark.parametrize("stamp", [float("nan"), None])
def test_detections_non_finite_stamp(tmp_path, stamp):
    """Catches a detection with no time being applied at t=NaN (every comparison false: never processed)."""
    path = tmp_path / "dets.jsonl"
    path.write_text(_detection_line() + "\n" + _detection_line(stamp_s=stamp) + "\n")
    with pytest.raises(InputError, match=_words("Line 2 of", str(path), "finite 'stamp_s'", "Got nan")):
        read_detections_jsonl(path)


def test_detections_empty_file_and_blank_lines(tmp_path):
    path = tmp_path / "empty.jsonl"
    path.write_text("")
    assert read_detections_jsonl(path) == {}
    path.write_text("\n  \n")
    assert read_detections_jsonl(path) == {}
    path.write_text("\n" + _detection_line() + "\n\n")
    got = read_detections_jsonl(path)
    assert list(got) == [3] and got[3][0].label == "elbow" and got[3][0].stamp_s == 1.0


def test_detections_binary_file(tmp_path):
    path = tmp_path / "dets.jsonl"
    path.write_bytes(b"\xff\xfe\x00\x81 not text\n")
    with pytest.raises(InputError, match=_words(str(path))):
        read_detections_jsonl(path)


def test_detections_malformed_record_names_line_and_file(tmp_path):
    path = tmp_path / "dets.jsonl"
    path.write_text(_detection_line() + "\n" + '{"label": "elbow"}\n')
    with pytest.raises(InputError, match=_words("Line 2", str(path), "score")):
        read_detections_jsonl(path)


# ------------------------------------------------------------------ SlamSession


def test_session_wrong_vehicle_config_and_mode(vehicle):
    with pytest.raises(SlamError, match=_words("'vehicle'", "SlamSession", "VehicleDescription", "Got str")):
        SlamSession("girona500")
    with pytest.raises(SlamError, match=_words("'config'", "SlamSession", "SlamConfig", "Got dict")):
        SlamSession(vehicle, config={"map": {}})
    with pytest.raises(InputError, match=_words("'mode'", "SlamSession", "'dr', 'position', 'pose', 'pose+heading'",
                                                "Got 'slam'")):
        SlamSession(vehicle, mode="slam")
    with pytest.raises(SlamError, match=_words("'initial_position_ned_m'", "shape (3,)", "Got (2,)")):
        SlamSession(vehicle, initial_position_ned_m=(0.0, 0.0))


@pytest.mark.parametrize("stamp", [float("nan"), float("inf")])
def test_session_non_finite_start_stamp(vehicle, stamp):
    with pytest.raises(SlamError, match=_words("'start_stamp_s'", "SlamSession", "must be finite", f"Got {stamp!r}")):
        SlamSession(vehicle, start_stamp_s=stamp)


def test_session_non_numeric_start_stamp(vehicle):
    with pytest.raises(SlamError, match=_words("'start_stamp_s'", "'abc'")):
        SlamSession(vehicle, start_stamp_s="abc")


def test_session_stamps_per_stream(vehicle):
    """Catches a stamp going backwards (or a late message) being applied at the wrong time silently."""
    s = SlamSession(vehicle, mode="dr")
    s.add_attitude(0.0, [0.0, 0.0, 0.0])
    s.add_attitude(1.0, [0.0, 0.0, 0.0])
    with pytest.raises(SlamError, match=_words("attitude stamps must not decrease", "Got 0.5 after 1.0")):
        s.add_attitude(0.5, [0.0, 0.0, 0.0])
    s.add_depth(0.9, 5.0)
    with pytest.raises(SlamError, match=_words("depth stamps must not decrease", "Got 0.8 after 0.9")):
        s.add_depth(0.8, 5.0)
    # the DVL stream's own stamps are fine, but the filter has already processed up to 0.9
    with pytest.raises(SlamError, match=_words("dvl message stamped 0.5", "processed up to 0.9")):
        s.add_dvl(0.5, [0.1, 0.0, 0.0])
    with pytest.raises(SlamError, match=_words("dvl stamp must be finite", "Got nan")):
        s.add_dvl(float("nan"), [0.1, 0.0, 0.0])
    with pytest.raises(SlamError, match=_words("dvl stamp must be a number of seconds", "Got 'x'")):
        s.add_dvl("x", [0.1, 0.0, 0.0])
    # rejected messages change nothing: the session still finishes
    assert s.finish().mode == "dr"


def test_session_finish_twice_and_messages_after_finish(vehicle):
    s = SlamSession(vehicle, mode="dr")
    s.add_attitude(0.0, [0.0, 0.0, 0.0])
    s.add_attitude(0.6, [0.0, 0.0, 0.0])
    s.finish()
    with pytest.raises(SlamError, match=_words("SlamSession.finish was already called")):
        s.finish()
    with pytest.raises(SlamError, match=_words("session is finished", "no more messages")):
        s.add_attitude(1.0, [0.0, 0.0, 0.0])


def test_session_finish_without_attitude(vehicle):
    with pytest.raises(SlamError, match=_words("no attitude sample", "needs the attitude as input")):
        SlamSession(vehicle).finish()
    s = SlamSession(vehicle)
    s.add_depth(0.0, 1.0)
    with pytest.raises(SlamError, match=_words("no attitude sample", "needs the attitude as input")):
        s.finish()


# ------------------------------------------------------------------ run_slam


def test_run_slam_not_a_dataset():
    with pytest.raises(SlamError, match=_words("'dataset'", "run_slam", "must be a Dataset", "Got str")):
        run_slam("mission/")


def test_run_slam_bad_mode(dataset):
    with pytest.raises(InputError, match=_words("'mode'", "run_slam", "'dr', 'position', 'pose', 'pose+heading'",
                                                "Got 'full'")):
        run_slam(dataset, mode="full")


def test_survey_file_errors_name_the_file_and_the_problem(tmp_path):
    """A survey file with a wrong header, a non-number or a non-positive sigma is a one-line error naming it."""
    from semslam.errors import InputError
    from semslam.slam import read_survey

    bad = tmp_path / "survey.csv"
    bad.write_text("name,label,x,y\n")
    with pytest.raises(InputError, match=_words("survey.csv", "header", "name,label,x_m,y_m,z_m")):
        read_survey(bad)
    bad.write_text("name,label,x_m,y_m,z_m,roll_rad,pitch_rad,yaw_rad\nv,valve,1,2,x,0,0,0\n")
    with pytest.raises(InputError, match=_words("survey.csv", "line 2", "numbers")):
        read_survey(bad)
    bad.write_text("name,label,x_m,y_m,z_m,roll_rad,pitch_rad,yaw_rad,position_sigma_m,rotation_sigma_rad\n"
                   "v,valve,1,2,3,0,0,0,0,0.1\n")
    with pytest.raises(InputError, match=_words("survey.csv", "line 2", "sigmas must be > 0")):
        read_survey(bad)
    with pytest.raises(InputError, match=_words("does not exist")):
        read_survey(tmp_path / "nothing.csv")


# ------------------------------------------------------------------ run_montecarlo


@pytest.mark.parametrize("n_runs, words", [(0, ("must be in [1, inf]", "Got 0")),
                                           ("3", ("must be an integer", "Got '3'")),
                                           (True, ("must be an integer", "Got True")),
                                           (2.0, ("must be an integer", "Got 2.0"))])
def test_montecarlo_bad_n_runs(n_runs, words):
    """Catches True counting as one run and "3" as three."""
    with pytest.raises(InputError, match=_words("'n_runs'", "run_montecarlo", *words)):
        run_montecarlo(n_runs, source="synthetic", loops=1)


def test_montecarlo_unknown_mode():
    with pytest.raises(SlamError, match=_words("'modes'", "run_montecarlo", "'dr', 'position', 'pose'",
                                               "Got 'slam'")):
        run_montecarlo(1, modes=("dr", "slam"), source="synthetic", loops=1)


def test_montecarlo_no_mode():
    with pytest.raises(SlamError, match=_words("'modes'")):
        run_montecarlo(1, modes=(), source="synthetic", loops=1)


# ------------------------------------------------------------------ build_report

HEAD = "stamp_s,x_m,y_m,z_m,cov_p_xx,cov_p_xy,cov_p_xz,cov_p_yy,cov_p_yz,cov_p_zz"
ROW = "0.0,0,0,0,1,0,0,1,0,1"


def _run(tmp_path, files: dict):
    run = tmp_path / "run"
    run.mkdir()
    for name, content in files.items():
        p = run / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(content) if isinstance(content, bytes) else p.write_text(content)
    return run


def test_report_missing_run_directory(tmp_path):
    with pytest.raises(ReportError, match=_words("the run directory", str(tmp_path / "nope"), "does not exist")):
        build_report(tmp_path / "nope")


def test_report_empty_run_directory(tmp_path):
    run = _run(tmp_path, {})
    with pytest.raises(ReportError, match=_words("nothing to report in", str(run), "none of the expected outputs")):
        build_report(run)
    assert not (run / "report.html").exists()


@pytest.mark.parametrize("text", [HEAD + "\n", ""])
def test_report_trajectory_without_data_rows(tmp_path, text):
    run = _run(tmp_path, {"trajectory.csv": text})
    with pytest.raises(ReportError, match=_words(str(run / "trajectory.csv"), "has no data rows")):
        build_report(run)


def test_report_trajectory_of_a_mode_without_data_rows(tmp_path):
    run = _run(tmp_path, {"slam/pose/trajectory.csv": HEAD + "\n"})
    with pytest.raises(ReportError, match=_words(str(run / "slam" / "pose" / "trajectory.csv"), "has no data rows")):
        build_report(run)


@pytest.mark.parametrize("body, words", [("0.0,abc,0,0,1,0,0,1,0,1\n", ("could not convert", "'abc'")),
                                         (ROW + "\n0.5,1\n", ("inhomogeneous",))])
def test_report_trajectory_malformed_numbers(tmp_path, body, words):
    run = _run(tmp_path, {"trajectory.csv": HEAD + "\n" + body})
    with pytest.raises(ReportError, match=_words(str(run / "trajectory.csv"), "is malformed", *words)):
        build_report(run)


def test_report_trajectory_missing_columns(tmp_path):
    run = _run(tmp_path, {"trajectory.csv": "stamp_s,x_m,y_m,z_m\n0,0,0,0\n"})
    with pytest.raises(ReportError, match=_words(str(run / "trajectory.csv"), "lacks the columns", "'cov_p_xx'",
                                                 "'cov_p_zz'")):
        build_report(run)


def test_report_malformed_metrics_json(tmp_path):
    run = _run(tmp_path, {"trajectory.csv": HEAD + "\n" + ROW + "\n", "metrics.json": "{not json"})
    with pytest.raises(ReportError, match=_words("cannot read", str(run / "metrics.json"), "Expecting property")):
        build_report(run)


def test_report_binary_metrics_json(tmp_path):
    run = _run(tmp_path, {"metrics.json": b"\xff\xfe\x81"})
    with pytest.raises(ReportError, match=_words("cannot read", str(run / "metrics.json"), "utf-8")):
        build_report(run)


def test_report_unreadable_trajectory(tmp_path):
    """The OSError branch of load_trajectory_csv (build_report only passes files that exist: called directly)."""
    with pytest.raises(ReportError, match=_words("cannot read", str(tmp_path / "missing.csv"), "No such file")):
        load_trajectory_csv(tmp_path / "missing.csv")
    with pytest.raises(ReportError, match=_words("cannot read", str(tmp_path), "Is a directory")):
        load_trajectory_csv(tmp_path)


@pytest.mark.parametrize("line, words", [("{oops", ("Expecting property",)),
                                         ('{"label": "elbow"}', ("A detection record is malformed", "score"))])
def test_report_malformed_detection_line(tmp_path, line, words):
    run = _run(tmp_path, {"dets.jsonl": line + "\n"})
    with pytest.raises(ReportError, match=_words(str(run / "dets.jsonl"), "malformed detection line", *words)):
        build_report(run)


def test_report_binary_detections_file(tmp_path):
    run = _run(tmp_path, {"dets.jsonl": b"\xff\xfe\x81\n"})
    with pytest.raises(ReportError, match=_words(str(run / "dets.jsonl"))):
        build_report(run)


def test_report_binary_trajectory(tmp_path):
    run = _run(tmp_path, {"trajectory.csv": b"\xff\xfe\x81," + HEAD.encode() + b"\n"})
    with pytest.raises(ReportError, match=_words(str(run / "trajectory.csv"))):
        build_report(run)


def test_report_trajectory_rows_shorter_than_the_header(tmp_path):
    run = _run(tmp_path, {"trajectory.csv": HEAD + "\n0,0,0,0\n0,0,0,0\n"})
    with pytest.raises(ReportError, match=_words(str(run / "trajectory.csv"))):
        build_report(run)


def test_report_trajectory_with_partial_truth_columns(tmp_path):
    run = _run(tmp_path, {"trajectory.csv": HEAD + ",truth_x_m\n" + ROW + ",0\n"})
    with pytest.raises(ReportError, match=_words(str(run / "trajectory.csv"), "truth_y_m")):
        build_report(run)


@pytest.mark.parametrize("name", ["evaluation/loo_esf_svm.json", "recognition.json", "consensus.json"])
def test_report_json_part_without_its_keys(tmp_path, name):
    run = _run(tmp_path, {name: "{}"})
    with pytest.raises(ReportError, match=_words(str(run / name))):
        build_report(run)
