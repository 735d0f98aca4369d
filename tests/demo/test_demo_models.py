"""`semslam demo --models DIR` (issue 15): the whole demo on the user's CAD models - the database is built from
them and they are the mission's objects."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from semslam.cli.main import main
from semslam.errors import SimulationError

MODELS = Path(__file__).parents[1] / "data" / "models"


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo_models") / "run"
    # the README's command: no --preset (the demo picks the one for objects resting on a floor seen by a laser)
    assert main(["demo", "--quick", "--models", str(MODELS), "--out", str(out), "--no-progress", "--seed", "1"]) == 0
    return out


def test_the_database_and_the_mission_are_the_users_models(run):
    """Catches a demo that ignores --models (the built-in database has a fourth class, reducing_socket)."""
    objects = (run / "mission" / "ground_truth" / "objects.csv").read_text()
    assert {"ball_valve", "elbow", "reducing_tee"} <= {line.split(",")[1] for line in objects.splitlines()[1:]}
    assert "reducing_socket" not in objects
    loo = json.loads((run / "evaluation" / "loo_esf_svm.json").read_text())
    assert sorted(loo["labels"]) == ["ball_valve", "elbow", "reducing_tee"]


def test_the_users_models_are_rendered_by_the_missions_laser_and_run_with_the_seabed_preset(run):
    """The database matches the sensor that looks for the parts (laser views, whole and cut by the swath's border),
    and without --preset the run's configuration is the `seabed` preset's (the demo's scene: parts resting on the
    tank's floor)."""
    from semslam.recognition import load_database

    ids = [str(v) for v in load_database(run / "db.npz").view_ids]
    assert all("_laser_hdg" in v for v in ids) and any(v.endswith("_cut") for v in ids)
    config = json.loads((run / "config.json").read_text())
    assert config["demo"]["db_sensor"] == "laser" and config["demo"]["preset"] == "seabed"
    assert config["pipeline"]["segmentation"]["max_planes"] == 2 and config["pipeline"]["border"] == "flag"


def test_the_users_parts_are_recognised_and_mapped(run):
    rec = json.loads((run / "recognition.json").read_text())["summary"]
    assert rec["n_detections"] >= 10 and rec["precision"] >= 0.95 and rec["recall"] >= 0.6
    pose = json.loads((run / "slam" / "pose" / "metrics.json").read_text())
    dr = json.loads((run / "slam" / "dr" / "metrics.json").read_text())
    assert pose["n_landmarks"] == 3 and pose["ate_rmse_m"] < dr["ate_rmse_m"]
    assert (run / "report.html").is_file()


def test_a_missing_models_folder_is_one_line(tmp_path, capsys):
    assert main(["demo", "--quick", "--models", str(tmp_path / "nope"), "--out", str(tmp_path / "o"),
                 "--no-progress"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("semslam: error:") and "nope" in err[0]


def test_simulate_mission_rejects_bad_objects():
    from semslam.simulation import simulate_dataset

    with pytest.raises(SimulationError, match="'objects' argument of simulate_dataset must be a non-empty dict"):
        simulate_dataset(objects={}, with_scans=False)


def test_a_bad_configuration_file_is_one_line_before_anything_is_written(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[pipeline]\nreject_margn = 2.0\n")
    out = tmp_path / "o"
    assert main(["demo", "--quick", "--models", str(MODELS), "--config", str(bad), "--out", str(out),
                 "--no-progress"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.toml" in err[0] and "reject_margn" in err[0]
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["bad.toml"]


@pytest.mark.parametrize("given, config, db_sensor, expected", [
    (None, None, None, "seabed"),                      # the README's `demo --models DIR`
    ("default", None, None, "default"),                # --preset wins
    (None, 'preset = "cluttered"\n', None, None),      # the file's preset wins (resolved by load_run_config)
    (None, "[pipeline]\nreject_margin = 5.0\n", None, "seabed"),  # a file naming no preset: on top of seabed
    (None, None, "kinect", None),                      # a Kinect database: the seabed preset is for laser views
])
def test_the_demo_preset_for_the_users_models(tmp_path, given, config, db_sensor, expected):
    from semslam.demo import DemoConfig, _demo_preset

    path = None
    if config is not None:
        path = tmp_path / "run.toml"
        path.write_text(config)
    cfg = DemoConfig(models_dir=str(MODELS), preset=given, config_file=None if path is None else str(path),
                     db_sensor=db_sensor)
    assert _demo_preset(cfg) == expected
    assert _demo_preset(DemoConfig(preset=given, config_file=cfg.config_file)) == given  # the built-in fittings


@pytest.mark.parametrize("text, keep, backend", [("[run]\nkeep_unreliable = true\nbackend = \"isam2\"\n", True, "isam2"),
                                                ("[run]\nseed = 1\n", False, "ekf")])
def test_the_demo_hands_the_config_files_run_options_to_the_runner(tmp_path, monkeypatch, text, keep, backend):
    """`semslam demo --config F` with `[run] keep_unreliable = true` and a backend: the unreliable detections go to
    the filter and the backend is the file's, as in `semslam run` (the demo once ignored both)."""
    from types import SimpleNamespace

    import semslam.pipeline as pipeline
    import semslam.run as run_pkg
    from semslam.demo import DemoConfig, _run_dive
    from semslam.run.config import load_run_config

    seen = {}

    class Stop(Exception):
        pass

    class FakeRecognizer:
        def __init__(self, *args, **kwargs):
            pass

        def warm_up(self):
            pass

    def fake_run_stream(dive, **kwargs):
        seen.update(kwargs)
        raise Stop

    monkeypatch.setattr(pipeline, "ScanRecognizer", FakeRecognizer)
    monkeypatch.setattr(run_pkg, "open_dive", lambda mission: mission)
    monkeypatch.setattr(run_pkg, "run_stream", fake_run_stream)
    f = tmp_path / "c.toml"
    f.write_text(text)
    with pytest.raises(Stop):
        _run_dive(SimpleNamespace(scans=[]), None, DemoConfig(), load_run_config(f), tmp_path, False, symmetries={})
    assert seen["keep_unreliable"] is keep and seen["backend"] == backend
