"""The configuration front door (semslam.run.config): presets, the file format and its one-line errors, older files,
the resolved configuration a run writes, and the commands' --config / --preset."""

from __future__ import annotations

import dataclasses

import importlib.util
import json
import math
from pathlib import Path

import pytest
import tomli_w

from semslam.errors import ConfigError
from semslam.pipeline import PipelineConfig
from semslam.pipeline.parts import PartsConfig
from semslam.run.config import CONFIG_FILE, PRESETS, RunConfig, load_run_config, write_resolved_config
from semslam.segmentation import SegmentationConfig
from semslam.slam import MODES, SlamConfig

ROOT = Path(__file__).resolve().parents[2]


def _catalogue_configs() -> dict:
    spec = importlib.util.spec_from_file_location("catalogue_bench", ROOT / "benchmarks" / "catalogue.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.CONFIGS


def test_default_preset_is_todays_defaults():
    for rc in (RunConfig(), load_run_config(), load_run_config(preset="default")):
        assert rc.preset == "default"
        assert rc.pipeline_config() == PipelineConfig()
        assert rc.slam_config() == SlamConfig()
        assert rc.run.modes == MODES and rc.run.backend == "ekf" and rc.run.seed == 0


def test_cluttered_preset_is_the_catalogue_benchmarks_best_setting():
    """catalogue_border_floor_gaps: the best-measured setting of benchmarks/catalogue.py (RESULTS.md); the preset
    and the benchmark's dict must not drift apart."""
    want = PipelineConfig(**_catalogue_configs()["catalogue_border_floor_gaps"])
    got = load_run_config(preset="cluttered").pipeline_config()
    assert got == want
    assert got != PipelineConfig()
    assert (got.verify_min_fitness, got.verify_max_visibility, got.border, got.verify_visibility_image,
            got.size_reference, got.parts, got.verify_max_plane_penetration_m) == (
        0.95, 0.15, "flag", "border", "principal", PartsConfig(view_gaps=True, max_parts=4, detected_parts=True), 0.01)
    assert load_run_config(preset="cluttered").slam_config() == SlamConfig()  # recognition only


def test_depth_camera_preset_is_the_readme_frame_recipe():
    """README: --max-range 0.5 --voxel auto --cluster-tolerance auto --max-planes 0 --up 0,-1,0 --reject-margin 1
    (origin points dropped, as the CLIs do)."""
    got = load_run_config(preset="depth-camera").pipeline_config()
    assert got.segmentation == SegmentationConfig(drop_origin=True, max_range_m=0.5, voxel_leaf_m="auto",
                                                  cluster_tolerance_m="auto", max_planes=0)
    assert got.up_scanner == (0.0, -1.0, 0.0) and got.reject_margin == 1.0
    assert got.verify_min_fitness is None and got.parts is None  # nothing of the cluttered recipe
    assert sorted(PRESETS) == ["cluttered", "default", "depth-camera", "seabed"]


def test_seabed_preset_is_cluttered_with_a_second_plane_and_upright_poses():
    """objects resting on the seabed beside structure: the cluttered recipe (no posed object more than 10 mm behind
    the plane it lies on included), a wall or slope removed as a second plane, a class failing verification followed
    by the next one, border-cut clusters searched across the object, the scan's other clusters about a cluster seen
    by the pose search, verification allowing for the laser camera's shadows, border-cut clusters tracked from the
    scan before, the pose kept upright with the AHRS's gravity (docs/configuration.md)."""
    seabed, cluttered = load_run_config(preset="seabed"), load_run_config(preset="cluttered")
    p, c = seabed.pipeline_config(), cluttered.pipeline_config()
    assert p.segmentation.max_planes == 2 and c.segmentation.max_planes == 1
    assert c.verify_max_plane_penetration_m == 0.01
    assert p.verify_next_classes == 1 and c.verify_next_classes == 0  # measured worse on the catalogue (RESULTS.md)
    assert p.pose.partial_start_step_m == 0.04 and c.pose.partial_start_step_m == 0.0  # upright search only
    assert p.pose_surroundings and not c.pose_surroundings  # not measured on the catalogue
    assert p.verify_camera_shadows and not c.verify_camera_shadows  # not measured on the catalogue
    assert p.parts.view_gaps and c.parts.view_gaps  # part gaps learnt from the views in both
    assert p.parts == c.parts and p.parts.max_parts == 4 and p.parts.detected_parts  # a gate valve's parts (catalogue)
    assert p.pose.n_candidates == 256 and c.pose.n_candidates == 96  # upright: 1296 orientations per up ranked
    assert p.track_border_cut_m == 0.03 and c.track_border_cut_m is None  # not measured on the catalogue's own
    assert dataclasses.replace(p, segmentation=c.segmentation, verify_next_classes=0, pose=c.pose,
                               pose_surroundings=False, verify_camera_shadows=False, track_border_cut_m=None) == c
    assert seabed.run.up_from_attitude and not cluttered.run.up_from_attitude


def test_a_file_overrides_its_preset_and_the_command_lines_preset_must_agree(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text('preset = "cluttered"\n[pipeline]\nreject_margin = 2.0\n[pipeline.parts]\nmax_parts = 2\n'
                 '[slam.output]\nsmooth = false\n[run]\nmodes = ["pose", "dr"]\nbackend = "isam2"\n')
    rc = load_run_config(f)
    p = rc.pipeline_config()
    assert rc.preset == "cluttered" and p.reject_margin == 2.0 and p.border == "flag"  # override + preset kept
    assert p.parts == PartsConfig(max_parts=2, view_gaps=True, detected_parts=True)  # merged into the preset's
    assert rc.slam_config() == SlamConfig().updated(smooth=False)
    assert rc.run.modes == ("pose", "dr") and rc.run.backend == "isam2"
    assert load_run_config(f, preset="cluttered") == rc
    with pytest.raises(ConfigError, match="names the preset 'cluttered', the command line 'depth-camera'"):
        load_run_config(f, preset="depth-camera")
    g = tmp_path / "g.toml"
    g.write_text("[pipeline]\nreject_margin = 2.0\n")
    assert load_run_config(g, preset="depth-camera").pipeline_config().segmentation.max_planes == 0
    with pytest.raises(ConfigError, match=r"Unknown preset 'crowded': expected one of \['cluttered'"):
        load_run_config(preset="crowded")


@pytest.mark.parametrize("text, key, words", [
    ("[pipeline]\nreject_margn = 2.0\n", "pipeline.reject_margn", "unknown key"),
    ("[slam.output]\nsmooth = \"false\"\n", "slam.output.smooth", "valid boolean"),
    ("[pipeline]\nreject_margin = true\n", "pipeline.reject_margin", "valid number"),
    ("[slam.map]\ndense_max_landmarks = 2.5\n", "slam.map.dense_max_landmarks", "valid integer"),
    ("[pipeline.segmentation]\ndistance_threshold_m = nan\n", "pipeline.segmentation.distance_threshold_m", "finite"),
    ("[pipeline]\nborder = \"cut\"\n", "pipeline.border", "'reject', 'flag', 'keep'"),
    ("[pipeline.pose]\nmin_fitness = -0.5\n", "pipeline.pose.min_fitness", "-0.5"),
    ("[slam.output]\nhistory_rate_hz = 1e9\n", "slam.output.history_rate_hz", "[0.001, 100] Hz"),
    ("[slam.motion]\nvelocity_rw_mps_per_sqrt_s = [0.1, 0.1]\n", "slam.motion.velocity_rw_mps_per_sqrt_s", "three"),
    ("[run]\nmodes = [\"pose\", \"slam\"]\n", "run.modes[1]", "'pose+heading'"),
    ("[run]\nseed = -3\n", "run.seed", "greater than or equal to 0"),
    ("[sensors]\ndvl = 1\n", "sensors", "unknown key"),
    ("preset = \"crowded\"\n", "preset", "'depth-camera'"),
])
def test_a_bad_key_type_or_value_is_one_line_naming_file_and_key(tmp_path, text, key, words):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_run_config(f)
    msg = str(info.value)
    assert "\n" not in msg and str(f) in msg and f"key {key!r}" in msg and words in msg, msg


def test_json_files_load_and_a_json_null_turns_a_presets_option_off(tmp_path):
    f = tmp_path / "c.json"
    f.write_text(json.dumps({"preset": "cluttered", "pipeline": {"parts": None, "size_tolerance": None}}))
    p = load_run_config(f).pipeline_config()
    assert p.parts is None and p.size_tolerance is None and p.verify_min_fitness == 0.95
    f.write_text(json.dumps({"pipeline": {"reject_margin": math.inf}}).replace("Infinity", "1e999"))
    with pytest.raises(ConfigError, match="pipeline.reject_margin"):
        load_run_config(f)


def test_older_config_files_still_load(tmp_path):
    slam = SlamConfig().updated(smooth=False, initial_position_sigma_m=0.02)
    pipe = PipelineConfig(reject_margin=2.0, border="keep", segmentation=SegmentationConfig(max_planes=2))
    cases = {  # file name -> (content, expected pipeline, expected slam)
        "sectioned.toml": (tomli_w.dumps({"slam": {"output": {"smooth": False}}, "pipeline": {"reject_margin": 2.0}}),
                           PipelineConfig(reject_margin=2.0), SlamConfig().updated(smooth=False)),
        "slam_run_config.json": (json.dumps(slam.to_dict()), PipelineConfig(), slam),  # `semslam slam`'s config.json
        "bare_pipeline.json": (json.dumps({k: v for k, v in pipe.to_dict().items() if v is not None}), pipe,
                               SlamConfig()),
        "detect_record.json": (json.dumps({"pipeline": pipe.to_dict(), "seed": 3, "db": "db.npz",
                                           "keep_unreliable": True, "up_from_attitude": False, "mission": "m"}),
                               pipe, SlamConfig()),
        "demo_record.json": (json.dumps({"demo": {"quick": True}, "simulator": {}, "pipeline": pipe.to_dict(),
                                         "slam": {m: slam.to_dict() for m in MODES}, "database": {}}), pipe, slam),
    }
    for name, (text, want_pipe, want_slam) in cases.items():
        f = tmp_path / name
        f.write_text(text)
        rc = load_run_config(f)
        assert rc.pipeline_config() == want_pipe, name
        assert rc.slam_config() == want_slam, name
    detect = load_run_config(tmp_path / "detect_record.json")
    assert detect.run.seed == 3 and detect.run.keep_unreliable is True


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_the_resolved_config_names_the_preset_and_loads_back_to_the_same_settings(tmp_path, preset):
    f = tmp_path / "over.toml"
    f.write_text('[pipeline]\nreject_margin = 3.0\n[slam.gating]\nassociation = "jcbb"\n[run]\nseed = 4\n')
    rc = load_run_config(f, preset=preset)
    d = rc.resolved_dict()
    assert d["preset"] == preset and d["run"]["seed"] == 4 and d["pipeline"]["reject_margin"] == 3.0
    assert len(d["pipeline"]["pose"]) == len(PipelineConfig().pose.to_dict())  # every value, nested ones too
    path = write_resolved_config(rc, tmp_path)
    assert path == tmp_path / CONFIG_FILE
    back = load_run_config(path)
    assert back == rc and back.pipeline_config() == rc.pipeline_config() and back.slam_config() == rc.slam_config()
    (tmp_path / "r.json").write_text(json.dumps(d))
    assert load_run_config(tmp_path / "r.json") == rc


def test_the_documented_file_and_preset_blocks_load_and_match_the_presets():
    """docs/configuration.md: its example file loads; the TOML shown for each preset is that preset."""
    import re
    import tomllib

    text = (ROOT / "docs" / "configuration.md").read_text()
    blocks = [tomllib.loads(b) for b in re.findall(r"```toml\n(.*?)```", text, re.S)]
    example, cluttered, seabed, depth = blocks
    assert RunConfig.from_dict(example, source="the example").run.modes == ("pose", "pose+heading")
    assert RunConfig.from_dict(cluttered).pipeline_config() == load_run_config(preset="cluttered").pipeline_config()
    # seabed is shown as what it adds to cluttered
    both = RunConfig.from_dict({"pipeline": {**cluttered["pipeline"], **seabed["pipeline"]}, "run": seabed["run"]})
    assert both.pipeline_config() == load_run_config(preset="seabed").pipeline_config()
    assert both.run == load_run_config(preset="seabed").run
    assert RunConfig.from_dict(depth).pipeline_config() == load_run_config(preset="depth-camera").pipeline_config()


def test_cli_run_with_the_cluttered_preset_writes_the_resolved_config(tmp_path, capsys):
    from semslam.cli.main import main

    mission = tmp_path / "mission"
    assert main(["simulate", "--quick", "--scan-interval", "4", "--out", str(mission), "--json"]) == 0
    over = tmp_path / "over.toml"
    over.write_text("[pipeline]\nreject_margin = 5.0\n[run]\nmodes = [\"dr\"]\n")
    run = tmp_path / "run"
    assert main(["run", str(mission), "--db", "builtin", "--out", str(run), "--preset", "cluttered",
                 "--config", str(over), "--mode", "pose", "--seed", "2", "--no-report", "--json"]) == 0
    capsys.readouterr()
    resolved = load_run_config(run / CONFIG_FILE)
    assert resolved.preset == "cluttered"
    assert resolved.pipeline_config() == PipelineConfig(**{**_catalogue_configs()["catalogue_border_floor_gaps"],
                                                           "reject_margin": 5.0})
    assert resolved.run.modes == ("pose",) and resolved.run.seed == 2  # explicit options over the file
    # the recogniser ran with it: the pipeline settings recorded beside the detections are the same
    record = json.loads((run / "detections.jsonl.config.json").read_text())
    assert PipelineConfig.from_dict(record["pipeline"]) == resolved.pipeline_config()

    bad = tmp_path / "bad.toml"
    bad.write_text("[pipeline]\nborder = true\n")
    assert main(["run", str(mission), "--db", "builtin", "--out", str(tmp_path / "run2"), "--config", str(bad)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("semslam: error: ") and "\n" not in err and str(bad) in err and "'pipeline.border'" in err
    assert not (tmp_path / "run2").exists()


def test_cli_slam_takes_its_modes_from_the_config_unless_the_command_line_names_them(tmp_path, capsys):
    import argparse

    from semslam.cli._inputs import run_config_from_args
    from semslam.cli.main import main

    cfg = tmp_path / "c.toml"
    cfg.write_text('[run]\nmodes = ["dr"]\n[slam.output]\nsmooth = false\n')
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["slam", "synthetic:3", "--out", str(a), "--config", str(cfg), "--json"]) == 0
    assert list(json.loads(capsys.readouterr().out)["metrics"]) == ["dr"]
    assert main(["slam", "synthetic:3", "--out", str(b), "--config", str(cfg), "--mode", "pose", "--json"]) == 0
    assert list(json.loads(capsys.readouterr().out)["metrics"]) == ["pose"]
    assert load_run_config(a / CONFIG_FILE).run.modes == ("dr",)
    assert load_run_config(b / CONFIG_FILE).slam_config().output.smooth is False
    assert json.loads((b / "config.json").read_text())["output"]["smooth"] is False  # the filter ran with it
    # without a config or --mode, each command keeps its own default (slam: pose; run, batch: every mode)
    bare = argparse.Namespace(config=None, preset=None, mode=None, seed=None, backend=None)
    assert run_config_from_args(bare, default_modes=("pose",)).run.modes == ("pose",)
    assert run_config_from_args(bare).run.modes == MODES
    with pytest.raises(ConfigError, match="command-line options: key 'run.seed'"):
        run_config_from_args(argparse.Namespace(config=None, preset=None, mode=None, seed=-1, backend=None))


def test_cli_batch_hands_every_dive_the_resolved_config(tmp_path, monkeypatch):
    """`semslam batch --preset/--config`: the resolved configuration travels in the dives' options (to Dask
    workers), from which process_dive rebuilds it."""
    import semslam.batch.dives as batch_mod
    from semslam.cli.main import main

    seen = {}

    class Captured(Exception):
        pass

    def fake_run_batch(dives, out, fn, *, options, **kw):
        seen.update(options)
        raise Captured

    monkeypatch.setattr(batch_mod, "run_batch", fake_run_batch)
    cfg = tmp_path / "c.toml"
    cfg.write_text("[slam.output]\nsmooth = false\n[run]\nbackend = \"isam2\"\n")
    (tmp_path / "dive").mkdir()
    with pytest.raises(Captured):
        main(["batch", str(tmp_path / "dive"), "--db", "builtin", "--out", str(tmp_path / "runs"), "--workers", "1",
              "--preset", "depth-camera", "--config", str(cfg), "--mode", "pose"])
    rc = RunConfig.from_dict(seen["config"])
    assert rc == load_run_config(cfg, preset="depth-camera").with_run(modes=("pose",))
    assert seen["modes"] == ["pose"] and seen["backend"] == "isam2" and seen["seed"] == 0


@pytest.mark.parametrize("how", ["config", "flag", "neither"])
def test_run_and_batch_hand_keep_unreliable_to_the_dive(tmp_path, monkeypatch, how):
    """`[run] keep_unreliable = true` (or `semslam run --keep-unreliable`) reaches the runner of `semslam run` and of
    each `semslam batch` dive: both once ignored it, while writing it into the run's config.toml."""
    import semslam.run.dive as dive_mod
    from semslam.cli.cmd_batch import process_dive
    from semslam.cli.main import main

    seen = []

    class Captured(Exception):
        pass

    def fake_run_dive(source, out_dir, **kw):
        seen.append(kw)
        raise Captured

    monkeypatch.setattr(dive_mod, "run_dive", fake_run_dive)
    cfg = tmp_path / "keep.toml"
    cfg.write_text("[run]\nkeep_unreliable = true\n" if how == "config" else "[run]\nseed = 1\n")
    (tmp_path / "dive").mkdir()
    args = ["run", str(tmp_path / "dive"), "--db", "builtin", "--out", str(tmp_path / "run"), "--config", str(cfg)]
    with pytest.raises(Captured):
        main(args + (["--keep-unreliable"] if how == "flag" else []))
    with pytest.raises(Captured):
        process_dive(tmp_path / "dive", tmp_path / "one", {"db": "builtin", "modes": ["dr"],
                                                           "config": load_run_config(cfg).resolved_dict()})
    assert seen[0]["keep_unreliable"] is (how != "neither")
    assert seen[1]["keep_unreliable"] is (how == "config")
    assert not (tmp_path / "run").exists()
