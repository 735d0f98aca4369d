"""The records the recogniser's stages pass along: :class:`ScanContext` (the per-scan inputs, built once per call of
:meth:`~semslam.pipeline.scan.ScanRecognizer.recognize`: nothing of one scan is stored on the recogniser) and
:class:`ClusterOutcome` (what happened to one cluster)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validation import as_float_array, as_rng
from ..cloud import PointCloud
from ..detection import Detection
from ..errors import InputError

__all__ = ["ClusterOutcome", "ScanContext", "scan_context"]

_CALLER = "ScanRecognizer.recognize"


@dataclass(frozen=True, eq=False)
class ScanContext:
    """The inputs of one scan that every stage reads.

    Attributes
    ----------
    scan : PointCloud
        The scan in the scanner frame; ``viewpoint_xyz_m`` is the scanner's origin.
    up_scanner : (3,) tuple or None
        The up direction in the scanner frame for this scan (None: the pose search spans SO(3)).
    point_stamps_s : ndarray (N,) or None
        Acquisition time of every scan point.
    stamp_s : float
        Stamp of the detections when ``point_stamps_s`` is None.
    scan_id : int
        Copied into every detection.
    segmentation_seed, cluster_seed : int
        Seed of the segmentation; cluster ``k`` is described and posed with ``cluster_seed + k``, the opt-in stages
        draw theirs from ``cluster_seed`` too.
    measured : PointCloud or None
        The scan as measured, when ``scan`` is its deskewed copy (same points, same order): whether a cluster touches
        the scan's border is a property of the directions the scanner measured, so the border test reads it.
    """

    scan: PointCloud
    up_scanner: tuple | None
    point_stamps_s: np.ndarray | None
    stamp_s: float
    scan_id: int
    segmentation_seed: int
    cluster_seed: int
    measured: PointCloud | None = None

    @property
    def border_scan(self) -> PointCloud:
        """The cloud of the border test: the scan as measured."""
        return self.scan if self.measured is None else self.measured

    def stamp_of(self, raw_idx: np.ndarray) -> float:
        """Stamp of a detection made of the scan points ``raw_idx``: the median of their stamps, or ``stamp_s``."""
        stamps = self.point_stamps_s
        return float(np.median(stamps[raw_idx])) if stamps is not None and len(raw_idx) else self.stamp_s


def scan_context(scan: Any, *, default_up_scanner: tuple | None, seed: Any, stamp_s: float, scan_id: int,
                 point_stamps_s: Any, up_scanner: Any, measured: Any = None) -> ScanContext:
    """Check the arguments of :meth:`~semslam.pipeline.scan.ScanRecognizer.recognize` and draw the scan's seeds
    (two integers from ``seed``); ``up_scanner`` (scaled to a largest component of 1) overrides
    ``default_up_scanner`` (the configuration's)."""
    if not isinstance(scan, PointCloud):
        raise InputError(f"The 'scan' argument of {_CALLER} must be a PointCloud. "
                         f"Got {type(scan).__name__} instead.")
    up_tuple = default_up_scanner
    if up_scanner is not None:
        up = as_float_array("up_scanner", up_scanner, (3,), caller=_CALLER)
        if not np.abs(up).max() > 0:
            raise InputError(f"The 'up_scanner' argument of {_CALLER} must be a non-zero 3-vector. "
                             f"Got {up.tolist()} instead.")
        up_tuple = tuple(float(v) for v in up / np.abs(up).max())
    stamps = None
    if point_stamps_s is not None:
        stamps = as_float_array("point_stamps_s", point_stamps_s, (scan.n_points,), caller=_CALLER)
    rng = as_rng(seed, caller=_CALLER)
    seeds = rng.integers(0, 2**31 - 1, size=2)
    if measured is not None and (not isinstance(measured, PointCloud) or measured.n_points != scan.n_points):
        raise InputError(f"The 'measured' argument of {_CALLER} must be the PointCloud the scan was deskewed from "
                         f"({scan.n_points} points). Got {type(measured).__name__} "
                         f"of {getattr(measured, 'n_points', '?')} points instead.")
    return ScanContext(scan, up_tuple, stamps, stamp_s, scan_id, int(seeds[0]), int(seeds[1]), measured)


@dataclass(frozen=True, eq=False)
class ClusterOutcome:
    """What happened to one cluster: its size, the match, and the detection or why there is none.

    ``distance`` is NaN and ``nearest_label`` empty when the cluster was rejected before matching (too
    big for every class, or cut by the scan border); ``extent_m`` (3,) holds its principal extents,
    largest first (metres).
    """

    cluster_index: int
    n_points: int
    label: str
    nearest_label: str
    distance: float
    threshold: float
    detection: Detection | None
    reason: str
    touches_border: bool = False
    extent_m: tuple = (0.0, 0.0, 0.0)

    def to_dict(self) -> dict:
        return {"cluster_index": self.cluster_index, "n_points": self.n_points, "label": self.label,
                "nearest_label": self.nearest_label, "distance": self.distance, "threshold": self.threshold,
                "detected": self.detection is not None, "reason": self.reason,
                "touches_border": self.touches_border, "extent_m": [float(e) for e in self.extent_m]}
