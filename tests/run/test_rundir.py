"""The run directory (``semslam/run/rundir.py``): the update log, the mode folders, the trajectory CSV."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from semslam.run.rundir import UPDATES, write_run
from semslam.slam import SlamConfig
from semslam.slam.results import SlamResult


def test_update_log_rows_are_written(tmp_path: Path):
    """Catches an ``updates.csv`` that loses the update log (the loop over ``update_log`` skipped): every record is
    one row in order, floats with 6 significant digits, unknown keys ignored, missing ones empty."""
    k = 3
    cov = np.tile(np.eye(3) * 1e-4, (k, 1, 1))
    log = [dict(stamp_s=0.5, kind="dvl", accepted=True, nis=2.3456789, dof=3, threshold=21.1075, reason="nominal",
                extra="ignored"),
           dict(stamp_s=1.0, kind="landmark", accepted=False, test="pose", landmark=2, label="valve", detection=0)]
    res = SlamResult(mode="pose", stamps_s=np.arange(k) * 0.5, position_ned_m=np.zeros((k, 3)), position_cov_m2=cov,
                     velocity_body_mps=np.zeros((k, 3)), velocity_cov=cov.copy(), yaw_bias_rad=np.zeros(k),
                     truth_position_ned_m=None, landmarks=[], update_log=log, metrics={}, config=SlamConfig(),
                     attitude_rpy_rad=np.zeros((k, 3)))
    out = write_run(res, tmp_path / "run")
    rows = list(csv.DictReader((out / UPDATES).open()))
    assert len(rows) == 2
    assert rows[0]["kind"] == "dvl" and rows[0]["nis"] == "2.34568" and rows[0]["threshold"] == "21.1075"
    assert rows[0]["accepted"] == "True" and rows[0]["reason"] == "nominal" and rows[0]["landmark"] == ""
    assert "extra" not in rows[0]
    assert rows[1]["kind"] == "landmark" and rows[1]["accepted"] == "False" and rows[1]["landmark"] == "2"


def test_mode_dirs_lists_only_modes_with_a_trajectory(tmp_path: Path):
    """Catches an inverted "has a trajectory" test in ``mode_dirs``: only the per-mode directories that hold a
    trajectory file are runs ("pose+heading" lives in ``pose_heading``); an empty mode directory is not."""
    from semslam.run.rundir import TRAJECTORY, mode_dir, mode_dirs

    for mode in ("pose", "pose+heading", "dr"):
        mode_dir(tmp_path, mode).mkdir(parents=True)
    for mode in ("pose", "pose+heading"):
        (mode_dir(tmp_path, mode) / TRAJECTORY).write_text("t\n")
    found = mode_dirs(tmp_path, ["dr", "pose", "pose+heading", "position"])
    assert found == {"pose": mode_dir(tmp_path, "pose"), "pose+heading": mode_dir(tmp_path, "pose+heading")}
    assert found["pose+heading"].name == "pose_heading"


def test_trajectory_csv_carries_the_attitude_or_nan_without_it(tmp_path: Path):
    """Catches an inverted "has attitude" test in ``trajectory.csv`` (``is None`` for ``is not None``) and a wrong
    number of placeholders (``(nan,) * 4``): the roll, pitch and yaw columns hold the result's attitude per epoch
    (9 significant digits), and exactly three ``nan`` for a result without attitude."""
    from dataclasses import replace

    from semslam.run.rundir import TRAJECTORY

    k = 3
    cov = np.tile(np.eye(3) * 1e-4, (k, 1, 1))
    att = np.array([[0.1, -0.2, 0.3], [0.01, 0.02, -3.1], [0.0, 0.5, 1.25]])
    res = SlamResult(mode="pose", stamps_s=np.arange(k) * 0.5, position_ned_m=np.zeros((k, 3)), position_cov_m2=cov,
                     velocity_body_mps=np.zeros((k, 3)), velocity_cov=cov.copy(), yaw_bias_rad=np.zeros(k),
                     truth_position_ned_m=None, landmarks=[], update_log=[], metrics={}, config=SlamConfig(),
                     attitude_rpy_rad=att)
    rows = list(csv.DictReader((write_run(res, tmp_path / "a") / TRAJECTORY).open()))
    got = np.array([[float(r[c]) for c in ("roll_rad", "pitch_rad", "yaw_rad")] for r in rows])
    np.testing.assert_allclose(got, att, rtol=1e-9)
    rows = list(csv.DictReader((write_run(replace(res, attitude_rpy_rad=None), tmp_path / "b") / TRAJECTORY).open()))
    assert all(r[c] == "nan" for r in rows for c in ("roll_rad", "pitch_rad", "yaw_rad"))
    assert all(None not in r for r in rows)  # exactly one value per header column (csv.DictReader's rest key)
