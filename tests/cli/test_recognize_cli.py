"""``semslam recognize``: text, --json and --out JSONL on a simulated scan, the builtin database cache, errors."""

from __future__ import annotations

import json

import pytest

from semslam.cli.main import main


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from semslam.io import write_point_cloud
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset

    m = simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1)), seed=4)
    path = tmp_path_factory.mktemp("scene") / "scan.pcd"
    write_point_cloud(path, m.load_scan(17))  # the ball valve, whole, and the tank's slope
    return path


@pytest.fixture
def cache(tmp_path_factory, monkeypatch):
    d = tmp_path_factory.getbasetemp() / "semslam_cache"
    monkeypatch.setenv("SEMSLAM_CACHE_DIR", str(d))
    return d


def test_recognize_builtin_json_and_jsonl(scene, cache, tmp_path, capsys):
    out = tmp_path / "det.jsonl"
    assert main(["recognize", str(scene), "--db", "builtin", "--no-pose", "--out", str(out), "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert [d["label"] for d in payload["detections"]] == ["ball_valve"]
    assert len(list(cache.glob("builtin_db_*.npz"))) == 1  # cached for the next run
    det = payload["detections"][0]
    assert set(det["T_sensor_object"]) >= {"matrix", "xyz_m", "rpy_rad", "quat_wxyz"}
    rejected = [c for c in payload["clusters"] if not c["detected"]]
    assert rejected and all(c["label"] == "unknown" and c["reason"].startswith("rejected") for c in rejected)
    assert {"segmentation", "descriptors", "matching", "pose", "total", "load_db"} <= set(payload["timings_ms"])
    lines = out.read_text().splitlines()
    assert [json.loads(s)["label"] for s in lines] == ["ball_valve"]


def test_recognize_text_with_pose_from_a_db_file(scene, cache, tmp_path, capsys):
    from semslam.recognition import save_database
    from semslam.simulation.builtin_db import builtin_database

    db_path = save_database(builtin_database(seed=0), tmp_path / "db.npz")
    assert main(["recognize", str(scene), "--db", str(db_path), "--descriptor", "esf", "--seed", "1"]) == 0
    text = capsys.readouterr().out
    assert "ball_valve" in text and "xyz_m" in text and "quat_wxyz" in text and "T_scanner_object" in text
    assert "covariance_6x6" in text and "reliable" in text and "rejected as unknown:" in text
    assert "too big for any class" in text and "timings (ms):" in text


def test_recognize_errors(scene, tmp_path, capsys):
    """A missing database is a SemslamError: exit 1 (not merely "non-zero") and exactly one stderr line naming
    the file; an unknown --descriptor is a usage error: SystemExit 2 naming the option and the bad value.

    Catches: a missing database crashing with a traceback (exit 1 from Python too, but many lines), a usage
    error reported as exit 1, or a message that does not say which file or option is wrong."""
    assert main(["recognize", str(scene), "--db", str(tmp_path / "missing.npz")]) == 1
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("semslam: error:"), lines
    assert "missing.npz" in lines[0] and "does not exist" in lines[0]
    with pytest.raises(SystemExit) as exc:
        main(["recognize", str(scene), "--db", "builtin", "--descriptor", "fpfh"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "argument --descriptor" in err and "'fpfh'" in err


def test_recognize_config_file_is_read_and_checked(scene, cache, tmp_path, capsys):
    """--config (TOML) sets the pipeline (here: no pose, a coarser cluster tolerance); a typo or a wrong type
    is a one-line error naming the file and the key."""
    cfg = tmp_path / "pipe.toml"
    cfg.write_text('[pipeline]\nestimate_pose = false\n[pipeline.segmentation]\ncluster_tolerance_m = 0.03\n')
    assert main(["recognize", str(scene), "--db", "builtin", "--config", str(cfg), "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["detections"] and all(d["covariance_6x6"] is None or not d["reliable"] for d in payload["detections"])
    for text, words in (('[pipeline]\nestimate_poses = false\n', "estimate_poses"),
                        ('[pipeline.segmentation]\ncluster_tolerance = 0.03\n', "cluster_tolerance"),
                        ('[pipeline\n', "TOML")):
        cfg.write_text(text)
        assert main(["recognize", str(scene), "--db", "builtin", "--config", str(cfg)]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0] and str(cfg) in err[0], err


def test_out_naming_a_directory_fails_before_the_work(scene, tmp_path, capsys):
    """`--out` naming a directory raised IsADirectoryError after the whole run; now one line, at once."""
    assert main(["recognize", str(scene), "--db", "builtin", "--out", str(tmp_path)]) == 1
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and "'--out'" in lines[0] and str(tmp_path) in lines[0]


def test_up_without_a_recorded_up_direction_is_said_not_silently_ignored(scene, cache, tmp_path, capsys):
    """`--up` keeps a pose upright only for classes whose database records their up direction (`db build --fuse
    --up`, a model's most probable resting pose, or both of two tied ones); the built-in database records one for
    every class (the socket's, the others' two ways up). A database without them (an older one, views of your own
    without --up) gets a note naming the classes. Catches the option silently doing nothing."""
    import dataclasses

    from semslam.recognition import save_database
    from semslam.simulation.builtin_db import builtin_database

    assert main(["recognize", str(scene), "--db", "builtin", "--no-pose", "--up", "0,-1,0", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["notes"] == []
    db = builtin_database(seed=0)
    bare = {k: v for k, v in db.params.items() if k not in ("up_object", "up_object_tied")}
    save_database(dataclasses.replace(db, params=bare), tmp_path / "no_up.npz")
    assert main(["recognize", str(scene), "--db", str(tmp_path / "no_up.npz"), "--no-pose", "--up", "0,-1,0",
                 "--json"]) == 0
    notes = json.loads(capsys.readouterr().out)["notes"]
    assert len(notes) == 1 and notes[0].startswith("--up is not used for ball_valve, elbow, reducing_socket, "
                                                   "reducing_tee:")
    assert main(["recognize", str(scene), "--db", "builtin", "--no-pose"]) == 0
    assert "--up is not used" not in capsys.readouterr().out


@pytest.mark.parametrize("mode, expected", [("cluster", False), ("border", False), ("scene", True)])
def test_the_scene_visibility_is_computed_for_the_clusters_its_mode_names(scene, cache, mode, expected):
    """``verify_visibility_image``: "scene" checks every detection against the whole scan, "border" only those cut
    by the scan border (the ball valve of this scan is whole), "cluster" none. Catches the mode ignored."""
    from semslam.io import read_point_cloud
    from semslam.pipeline import PipelineConfig, ScanRecognizer
    from semslam.simulation.builtin_db import builtin_database

    cfg = PipelineConfig(verify_min_fitness=0.5, verify_max_visibility=0.99, border="flag",
                         verify_visibility_image=mode)
    result = ScanRecognizer(builtin_database(seed=0), cfg).recognize(read_point_cloud(scene), seed=0)
    (det,) = [d for d in result.detections if d.label == "ball_valve"]
    assert not det.extras["touches_border"]
    assert ("pose_visibility_scene" in det.extras) is expected
    if expected:
        assert 0.0 <= det.extras["pose_visibility_scene"] <= det.extras["pose_visibility"] + 1e-9


def test_recognize_pauses_the_garbage_collector_only_while_it_runs(monkeypatch, tmp_path, capsys):
    """`recognize` runs with the cyclic collector paused (its start-up is ~10^5 long-lived objects) and gives it back
    as it was, after success and after an error; other commands leave it alone."""
    import gc

    import semslam.cli.cmd_recognize as cmd

    seen = []
    monkeypatch.setattr(cmd, "run", lambda args: seen.append(gc.isenabled()) or 0)
    assert gc.isenabled()
    assert main(["recognize", "x.pcd", "--db", "builtin"]) == 0
    assert seen == [False] and gc.isenabled()
    monkeypatch.undo()
    assert main(["recognize", str(tmp_path / "missing.pcd"), "--db", "builtin"]) == 1  # an error on the way out
    assert "semslam: error" in capsys.readouterr().err and gc.isenabled()
    gc.disable()
    try:  # a caller that runs with the collector off keeps it off
        monkeypatch.setattr(cmd, "run", lambda args: 0)
        assert main(["recognize", "x.pcd", "--db", "builtin"]) == 0
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_recognize_reads_the_run_configuration_file_with_its_preset(scene, cache, tmp_path, capsys):
    """`recognize --config` is the one configuration file of `run` and `detect`: its preset is applied (it used to be
    ignored beside a [pipeline] table, and refused alone), the preset's up from the attitude is said to be unusable
    on one scan file, and a --preset that disagrees with the file's is a one-line error."""
    cfg = tmp_path / "run.toml"
    cfg.write_text('preset = "seabed"\n[pipeline]\nreject_margin = 5.0\n')
    assert main(["recognize", str(scene), "--db", "builtin", "--config", str(cfg), "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert any("up_from_attitude" in n and "--up" in n for n in payload["notes"])
    assert main(["recognize", str(scene), "--db", "builtin", "--preset", "seabed", "--up", "0,0,-1", "--json"]) == 0
    assert not any("up_from_attitude" in n for n in json.loads(capsys.readouterr().out)["notes"])
    assert main(["recognize", str(scene), "--db", "builtin", "--config", str(cfg), "--preset", "cluttered"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'seabed'" in err[0] and "'cluttered'" in err[0] and str(cfg) in err[0]
