"""The one exception hierarchy of semslam.

Every error that bad input can cause is a :class:`SemslamError`. Messages name the argument (or file),
what was expected and what was given, so that the CLI can print them as one line::

    The 'points_xyz_m' argument of compute_vfh must have shape (N, 3). Got (12, 4) instead.

The CLI catches :class:`SemslamError` only, prints ``semslam: error: <message>`` and exits 1; anything
else is a bug and keeps its traceback.
"""

from __future__ import annotations


class SemslamError(Exception):
    """Base class of every error semslam raises on purpose."""


class InputError(SemslamError, ValueError):
    """An argument has the wrong shape, type, range or value."""


class PcdError(SemslamError):
    """A point-cloud file (PCD, PLY, NPY) cannot be read or written. The message names the file."""


class DatabaseError(SemslamError):
    """A view database is missing, corrupted, of another version, or inconsistent."""


class SegmentationError(SemslamError):
    """Plane removal or clustering cannot run on the given cloud."""


class DescriptorError(SemslamError):
    """A descriptor (ESF, VFH, FPFH, normals) cannot be computed on the given cloud."""


class RecognitionError(SemslamError):
    """Matching or classification cannot run (empty database, unfitted classifier, ...)."""


class RegistrationError(SemslamError):
    """Alignment cannot run or did not produce a transform."""


class SimulationError(SemslamError):
    """The simulator was given an impossible configuration."""


class SlamError(SemslamError):
    """The filter was given inconsistent input (unsorted stamps, wrong sizes, ...)."""


class ConfigError(SemslamError):
    """A configuration file or value is invalid."""


class ReportError(SemslamError):
    """A run directory cannot be reported (missing outputs, wrong format)."""


class BagError(SemslamError):
    """A ROS bag cannot be read: missing or corrupt file, unknown message type, missing or mistyped topic."""


class DatasetError(SemslamError):
    """A dataset (sensor logs, vehicle description, dataset directory) is missing, malformed or inconsistent."""
