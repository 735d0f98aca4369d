"""semslam.simulation: the simulator (object meshes, Kinect view database, CIRS-like tank, laser
scanner, vehicle motion, navigation sensors) and the mission types and directory format."""

from .catalogue import CATALOGUE_LABELS, catalogue_objects
from .config import (
                     AhrsConfig,
                     DepthConfig,
                     DvlConfig,
                     KinectConfig,
                     ScannerConfig,
                     SimulatorConfig,
                     TrajectoryConfig,
                     WorldConfig,
)
from .kinect import acquire_views, builtin_view_clouds, kinect_view
from ..dataset import AhrsLog, AttitudeLog, DepthLog, DvlLog, Mission, ObjectTruth, ScanRecord, VehicleTruth
from ..dataset import read_mission, write_mission
from .objects import BUILTIN_LABELS, ObjectModel, builtin_objects, load_object, make_object
from .scanner import LaserScanner, ScanResult
from .simulate import MISSION_FORMAT_VERSION, simulate_mission
from .trajectory import Trajectory, TrajectorySample
from .world import World, build_world, floor_depth_m

__all__ = [
                     "BUILTIN_LABELS",
                     "CATALOGUE_LABELS",
                     "MISSION_FORMAT_VERSION",
                     "AhrsConfig",
                     "AhrsLog",
                     "DepthConfig",
                     "DepthLog",
                     "DvlConfig",
                     "DvlLog",
                     "KinectConfig",
                     "LaserScanner",
                     "Mission",
                     "ObjectModel",
                     "ObjectTruth",
                     "ScanRecord",
                     "ScanResult",
                     "ScannerConfig",
                     "SimulatorConfig",
                     "Trajectory",
                     "TrajectoryConfig",
                     "TrajectorySample",
                     "VehicleTruth",
                     "World",
                     "WorldConfig",
                     "acquire_views",
                     "build_world",
                     "builtin_objects",
                     "builtin_view_clouds",
                     "catalogue_objects",
                     "floor_depth_m",
                     "kinect_view",
                     "load_object",
                     "make_object",
                     "read_mission",
                     "simulate_mission",
                     "write_mission",
]
