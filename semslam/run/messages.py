"""The typed messages of a dive as the runner consumes them, in semslam's units and frames (converted at the
border by the source: a bag's ENU/FLU messages, a dataset directory's CSV rows, the simulator's arrays, live
topics). Every message carries its own stamp (s, one clock); a source yields them in stamp order.

=============  ==========================================================================================
``Attitude``   AHRS roll, pitch, yaw (rad) of the vehicle in the world NED frame
``Dvl``        bottom velocity (m/s) in the DVL frame (FRD), validity, optional per-beam slant ranges (m)
``Depth``      pressure depth (m, positive down)
``Fix``        horizontal position fix: north, east (m) in the world frame, its 2x2 covariance, its source
``Scan``       a laser scan: its cloud in the scanner frame and each point's stamp (or None)
=============  ==========================================================================================
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: processing order of messages sharing a stamp (as :func:`semslam.slam.merged_messages`)
ORDER = {"attitude": 0, "dvl": 1, "depth": 2, "fix": 3, "detections": 4, "scan": 5}


@dataclass(frozen=True, slots=True)
class Attitude:
    stamp_s: float
    rpy_rad: np.ndarray
    kind = "attitude"


@dataclass(frozen=True, slots=True)
class Dvl:
    stamp_s: float
    velocity_mps: np.ndarray
    valid: bool
    beam_range_m: np.ndarray | None = None
    kind = "dvl"


@dataclass(frozen=True, slots=True)
class Depth:
    stamp_s: float
    depth_m: float
    kind = "depth"


@dataclass(frozen=True, slots=True)
class Fix:
    stamp_s: float
    position_ne_m: np.ndarray
    covariance_ne_m2: np.ndarray
    source: str = "gps"
    kind = "fix"


@dataclass(frozen=True, slots=True)
class Scan:
    """A scan, stamped at its end (when a sensor publishes it); ``point_stamps_s`` (N,) or None."""

    stamp_s: float
    scan_id: int
    start_stamp_s: float
    end_stamp_s: float
    cloud: Any
    point_stamps_s: np.ndarray | None = None
    kind = "scan"


Message = Attitude | Dvl | Depth | Fix | Scan
