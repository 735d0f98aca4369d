"""The command-line skeleton: version, help, one-line errors, exit codes."""

from __future__ import annotations

import subprocess
import sys

import pytest

from semslam import __version__
from semslam.cli.main import main


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert __version__ in capsys.readouterr().out


def test_no_command_prints_help_and_fails(capsys):
    assert main([]) == 2
    assert "usage: semslam" in capsys.readouterr().out


def test_unknown_command_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["no-such-command"])
    assert exc.value.code == 2


def test_semslam_error_is_one_line_and_exit_1(tmp_path):
    missing = tmp_path / "missing.pcd"
    proc = subprocess.run([sys.executable, "-m", "semslam.cli.main", "info", str(missing)],
                          capture_output=True, text=True)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("semslam: error:") and "missing.pcd" in lines[0]
    assert "Traceback" not in proc.stderr
