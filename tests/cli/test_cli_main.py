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


def test_the_cli_mode_choices_are_the_filter_modes():
    """The CLI offers exactly the filter's modes (both read semslam.modes), plus "all"."""
    from semslam.cli.cmd_slam import MODE_CHOICES
    from semslam.slam import MODES

    assert MODE_CHOICES == (*MODES, "all")


def test_building_the_parser_does_not_import_the_slam_package():
    """Every command builds the whole parser: it must not pay for numba kernels it does not run."""
    import subprocess
    import sys

    code = "import sys; from semslam.cli.main import build_parser; build_parser(); print('semslam.slam' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "False", out.stderr[-2000:]
