"""Outputs never destroy what semslam did not write (semslam._outdir): a directory is replaced only with --overwrite
and only when its ownership marker proves semslam wrote it; staging folders are the process's own; a file is
replaced only with --overwrite; an output is never an input."""

from __future__ import annotations

import json
import os

import pytest

from semslam._outdir import (MARKER, check_output_dir, check_output_file, claim_output_dir, is_owned, marker_text,
                             ownership, staged_output_dir, staged_output_file)
from semslam.cli.main import main
from semslam.errors import InputError


def test_a_foreign_directory_is_never_replaced(tmp_path, capsys):
    user = tmp_path / "mine"
    (user / "sub").mkdir(parents=True)
    (user / "precious.txt").write_text("keep me")
    for argv in (["slam", "synthetic:1", "--mode", "dr", "--out", str(user), "--overwrite"],
                 ["simulate", "--quick", "--no-scans", "--out", str(user), "--overwrite"]):
        assert main(argv) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(user) in err[0] and "remove it yourself" in err[0], err
    assert (user / "precious.txt").read_text() == "keep me" and (user / "sub").is_dir()
    f = tmp_path / "a_file"
    f.write_text("x")
    with pytest.raises(InputError, match="must name a directory"):
        check_output_dir(f, overwrite=True)


def test_an_earlier_run_survives_a_failed_run_and_is_replaced_by_a_complete_one(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["slam", "synthetic:1", "--mode", "dr", "--out", str(run)]) == 0
    own = ownership(run)
    assert own is not None and own.kind == "run" and (run / "trajectory.csv").is_file()
    before = (run / "trajectory.csv").read_text()
    assert main(["slam", "synthetic:1", "--mode", "dr", "--out", str(run)]) == 1  # no --overwrite
    assert "earlier semslam run" in capsys.readouterr().err
    with pytest.raises(RuntimeError, match="killed"):
        with staged_output_dir(run, overwrite=True) as tmp:
            assert tmp.name.startswith(f".run.semslam-{os.getpid()}-") and tmp.name.endswith(".tmp")
            (tmp / "trajectory.csv").write_text("half")
            raise RuntimeError("killed")
    assert (run / "trajectory.csv").read_text() == before  # the old run is intact, its own staging gone
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    assert main(["slam", "synthetic:2", "--mode", "dr", "--out", str(run), "--overwrite"]) == 0
    assert (run / "trajectory.csv").read_text() != before
    assert ownership(run).id != own.id  # each output draws its own id


def test_a_sibling_staging_folder_it_did_not_create_is_left_alone(tmp_path):
    """Another process's (or a killed one's) staging folder, whatever its name, is not ours to remove."""
    run = tmp_path / "run"
    others = [tmp_path / ".run.abc.tmp", tmp_path / f".run.semslam-{os.getpid()}-zzz.tmp", tmp_path / ".run.x.tmp"]
    for o in others:
        o.mkdir()
        (o / "f").write_text("someone's")
    for overwrite in (False, True):
        with staged_output_dir(run, overwrite=overwrite) as tmp:
            (tmp / "a").write_text("1")
    with staged_output_file(tmp_path / "f.txt") as tmp:
        tmp.write_text("x")
    assert all((o / "f").read_text() == "someone's" for o in others)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["run", "f.txt"] + [o.name for o in others])


@pytest.mark.parametrize("content", [
    "semslam run\n",  # the fixed text of the first markers
    "",
    json.dumps({"semslam_output": 2, "kind": "run", "id": "0" * 32, "check": "0" * 64}),  # a check that does not match
    marker_text("run").replace('"semslam_output": 2', '"semslam_output": 1'),  # another version
    "\x00\xff" * 10,
])
def test_a_marker_that_does_not_prove_ownership_is_refused(tmp_path, content):
    d = tmp_path / "d"
    d.mkdir()
    (d / MARKER).write_text(content, encoding="utf-8", errors="surrogateescape")
    (d / "trajectory.csv").write_text("t")
    assert ownership(d) is None and not is_owned(d)
    with pytest.raises(InputError, match="cannot prove it wrote it.*remove it yourself"):
        check_output_dir(d, overwrite=True)


@pytest.mark.parametrize("names", [("config.json", "metrics.json", "report.html"),
                                   ("config.json", "metrics.json", "trajectory.csv"), ("mission.json",)])
def test_look_alike_directories_are_not_replaced(tmp_path, names):
    """Resemblance proves nothing: a run written before the marker existed is refused too (remove it yourself)."""
    old = tmp_path / "demo"
    old.mkdir()
    for name in names:
        (old / name).write_text("{}")
    for kind in ("run", "demo", "mission"):
        with pytest.raises(InputError, match="remove it yourself"):
            with staged_output_dir(old, overwrite=True, kind=kind):
                pass
    assert sorted(p.name for p in old.iterdir()) == sorted(names)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo"]


def test_an_output_of_another_kind_is_not_replaced(tmp_path):
    m = tmp_path / "m"
    with staged_output_dir(m, kind="mission") as tmp:
        (tmp / "mission.json").write_text("{}")
    assert is_owned(m, "mission") and not is_owned(m, "run")
    with pytest.raises(InputError, match="holds a semslam mission, not a run"):
        check_output_dir(m, overwrite=True, kind="run")
    check_output_dir(m, overwrite=True, kind="run", replaces=("run", "mission"))  # when the caller says so


