"""semslam.simulation: the simulator (object meshes, Kinect view database, CIRS-like tank, laser
scanner, vehicle motion, navigation sensors) writing datasets (and, through :mod:`semslam.io.ros`, bags). The data
types are :mod:`semslam.dataset`."""

from .._signals import critical

with critical():  # trimesh imports its optional native readers (cascadio: OpenCASCADE): not to be cut by a Ctrl-C
    import trimesh  # noqa: F401

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
from .objects import BUILTIN_LABELS, ObjectModel, builtin_objects, load_object, make_object
from .scanner import LaserScanner, ScanResult
from .simulate import simulate_dataset, simulate_scans
from .trajectory import Trajectory, TrajectorySample
from .world import World, build_world, floor_depth_m

__all__ = [
                     "BUILTIN_LABELS",
                     "CATALOGUE_LABELS",
                     "AhrsConfig",
                     "DepthConfig",
                     "DvlConfig",
                     "KinectConfig",
                     "LaserScanner",
                     "ObjectModel",
                     "ScanResult",
                     "ScannerConfig",
                     "SimulatorConfig",
                     "Trajectory",
                     "TrajectoryConfig",
                     "TrajectorySample",
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
                     "simulate_dataset", "simulate_scans",
]
