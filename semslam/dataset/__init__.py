"""semslam.dataset: the data contract of a dive, independent of where it came from.

A :class:`Dataset` holds a :class:`VehicleDescription` (mounting and sensor figures, from a TOML file), the
navigation logs (:class:`DvlLog`, :class:`AttitudeLog`, :class:`DepthLog`), the scans (:class:`ScanRecord`) and
optional ground truth (:class:`VehicleTruth`, :class:`ObjectTruth`). A dataset directory is one on-disk form
(:func:`read_dataset`, :func:`write_dataset`); the simulator and the ROS-bag reader are producers of it.
"""

from .dataset import Dataset
from .logs import (AttitudeLog, DepthLog, DvlLog, ObjectTruth, PositionFixLog, ScanRecord, VehicleTruth,
                   check_stamps)
from .directory import FORMAT_VERSION, read_dataset, vehicle_from_simulator_dict, write_dataset
from .vehicle import (
    AttitudeSpec,
    DepthSpec,
    DvlSpec,
    ScannerSpec,
    VehicleDescription,
    read_vehicle_toml,
    write_vehicle_toml,
)

__all__ = [
    "Dataset", "AttitudeLog", "DepthLog", "DvlLog", "PositionFixLog", "ObjectTruth", "ScanRecord",
    "VehicleTruth", "check_stamps", "FORMAT_VERSION", "read_dataset", "vehicle_from_simulator_dict", "write_dataset",
    "AttitudeSpec", "DepthSpec", "DvlSpec", "ScannerSpec", "VehicleDescription", "read_vehicle_toml",
    "write_vehicle_toml",
]
