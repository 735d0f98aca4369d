"""Tests that kill surviving mutants of ``semslam/slam/export.py`` (benchmarks/mutation.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from semslam.slam import SlamConfig
from semslam.slam.export import export_run
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