def test_a_symlink_is_never_replaced(tmp_path):
    real = tmp_path / "real"
    with staged_output_dir(real) as tmp:
        (tmp / "a").write_text("1")
    link = tmp_path / "link"
    link.symlink_to(real, target_is_directory=True)
    with pytest.raises(InputError, match="symbolic link"):
        check_output_dir(link, overwrite=True)


def test_an_output_equal_to_inside_or_holding_an_input_is_refused(tmp_path):
    src = tmp_path / "mission"
    (src / "scans").mkdir(parents=True)
    (src / "a.pcd").write_text("x")
    with pytest.raises(InputError, match="is the input"):
        check_output_dir(src, overwrite=True, inputs=[src])
    with pytest.raises(InputError, match="is inside the input"):
        check_output_dir(src / "scans" / "run", overwrite=True, inputs=[src])
    with pytest.raises(InputError, match="holds the input"):
        check_output_dir(tmp_path, overwrite=True, inputs=[src / "a.pcd"])
    with pytest.raises(InputError, match="is the input"):
        check_output_file(tmp_path / "x" / ".." / "mission" / "a.pcd", overwrite=True, inputs=[src / "a.pcd"])
    os.symlink(src, tmp_path / "alias")
    with pytest.raises(InputError, match="is inside the input"):  # through a link to it too
        check_output_file(tmp_path / "alias" / "new.jsonl", overwrite=True, inputs=[src])
    check_output_dir(tmp_path / "elsewhere", overwrite=False, inputs=[src, None, "synthetic:1"])  # siblings are fine


def test_a_file_is_replaced_only_with_overwrite_and_atomically(tmp_path):
    f = tmp_path / "det.jsonl"
    with staged_output_file(f) as tmp:
        assert tmp.name == "det.jsonl" and tmp.parent.name.startswith(f".det.jsonl.semslam-{os.getpid()}-")
        tmp.write_text("one")
    with pytest.raises(InputError, match="exists: choose another, or overwrite it"):
        check_output_file(f, overwrite=False)
    with pytest.raises(RuntimeError):
        with staged_output_file(f, overwrite=True) as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed")
    assert f.read_text() == "one"
    with staged_output_file(f, overwrite=True) as tmp:
        tmp.write_text("two")
    assert f.read_text() == "two" and sorted(p.name for p in tmp_path.iterdir()) == ["det.jsonl"]
    with pytest.raises(InputError, match="must name a file to write"):
        check_output_file(tmp_path, overwrite=True)


def test_claim_output_dir_marks_a_new_folder_and_refuses_a_foreign_one(tmp_path):
    runs = claim_output_dir(tmp_path / "runs", kind="batch")
    assert is_owned(runs, "batch")
    (runs / "summary.csv").write_text("x")
    assert claim_output_dir(runs, kind="batch") == runs  # an earlier batch's folder: reused
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "summary.csv").write_text("mine")
    with pytest.raises(InputError, match="remove it yourself"):
        claim_output_dir(foreign, kind="batch")
    assert sorted(p.name for p in foreign.iterdir()) == ["summary.csv"]


def test_nothing_is_committed_after_a_ctrl_c_a_library_swallowed(tmp_path):
    """A real SIGINT through the command's handler, raised inside a finaliser (Python reports it as unraisable and
    goes on, as in a CI run whose interrupted `simulate` wrote its whole mission): the outputs staged after it are
    not swapped in, the earlier ones stay, no staging folder is left."""
    import gc
    import signal
    import sys

    from semslam._atomic import atomic_write_text
    from semslam._signals import forget_interrupts, interrupt_seen
    from semslam.cli import main as cli_main

    run, f, t = tmp_path / "run", tmp_path / "det.jsonl", tmp_path / "map.txt"
    with staged_output_dir(run) as tmp:
        (tmp / "a.txt").write_text("earlier")
    f.write_text("earlier")
    t.write_text("earlier")

    class Swallower:
        def __del__(self):
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):  # the handler runs here: its KeyboardInterrupt is lost with the finaliser
                pass

    old, old_hook = signal.signal(signal.SIGINT, cli_main._on_sigint), sys.unraisablehook
    sys.unraisablehook = lambda u: None
    try:
        Swallower()
        gc.collect()
        assert interrupt_seen()
        with pytest.raises(KeyboardInterrupt):
            with staged_output_dir(run, overwrite=True) as tmp:
                (tmp / "a.txt").write_text("after the Ctrl-C")
        with pytest.raises(KeyboardInterrupt):
            with staged_output_file(f, overwrite=True) as tmp:
                tmp.write_text("after the Ctrl-C")
        with pytest.raises(KeyboardInterrupt):
            atomic_write_text(t, "after the Ctrl-C")
    finally:
        signal.signal(signal.SIGINT, old)
        sys.unraisablehook = old_hook
        forget_interrupts()
    assert (run / "a.txt").read_text() == f.read_text() == t.read_text() == "earlier"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["det.jsonl", "map.txt", "run"]
    with staged_output_file(f, overwrite=True) as tmp:  # once forgotten (a caller's next command): committed
        tmp.write_text("next")
    assert f.read_text() == "next"
