"""Outputs never destroy what semslam did not write (semslam._outdir): a foreign directory is refused even with
--overwrite, an earlier run is replaced only with --overwrite and only once the new one is complete."""

from __future__ import annotations

import pytest

from semslam._outdir import MARKER, check_output_dir, staged_output_dir
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
        assert len(err) == 1 and str(user) in err[0] and "not write" in err[0], err
    assert (user / "precious.txt").read_text() == "keep me" and (user / "sub").is_dir()
    f = tmp_path / "a_file"
    f.write_text("x")
    with pytest.raises(InputError, match="must name a directory"):
        check_output_dir(f, overwrite=True)


def test_an_earlier_run_survives_a_failed_run_and_is_replaced_by_a_complete_one(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["slam", "synthetic:1", "--mode", "dr", "--out", str(run)]) == 0
    assert (run / MARKER).is_file() and (run / "trajectory.csv").is_file()
    before = (run / "trajectory.csv").read_text()
    assert main(["slam", "synthetic:1", "--mode", "dr", "--out", str(run)]) == 1  # no --overwrite
    assert "earlier semslam run" in capsys.readouterr().err
    with pytest.raises(RuntimeError, match="killed"):
        with staged_output_dir(run, overwrite=True) as tmp:
            (tmp / "trajectory.csv").write_text("half")
            raise RuntimeError("killed")
    assert (run / "trajectory.csv").read_text() == before  # the old run is intact, no temporary left
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".run.")]
    assert main(["slam", "synthetic:2", "--mode", "dr", "--out", str(run), "--overwrite"]) == 0
    assert (run / "trajectory.csv").read_text() != before and (run / MARKER).is_file()
    stale = tmp_path / ".run.abc.tmp"
    stale.mkdir()
    assert main(["slam", "synthetic:2", "--mode", "dr", "--out", str(run), "--overwrite"]) == 0
    assert not stale.exists()  # a killed run's leftovers are cleaned by the next run into the same place


def test_a_run_written_before_the_marker_is_still_replaced(tmp_path):
    """`make demo` after an upgrade: runs/demo of semslam 0.1 has no marker but is recognisably a semslam run."""
    old = tmp_path / "demo"
    old.mkdir()
    for name in ("config.json", "metrics.json", "report.html"):
        (old / name).write_text("{}")
    with staged_output_dir(old, overwrite=True) as tmp:
        (tmp / "report.html").write_text("new")
    assert (old / "report.html").read_text() == "new" and (old / MARKER).is_file()
    (old / MARKER).unlink()  # report.html alone, no marker: not recognisably ours, refused
    with pytest.raises(InputError, match="not written by semslam"):
        check_output_dir(old, overwrite=True)
