"""Reading a run directory's files for the report: JSON, CSV rows and SLAM trajectories (a file that cannot be
read is a one-line :class:`~semslam.errors.ReportError` naming it)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from ..errors import ReportError
from ..modes import MODES

MODE_ORDER = MODES


def _load_json(path: Path) -> dict | None:
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ReportError(f"cannot read {path}: {exc}") from None



def load_trajectory_csv(path: Path) -> dict:
    """Read a ``trajectory.csv`` written by :func:`semslam.run.dataset_loop.write_run`."""
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise ReportError(f"cannot read {path}: {exc}") from None
    if len(rows) < 2:
        raise ReportError(f"{path} has no data rows")
    head = rows[0]
    try:
        data = np.array(rows[1:], dtype=float)
    except ValueError as exc:
        raise ReportError(f"{path} is malformed: {exc}") from None
    if data.ndim != 2 or data.shape[1] != len(rows[0]):
        raise ReportError(f"{path} is malformed: rows of {data.shape[-1] if data.ndim == 2 else '?'} values under a "
                          f"header of {len(rows[0])} columns")
    col = {name: i for i, name in enumerate(head)}
    need = ["stamp_s", "x_m", "y_m", "z_m"] + [f"cov_p_{a}{b}" for a, b in ("xx", "xy", "xz", "yy", "yz", "zz")]
    missing = [n for n in need if n not in col]
    if missing:
        raise ReportError(f"{path} lacks the columns {missing}")
    cov = np.zeros((len(data), 3, 3))
    for a, i in zip("xyz", range(3)):
        for b, j in zip("xyz", range(3)):
            key = f"cov_p_{a}{b}" if i <= j else f"cov_p_{b}{a}"
            cov[:, i, j] = data[:, col[key]]
    out = {"stamp_s": data[:, col["stamp_s"]], "position_ned_m": data[:, [col["x_m"], col["y_m"], col["z_m"]]],
           "position_cov": cov}
    truth_cols = [c for c in ("truth_x_m", "truth_y_m", "truth_z_m") if c in col]
    if truth_cols and len(truth_cols) != 3:
        raise ReportError(
            f"{path} lacks the columns {sorted({'truth_x_m', 'truth_y_m', 'truth_z_m'} - set(truth_cols))}"
        )
    if truth_cols:
        out["truth_position_ned_m"] = data[:, [col["truth_x_m"], col["truth_y_m"], col["truth_z_m"]]]
    if "yaw_bias_rad" in col:
        out["yaw_bias_rad"] = data[:, col["yaw_bias_rad"]]
    return out



def _load_csv_dicts(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))
