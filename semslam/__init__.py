"""semslam: object-level (semantic) SLAM for underwater vehicles.

Recognise known objects in laser scans (ESF / VFH descriptors as in PCL), estimate their 6-DoF pose,
and use them as landmarks in a semantic EKF-SLAM. See README.md for a tour.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version as _version

from .cloud import PointCloud
from .detection import Detection
from .errors import SemslamError
from .geometry import RigidTransform

try:
    __version__ = _version("semslam")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"

__all__ = ["Detection", "PointCloud", "RigidTransform", "SemslamError", "__version__"]
