"""Ownership, not resemblance (issue 31, item 1): every command that writes leaves a foreign folder, a folder that
only looks like a semslam output, a file it was not told to overwrite, and a ``.NAME.x.tmp`` sibling it did not
create untouched, byte for byte; and no output may be, lie inside, or hold one of the command's inputs.

Every command runs through the CLI entry point in this process; the inputs are one tiny simulated mission (and its
ROS 1 bag), written once for the module, and small PCDs from tests/data."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from semslam._outdir import MARKER, is_owned
from semslam.cli.main import main

DATA = Path(__file__).parents[1] / "data"

#: folders semslam did not write: a user's, look-alikes of a run and of a mission, a run marked before ownership ids
PLANTED = {
    "foreign": {"precious.txt": "keep me", "sub/notes.md": "mine too"},
    "lookalike_run": {"config.json": "{}", "metrics.json": "{\"ate_rmse_m\": 1}", "report.html": "<html>mine</html>"},
    "lookalike_mission": {"mission.json": "{\"format_version\": 2}", "dvl.csv": "stamp_s\n"},
    "old_marker_run": {MARKER: "semslam run\n", "config.json": "{}", "metrics.json": "{}", "trajectory.csv": "t\n"},
}
FOLDERS = tuple(PLANTED)


def _snapshot(root: Path) -> dict:
    """Every entry under ``root``: relative path -> bytes (files) or None (directories)."""
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in sorted(root.rglob("*"))}


def _plant(area: Path) -> None:
    for name, files in PLANTED.items():
        for rel, text in files.items():
            (area / name / rel).parent.mkdir(parents=True, exist_ok=True)
            (area / name / rel).write_text(text)
        (area / f".{name}.x.tmp").mkdir()  # someone's staging folder: never ours to clean
        (area / f".{name}.x.tmp" / "half.csv").write_text("half")
    (area / "existing.out").write_text("a file the user keeps")
    (area / ".existing.out.x.tmp").write_text("not ours")


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """``inputs/``: a tiny mission M (no scans), its ROS 1 bag B.bag (+ companions), a scene PCD, a views folder;
    ``area/``: the planted folders and files."""
    root = tmp_path_factory.mktemp("ownership")
    inp = root / "inputs"
    inp.mkdir()
    assert main(["simulate", "--quick", "--no-scans", "--out", str(inp / "M"), "--json"]) == 0
    assert main(["simulate", "--quick", "--no-scans", "--format", "ros1", "--out", str(inp / "B.bag"), "--json"]) == 0
    shutil.copy(DATA / "real_frames" / "ball_valve_yaw000_1_crop.pcd", inp / "scene.pcd")
    shutil.copy(DATA / "io" / "src_fields.pcd", inp / "small.pcd")
    shutil.copytree(DATA / "models", inp / "models")
    (inp / "views" / "valve").mkdir(parents=True)
    shutil.copy(DATA / "io" / "src_fields.pcd", inp / "views" / "valve" / "v0.pcd")
    area = root / "area"
    area.mkdir()
    _plant(area)
    return root


def _commands(inp: Path, out: str) -> dict[str, list[str]]:
    """Every command that writes a directory, with ``out`` as its output."""
    return {
        "slam": ["slam", "synthetic:1", "--mode", "dr", "--out", out],
        "run": ["run", str(inp / "M"), "--db", "builtin", "--out", out],
        "demo": ["demo", "--quick", "--no-progress", "--out", out],
        "simulate": ["simulate", "--quick", "--no-scans", "--out", out],
        "simulate ros2-mcap": ["simulate", "--quick", "--no-scans", "--format", "ros2-mcap", "--out", out],
        "simulate ros2-sqlite3": ["simulate", "--quick", "--no-scans", "--format", "ros2-sqlite3", "--out", out],
        "bag export": ["bag", "export", str(inp / "B.bag"), "--out", out],
        "segment": ["segment", str(inp / "small.pcd"), "--out", out],
        "batch": ["batch", str(inp / "M"), "--db", "builtin", "--out", out, "--workers", "1"],
    }


def _file_commands(inp: Path, out: str) -> dict[str, list[str]]:
    """Every command that writes a file, with ``out`` as its output."""
    return {
        "recognize": ["recognize", str(inp / "small.pcd"), "--db", "builtin", "--out", out],
        "detect": ["detect", str(inp / "M"), "--db", "builtin", "--out", out],
        "register": ["register", str(inp / "scene.pcd"), str(inp / "scene.pcd"), "--up", "0,-1,0", "--out", out],
        "db build": ["db", "build", str(inp / "views"), "--out", out],
        "simulate ros1": ["simulate", "--quick", "--no-scans", "--format", "ros1", "--out", out],
    }


def _refused(argv: list[str], capsys, *needles: str) -> str:
    assert main(argv) == 1, argv
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("semslam: error:"), (argv, err)
    assert any(n in err[0] for n in needles), (argv, err)
    return err[0]


def test_every_writing_command_leaves_foreign_and_look_alike_folders_untouched(world, capsys):
    inp, area = world / "inputs", world / "area"
    before = _snapshot(area)
    for folder in FOLDERS:
        out = str(area / folder)
        for name, argv in _commands(inp, out).items():
            overwrite = [] if name == "batch" else ["--overwrite"]  # batch updates its own folder in place
            err = _refused(argv + overwrite, capsys, "remove it yourself")
            assert out in err, (name, err)
        for name, argv in _file_commands(inp, out).items():  # a folder is never replaced by a file
            _refused(argv + ["--overwrite"], capsys, "must name a file")
    ros1 = _file_commands(inp, str(area / "x.bag"))["simulate ros1"]
    (area / "x.bag.vehicle.toml").write_text("mine")  # a companion file the user keeps
    before["x.bag.vehicle.toml"] = b"mine"
    _refused(ros1, capsys, "exists")
    assert not (area / "x.bag").exists()  # refused before the bag was written
    _refused(["report", str(area / "lookalike_run")], capsys, "nothing to report")
    assert _snapshot(area) == before


def test_every_file_writing_command_keeps_an_existing_file_without_overwrite(world, capsys):
    inp, area = world / "inputs", world / "area"
    (area / "fresh.jsonl.config.json").write_text("the user's")  # detect's companion file: kept too
    before = _snapshot(area)
    for name, argv in _file_commands(inp, str(area / "existing.out")).items():
        _refused(argv, capsys, "exists: choose another, or overwrite it")
    _refused(_file_commands(inp, str(area / "fresh.jsonl"))["detect"], capsys, "exists: choose another")
    assert _snapshot(area) == before  # fresh.jsonl not written either: refused before the work
    (area / "fresh.jsonl.config.json").unlink()


def test_writing_beside_someone_elses_staging_folder_leaves_it_alone(world, capsys):
    """A complete write next to planted ``.NAME.x.tmp`` siblings: they stay, byte for byte; the command's own
    staging is gone; the output carries a valid ownership marker, and --overwrite then replaces it."""
    inp, area = world / "inputs", world / "area"
    work = world / "writes"
    work.mkdir()
    names = {"slam": "run", "simulate": "mission", "segment": "seg", "simulate ros2-mcap": "bag2"}
    files = {"register": "aligned.pcd", "simulate ros1": "b1.bag"}
    for n in list(names.values()) + list(files.values()):
        (work / f".{n}.x.tmp").mkdir()
        (work / f".{n}.x.tmp" / "half").write_text("someone's")
    planted = _snapshot(work)
    before = _snapshot(area)
    for cmd, n in names.items():
        argv = _commands(inp, str(work / n))[cmd]
        assert main(argv + ["--json"]) == 0, cmd
        assert is_owned(work / n), cmd
        if cmd != "slam":  # (tests/core/test_outdir.py replaces a slam run)
            assert main(argv + ["--json", "--overwrite"]) == 0, cmd  # an output semslam proves it wrote: replaced
    for cmd, n in files.items():
        argv = _file_commands(inp, str(work / n))[cmd]
        assert main(argv + ["--json"]) == 0, cmd
        if cmd != "register":
            assert main(argv + ["--json", "--overwrite"]) == 0, cmd
    capsys.readouterr()
    after = _snapshot(work)
    assert {k: v for k, v in after.items() if k in planted} == planted
    left = sorted(p.name for p in work.iterdir() if p.name.startswith("."))
    assert left == sorted(f".{n}.x.tmp" for n in list(names.values()) + list(files.values()))
    assert _snapshot(area) == before


def test_an_output_equal_to_inside_or_holding_an_input_is_refused(world, capsys):
    inp = world / "inputs"
    before = _snapshot(inp)
    m, bag, scene = inp / "M", inp / "B.bag", inp / "small.pcd"
    same, inside, holds = "is the input", "is inside the input", "holds the input"
    cases = [
        (["slam", str(m), "--mode", "dr", "--out", str(m), "--overwrite"], same),
        (["slam", str(m), "--mode", "dr", "--out", str(m / "run")], inside),
        (["slam", str(m), "--mode", "dr", "--out", str(inp), "--overwrite"], holds),
        (["run", str(m), "--db", "builtin", "--out", str(m / "run")], inside),
        (["run", str(bag), "--db", "builtin", "--out", str(inp), "--overwrite"], holds),
        (["bag", "export", str(bag), "--out", str(inp), "--overwrite"], holds),
        (["batch", str(m), "--db", "builtin", "--out", str(m / "runs")], inside),
        (["detect", str(m), "--db", "builtin", "--out", str(m / "detections.jsonl")], inside),
        (["recognize", str(scene), "--db", "builtin", "--out", str(scene), "--overwrite"], same),
        (["register", str(scene), str(inp / "scene.pcd"), "--out", str(scene), "--overwrite"], same),
        (["db", "build", str(inp / "views"), "--out", str(inp / "views" / "db.npz")], inside),
        (["segment", str(scene), "--out", str(inp), "--overwrite"], holds),
        (["demo", "--quick", "--models", str(inp / "models"), "--out", str(inp / "models" / "run")], inside),
        (["simulate", "--quick", "--no-scans", "--out", str(inp), "--overwrite"], "remove it yourself"),
    ]
    for argv, needle in cases:
        _refused(argv, capsys, needle)
    assert _snapshot(inp) == before


def test_montecarlo_out_follows_the_ownership_rule(tmp_path, capsys):
    """``montecarlo --out`` writes a marked directory, refuses a foreign non-empty folder before the work, and
    replaces its own earlier output only with --overwrite."""
    mc = ["montecarlo", "--runs", "1", "--mode", "dr", "--source", "synthetic", "--loops", "1", "--json"]
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    assert main([*mc, "--out", str(foreign)]) == 1
    assert "cannot prove it wrote it" in capsys.readouterr().err
    assert sorted(p.name for p in foreign.iterdir()) == ["notes.txt"] and (foreign / "notes.txt").read_text() == "mine"
    out = tmp_path / "mc"
    assert main([*mc, "--out", str(out)]) == 0
    assert is_owned(out, "montecarlo") and (out / "summary.json").is_file()
    capsys.readouterr()
    assert main([*mc, "--out", str(out)]) == 1           # an earlier Monte Carlo: only with --overwrite
    assert "overwrite" in capsys.readouterr().err
    assert main([*mc, "--out", str(out), "--overwrite"]) == 0
