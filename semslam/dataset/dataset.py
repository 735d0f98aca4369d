"""A dive as semslam consumes it: the vehicle description, navigation logs, scans and optional ground truth.

:class:`Dataset` is the data contract between every producer (the simulator, a dataset directory, a ROS bag,
numpy arrays) and every consumer (:func:`semslam.pipeline.dataset_detection.detect_dataset`,
:class:`semslam.slam.SlamSession`,
:func:`semslam.run.run_slam`). Build one in Python from arrays::

    from semslam.dataset import Dataset, DvlLog, AttitudeLog, DepthLog, VehicleDescription
    ds = Dataset(VehicleDescription.girona500(), DvlLog(t, v, valid), AttitudeLog(t_a, rpy), DepthLog(t_d, z))
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DatasetError, PcdError
from ..cloud import POINT_TIME_FIELDS
from ..geodesy import GeodeticOrigin
from .logs import AttitudeLog, DepthLog, DvlLog, ObjectTruth, PositionFixLog, ScanRecord, VehicleTruth
from .vehicle import VehicleDescription



@dataclass(frozen=True, eq=False)
class Dataset:
    """A whole dive. ``directory`` is where it was read from (None in memory); ``metadata`` is free-form
    provenance (a simulator's settings, a bag's name) that no algorithm reads; ``scan_clouds`` holds in-memory
    scans (scan_id -> PointCloud) when there is no directory to read them from.

    ``fixes`` are the vehicle's own position fixes (GPS, USBL) in the world frame, which is local NED about
    ``geodetic_origin`` when one is stated. ``truth`` and ``objects`` are ground truth: only evaluation reads them,
    after a run (the estimate of a dive is the same with or without them)."""

    vehicle: VehicleDescription
    dvl: DvlLog
    attitude: AttitudeLog
    depth: DepthLog
    truth: VehicleTruth | None = None
    objects: list[ObjectTruth] = field(default_factory=list)
    scans: list[ScanRecord] = field(default_factory=list)
    metadata: dict = field(default_factory=dict)
    directory: Path | None = None
    seed: int | None = None
    scan_clouds: dict | None = None
    fixes: PositionFixLog | None = None
    geodetic_origin: GeodeticOrigin | None = None

    def __post_init__(self) -> None:
        for name, cls in (("vehicle", VehicleDescription), ("dvl", DvlLog), ("attitude", AttitudeLog),
                          ("depth", DepthLog)):
            if not isinstance(getattr(self, name), cls):
                raise DatasetError(f"The {name!r} argument of Dataset must be a {cls.__name__}. Got "
                                   f"{type(getattr(self, name)).__name__} instead.")
        if self.fixes is not None and not isinstance(self.fixes, PositionFixLog):
            raise DatasetError(f"The 'fixes' argument of Dataset must be a PositionFixLog or None. Got "
                               f"{type(self.fixes).__name__} instead.")
        if self.geodetic_origin is not None and not isinstance(self.geodetic_origin, GeodeticOrigin):
            raise DatasetError(f"The 'geodetic_origin' argument of Dataset must be a GeodeticOrigin or None. Got "
                               f"{type(self.geodetic_origin).__name__} instead.")
        if self.truth is not None and not isinstance(self.truth, VehicleTruth):
            raise DatasetError(f"The 'truth' argument of Dataset must be a VehicleTruth or None. Got "
                               f"{type(self.truth).__name__} instead.")
        ids = [s.scan_id for s in self.scans]
        if len(set(ids)) != len(ids):
            raise DatasetError("The 'scans' argument of Dataset must have unique scan ids.")
        beams = self.dvl.beam_range_m
        n_az = len(self.vehicle.dvl.beam_azimuth_rad)
        if beams is not None and beams.shape[1] != n_az:
            raise DatasetError(f"The DVL log has {beams.shape[1]} beam ranges per row but the vehicle description "
                               f"has {n_az} beam azimuths.")

    @property
    def duration_s(self) -> float:
        stamps = [s for s in (self.dvl.stamp_s, self.attitude.stamp_s, self.depth.stamp_s) if len(s)]
        if not stamps:
            return 0.0
        return max(float(s[-1]) for s in stamps) - min(float(s[0]) for s in stamps)

    # -- scans -------------------------------------------------------------------------------------
    def scan_record(self, scan_id: int) -> ScanRecord:
        rec = next((s for s in self.scans if s.scan_id == scan_id), None)
        if rec is None:
            raise DatasetError(f"The 'scan_id' argument of Dataset.load_scan must be one of the dataset's scan ids. "
                               f"Got {scan_id!r} instead.")
        return rec

    def load_scan(self, scan_id: int):
        """The cloud of scan ``scan_id``: from memory when held, else read from ``directory / record.path``
        with :func:`semslam.io.read_point_cloud` (frame ``"scanner"``)."""
        if self.scan_clouds is not None and scan_id in self.scan_clouds:
            return self.scan_clouds[scan_id]
        record = self.scan_record(scan_id)
        if self.directory is None:
            raise DatasetError(f"Scan {scan_id} is not in memory and the dataset has no directory to read it from.")
        from ..io import read_point_cloud

        path = Path(self.directory) / record.path
        try:
            return read_point_cloud(path, frame_id="scanner")
        except PcdError as exc:
            raise DatasetError(
                f"Scan {scan_id} of the dataset in {str(self.directory)!r} cannot be read: {exc}"
            ) from None

    def point_stamps_s(self, record: ScanRecord, cloud: Any) -> np.ndarray | None:
        """Acquisition stamp (s) of every point of a scan: from a per-point time field (seconds from the
        scan's start), else from the ``line`` field and the scanner's ``line_count`` (line k at ``start + k
        (end - start) / (line_count - 1)``); None when the scan carries neither (every point at its end)."""
        for name in POINT_TIME_FIELDS:
            if name in cloud.fields:
                return record.start_stamp_s + np.asarray(cloud.fields[name], dtype=float)
        n_lines = self.vehicle.scanner.line_count
        if "line" not in cloud.fields or n_lines < 2:
            return None
        line = np.asarray(cloud.fields["line"], dtype=float)
        step = (record.end_stamp_s - record.start_stamp_s) / (n_lines - 1)
        return record.start_stamp_s + line * step


