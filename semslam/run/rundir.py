"""The layout of a SLAM run directory, owned here: what :func:`write_run` writes, where the demo, the CLI and the
report find it.

::

    RUN/                         one mode (``semslam slam --mode pose --out RUN``), or RUN/slam/<mode>/ per mode
      trajectory.csv             online filter: stamp, position, velocity, covariances, yaw bias[, truth]
      trajectory_smoothed.csv    RTS-smoothed trajectory (when smoothed)
      landmarks.csv              the map: pose, covariance, first/last seen, errors when truth exists
      updates.csv                one row per filter decision (sensor and object updates, candidates)
      metrics.json               the run's metrics
      config.json                the SlamConfig of the run (``semslam slam --config`` reads it back)
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np

from .._atomic import atomic_write_text
from ..slam.results import SlamResult

TRAJECTORY = "trajectory.csv"
TRAJECTORY_SMOOTHED = "trajectory_smoothed.csv"
LANDMARKS = "landmarks.csv"
UPDATES = "updates.csv"
METRICS = "metrics.json"
CONFIG = "config.json"
#: where ``semslam demo`` and ``semslam slam --mode all`` put each mode's run, below the run directory
MODES_DIR = "slam"
#: detections of a run (``semslam detect``, the demo)
DETECTIONS = "detections.jsonl"


def mode_dirs(run_dir: Path, modes) -> dict[str, Path]:
    """``{mode: directory}`` of the per-mode runs found below ``run_dir`` (``RUN/slam/<mode>/``)."""
    out = {}
    for mode in modes:
        d = Path(run_dir) / MODES_DIR / mode.replace("+", "_")
        if (d / TRAJECTORY).is_file():
            out[mode] = d
    return out


def mode_dir(run_dir: Path, mode: str) -> Path:
    return Path(run_dir) / MODES_DIR / mode.replace("+", "_")


def write_run(result: SlamResult, out_dir: str | Path) -> Path:
    """Write ``trajectory.csv``, ``trajectory_smoothed.csv`` (when smoothed), ``landmarks.csv``, ``updates.csv``,
    ``metrics.json`` and ``config.json`` (each atomically) into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    head = ["stamp_s", "x_m", "y_m", "z_m", "u_mps", "v_mps", "w_mps"]
    head += [f"cov_p_{a}{b}" for a in "xyz" for b in "xyz" if a <= b] + [
        f"cov_v_{a}{b}" for a in "uvw" for b in "uvw" if a <= b
    ]
    head += ["yaw_bias_rad", "roll_rad", "pitch_rad", "yaw_rad"] + (
        ["truth_x_m", "truth_y_m", "truth_z_m"] if result.truth_position_ned_m is not None else []
    )
    w.writerow(head)
    iu = np.triu_indices(3)
    for k in range(len(result.stamps_s)):
        row = [result.stamps_s[k], *result.position_ned_m[k], *result.velocity_body_mps[k],
               *result.position_cov_m2[k][iu], *result.velocity_cov[k][iu], result.yaw_bias_rad[k],
               *(result.attitude_rpy_rad[k] if result.attitude_rpy_rad is not None else (np.nan,) * 3)]
        if result.truth_position_ned_m is not None:
            row += list(result.truth_position_ned_m[k])
        w.writerow([f"{v:.9g}" for v in row])
    atomic_write_text(out / TRAJECTORY, buf.getvalue())
    if result.smoothed_position_ned_m is not None:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["stamp_s", "x_m", "y_m", "z_m", "u_mps", "v_mps", "w_mps"]
                   + [f"cov_p_{a}{b}" for a in "xyz" for b in "xyz" if a <= b])
        for k in range(len(result.stamps_s)):
            row = [result.stamps_s[k], *result.smoothed_position_ned_m[k], *result.smoothed_velocity_body_mps[k],
                   *result.smoothed_position_cov_m2[k][iu]]
            w.writerow([f"{v:.9g}" for v in row])
        atomic_write_text(out / TRAJECTORY_SMOOTHED, buf.getvalue())

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    i6 = np.triu_indices(6)
    names = ["x", "y", "z", "roll", "pitch", "yaw"]
    w.writerow(["landmark_id", "label", "x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad", "first_seen_s",
                "last_seen_s", "n_updates", "matched_object", "position_error_m", "orientation_error_rad"]
               + [f"cov_{names[a]}_{names[b]}" for a, b in zip(*i6)])
    for lm in result.landmarks:
        w.writerow([lm.landmark_id, lm.label, *[f"{v:.9g}" for v in lm.pose_xyzrpy], f"{lm.first_seen_s:.6f}",
                    f"{lm.last_seen_s:.6f}", lm.n_updates, lm.matched_object, f"{lm.position_error_m:.6g}",
                    f"{lm.orientation_error_rad:.6g}", *[f"{v:.9g}" for v in lm.covariance_6x6[i6]]])
    atomic_write_text(out / LANDMARKS, buf.getvalue())

    cols = ["stamp_s", "kind", "accepted", "test", "nis", "dof", "threshold", "landmark", "label", "detection",
            "object_name", "reason"]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in result.update_log:
        w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    atomic_write_text(out / UPDATES, buf.getvalue())

    from .._jsonable import to_jsonable

    atomic_write_text(out / METRICS, json.dumps(to_jsonable(result.metrics), indent=2) + "\n")
    atomic_write_text(out / CONFIG, json.dumps(to_jsonable(result.config.to_dict()), indent=2) + "\n")
    return out
