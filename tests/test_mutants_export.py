"""Tests that kill surviving mutants of ``semslam/slam/export.py`` (benchmarks/mutation.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from semslam.slam import SlamConfig
from semslam.run.export import export_run
from semslam.slam.results import SlamResult


def test_export_into_an_existing_directory(tmp_path: Path):
    """Catches ``mkdir(exist_ok=False)``: exporting into a directory that already exists (a run directory, or a
    second export of the same run) writes the files there instead of failing, and a re-export overwrites them
    with the same content."""
    k = 4
    cov = np.tile(np.diag([1e-4, 4e-4, 9e-4]), (k, 1, 1))
    res = SlamResult(mode="pose", stamps_s=np.arange(k) * 0.5, position_ned_m=np.arange(3.0 * k).reshape(k, 3),
                     position_cov_m2=cov, velocity_body_mps=np.zeros((k, 3)), velocity_cov=cov.copy(),
                     yaw_bias_rad=np.zeros(k), truth_position_ned_m=None, landmarks=[], update_log=[], metrics={},
                     config=SlamConfig(), attitude_rpy_rad=np.zeros((k, 3)))
    out = tmp_path / "run"
    out.mkdir()
    first = export_run(res, out, formats=("tum",))
    assert [p.name for p in first] == ["trajectory.tum"] and first[0].parent == out
    text = first[0].read_text()
    assert len([ln for ln in text.splitlines() if ln and not ln.startswith("#")]) == k
    again = export_run(res, out, formats=("tum",))
    assert again == first and again[0].read_text() == text


def _smoothed_result(k=4):
    cov = np.tile(np.diag([1e-4, 4e-4, 9e-4]), (k, 1, 1))
    pos = np.arange(3.0 * k).reshape(k, 3)
    return SlamResult(mode="pose", stamps_s=np.arange(k) * 0.5, position_ned_m=pos, position_cov_m2=cov,
                      velocity_body_mps=np.zeros((k, 3)), velocity_cov=cov.copy(), yaw_bias_rad=np.zeros(k),
                      truth_position_ned_m=None, landmarks=[], update_log=[], metrics={}, config=SlamConfig(),
                      attitude_rpy_rad=np.zeros((k, 3)), smoothed_position_ned_m=pos + 100.0,
                      smoothed_position_cov_m2=cov.copy())


def _kitti_positions(path: Path) -> np.ndarray:
    return np.loadtxt(path).reshape(-1, 3, 4)[:, :, 3]


def test_export_names_the_smoothed_kitti_files_after_their_content(tmp_path: Path):
    """Catches swapped KITTI file names in ``export_run`` (``'_smoothed' if not s``): ``trajectory.kitti`` holds the
    online positions and ``trajectory_smoothed.kitti`` the smoothed ones (here offset by 100 m), as documented."""
    res = _smoothed_result()
    written = export_run(res, tmp_path, formats=("kitti",), smoothed=True)
    names = sorted(p.name for p in written)
    assert names == ["trajectory.kitti", "trajectory.times.txt", "trajectory_smoothed.kitti",
                     "trajectory_smoothed.times.txt"]
    np.testing.assert_allclose(_kitti_positions(tmp_path / "trajectory.kitti"), res.position_ned_m, atol=1e-9)
    np.testing.assert_allclose(_kitti_positions(tmp_path / "trajectory_smoothed.kitti"), res.smoothed_position_ned_m,
                               atol=1e-9)


def test_tum_header_names_the_body_frame_of_the_world_frame(tmp_path: Path):
    """Catches an inverted body-frame label in the TUM header (``"FLU" if not frame == "enu"``): NED files are
    ``T_world_vehicle`` with an FRD body, ENU files with an FLU body (the module's frame convention)."""
    from semslam.run.export import write_tum

    res = _smoothed_result()
    ned = write_tum(res, tmp_path / "ned.tum").read_text().splitlines()[0]
    enu = write_tum(res, tmp_path / "enu.tum", frame="enu").read_text().splitlines()[0]
    assert "world NED, body FRD" in ned
    assert "world ENU, body FLU" in enu


def test_write_kitti_takes_its_paths_by_keyword_and_its_options_by_keyword_only(tmp_path: Path):
    """Catches a positional-only marker (``/``) in place of the keyword-only one (``*``) in ``write_kitti``'s
    signature: ``path`` may be given by name, and ``smoothed`` / ``frame`` must not be accepted positionally (a
    stray positional ``True`` would silently export the smoothed trajectory)."""
    import pytest

    from semslam.run.export import write_kitti

    res = _smoothed_result()
    poses, times = write_kitti(result=res, path=tmp_path / "a.kitti")
    assert poses.name == "a.kitti" and times.name == "a.times.txt"
    with pytest.raises(TypeError):
        write_kitti(res, tmp_path / "b.kitti", True)


def test_a_non_path_is_an_input_error_naming_the_argument(tmp_path: Path):
    """Catches a ``TypeError`` escaping the path check (its ``except TypeError`` never taken): a number given as
    the output path is an ``InputError`` naming the argument and the function."""
    import pytest

    from semslam.errors import InputError
    from semslam.run.export import write_kitti, write_tum

    res = _smoothed_result()
    with pytest.raises(InputError, match="The 'path' argument of write_tum must be a file path"):
        write_tum(res, 3)
    with pytest.raises(InputError, match="The 'times_path' argument of write_kitti must be a file path"):
        write_kitti(res, tmp_path / "a.kitti", times_path=3.5)


def test_export_creates_missing_parent_directories(tmp_path: Path):
    """Catches ``mkdir(parents=False)`` in ``export_run``: an output directory several levels below an existing one
    is created with its parents, and the files land in it."""
    out = tmp_path / "a" / "b" / "run"
    written = export_run(_smoothed_result(), out, formats=("tum",))
    assert [p.parent for p in written] == [out, out] and all(p.is_file() for p in written)
