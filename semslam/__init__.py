"""semslam: object-level (semantic) SLAM for underwater vehicles.

Recognise known objects in laser scans (ESF / VFH descriptors as in PCL), estimate their 6-DoF pose,
and use them as landmarks in a semantic EKF-SLAM. See README.md for a tour and its architecture section for the
packages (the core types: :class:`semslam.cloud.PointCloud`, :class:`semslam.detection.Detection`,
:class:`semslam.geometry.RigidTransform`, :class:`semslam.errors.SemslamError`).

Importing the package loads nothing else: the ``semslam`` command starts (and answers a Ctrl-C) at once.
"""

#: the one place the version is written (pyproject.toml reads it from here)
__version__ = "0.1.0"

__all__ = ["__version__"]
