"""Orchestration: world + trajectory + navigation sensors + laser scans -> :class:`~semslam.dataset.Dataset`.

Randomness: one :class:`numpy.random.SeedSequence` from ``seed`` is split into independent streams for
the world, the trajectory, the DVL, the AHRS, the depth sensor and the scanner, so that turning scans
off (``with_scans=False``) or changing one sensor's settings leaves the other streams unchanged.

Scans: a scan lasts ``1 / scan_rate_hz`` and one starts every ``scan_interval_s``; with
``only_when_objects_in_view`` a scan is kept only when an object's centre is inside the laser's
footprint at the scan's mid stamp (the default mission: ~100-150 scans).
"""

from __future__ import annotations

from typing import Any, Iterator

import numpy as np

from .._progress import progress_steps
from .._validation import check_positive
from ..errors import SimulationError
from ..geometry import RigidTransform
from ._ray_kernels import RayCaster
from .config import SimulatorConfig
from ..dataset import Dataset, ScanRecord, VehicleTruth, vehicle_from_simulator_dict
from .objects import ObjectModel, builtin_objects
from .scanner import LaserScanner
from .sensors import sensor_stamps, simulate_ahrs, simulate_depth, simulate_dvl, simulate_fixes
from .trajectory import Trajectory
from .world import World, build_world

#: Time between scan starts (s); a scan lasts 1 / scan_rate_hz.
DEFAULT_SCAN_INTERVAL_S = 0.5

_STREAMS = ("world", "trajectory", "dvl", "ahrs", "depth", "scanner", "fixes")


def _streams(seed: int) -> dict[str, np.random.Generator]:
    children = np.random.SeedSequence(seed).spawn(len(_STREAMS))
    return {name: np.random.default_rng(child) for name, child in zip(_STREAMS, children)}


def _check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SimulationError(
            f"The 'seed' argument of simulate_dataset must be a non-negative integer. Got {seed!r} instead."
        )
    return int(seed)


def mission_trajectory(world: World, config: SimulatorConfig, rng: np.random.Generator) -> Trajectory:
    """The square through the four fittings' corners (nominal positions, before jitter)."""
    cn, ce = config.world.objects_centre_ne_m
    h = config.world.object_spacing_m / 2
    corners = [(cn - h, ce - h), (cn + h, ce - h), (cn + h, ce + h), (cn - h, ce + h)]
    return Trajectory(corners, config.world.tank_depth_m, config.trajectory, seed=rng)


def simulate_dataset(config: SimulatorConfig | None = None, *, seed: int = 0, with_scans: bool = True,
                     scan_interval_s: float = DEFAULT_SCAN_INTERVAL_S, progress: bool = False,
                     objects: dict | None = None, world_seed: int | None = None) -> Dataset:
    """Simulate a whole mission (a dive too long to hold its scans: :func:`simulate_scans`).

    Parameters
    ----------
    config : SimulatorConfig, optional
        Defaults: CIRS-like tank, four fittings, 3 loops at 0.3 m/s and 1.5 m altitude.
    seed : int
        Everything random derives from it: the same seed gives identical missions.
    with_scans : bool
        False skips the laser (navigation and truth only: fast, for Monte-Carlo filter studies).
    scan_interval_s : float
        Time between scan starts (>= the scan duration 1 / scan_rate_hz).
    objects : dict of str to ObjectModel, optional
        The objects placed in the tank (default: the four built-in fittings), e.g. a user's CAD models from
        :func:`semslam.simulation.cad_models.read_models`; the first four go to the corners of the route.
    world_seed : int, optional
        The seed of the world alone (the objects' placement): another dive over the same structure as the mission of
        that seed, with its own trajectory and sensor noise from ``seed`` (map reuse across dives).

    Returns
    -------
    Dataset
        The vehicle description (the simulated sensors' specification), sensor logs, 50 Hz truth, object truths, scan
        records (``path`` = ``scans/scan_NNNNN.pcd``) and
        the in-memory clouds (``mission.load_scan(scan_id)``, frame ``"scanner"``).
    """
    scan_interval_s = check_positive("scan_interval_s", scan_interval_s, caller="simulate_dataset")
    config, rngs, world, traj = _world_and_route(config, seed, objects, world_seed)
    dvl = simulate_dvl(traj, config.world, config.dvl, rngs["dvl"])
    ahrs = simulate_ahrs(traj, config.ahrs, rngs["ahrs"])
    depth = simulate_depth(traj, config.depth, rngs["depth"])
    fixes = simulate_fixes(traj, config.fixes, rngs["fixes"]) if config.fixes.any else None
    t_truth = sensor_stamps(config.trajectory.truth_rate_hz, traj.duration_s)
    s = traj.sample(t_truth)
    truth = VehicleTruth(t_truth, s.position_ned_m, s.rpy_rad, s.velocity_body_mps)
    scanner = LaserScanner(config.scanner)
    records, clouds = [], {}
    if with_scans:
        records, clouds = _simulate_scans(world, traj, scanner, config, scan_interval_s, rngs["scanner"], progress)
    sim_dict = config.to_dict()
    cfg_dict = {
        "simulator": sim_dict,
        "scan_interval_s": scan_interval_s,
        "with_scans": bool(with_scans),
        "frames": {
            "world": "NED, origin at the water surface above the tank centre, x along the long side",
            "vehicle": "body: x forward, y starboard, z down",
            "scanner": "z optical axis, x baseline laser->camera, y = z cross x; each line in the scanner frame at its own stamp",
            "object": "canonical frame of the class: origin at the bounding-box centre",
            "rpy": "intrinsic Z-Y-X, R = Rz(yaw) Ry(pitch) Rx(roll)",
        },
        "units": {"length": "m", "angle": "rad", "time": "s", "velocity": "m/s"},
    }
    vehicle = vehicle_from_simulator_dict(sim_dict, scanner.T_vehicle_scanner)
    origin = None
    if fixes is not None:
        from ..geodesy import GeodeticOrigin

        origin = GeodeticOrigin(config.fixes.origin_latitude_deg, config.fixes.origin_longitude_deg, 0.0)
    return Dataset(vehicle, dvl, ahrs, depth, truth, list(world.objects), records, cfg_dict, None, seed,
                   clouds if with_scans else None, fixes=fixes, geodetic_origin=origin)


def _world_and_route(config, seed, objects, world_seed):
    """Checked arguments of :func:`simulate_dataset` -> ``(config, rngs, world, trajectory)``."""
    config = SimulatorConfig() if config is None else config
    if not isinstance(config, SimulatorConfig):
        raise SimulationError(
            f"The 'config' argument of simulate_dataset must be a SimulatorConfig or None. Got "
            f"{type(config).__name__} instead."
        )
    rngs = _streams(_check_seed(seed))
    if world_seed is not None:
        rngs["world"] = _streams(_check_seed(world_seed))["world"]
    if objects is None:
        objects = builtin_objects()
    elif not isinstance(objects, dict) or not objects or not all(isinstance(m, ObjectModel) for m in objects.values()):
        raise SimulationError("The 'objects' argument of simulate_dataset must be a non-empty dict of ObjectModel. "
                              f"Got {type(objects).__name__} {objects!r:.80} instead.")
    world = build_world(config.world, objects, seed=rngs["world"])
    return config, rngs, world, mission_trajectory(world, config, rngs["trajectory"])


def simulate_scans(config: SimulatorConfig | None = None, *, seed: int = 0,
                   scan_interval_s: float = DEFAULT_SCAN_INTERVAL_S, progress: bool = False,
                   objects: dict | None = None, world_seed: int | None = None) -> Iterator[tuple[ScanRecord, Any]]:
    """The scans of ``simulate_dataset(config, seed=seed, ...)`` (same arguments) one at a time, ``(record,
    cloud)`` in time order: the same records and clouds bit for bit, never all in memory (a long dive written
    straight to a bag: :func:`semslam.dataset.rosbag_write.write_bag` with ``scans=``). Arguments are checked
    here, at the call."""
    scan_interval_s = check_positive("scan_interval_s", scan_interval_s, caller="simulate_scans")
    config, rngs, world, traj = _world_and_route(config, seed, objects, world_seed)
    scanner = LaserScanner(config.scanner)
    _check_interval(scanner, scan_interval_s)
    return _iter_scans(world, traj, scanner, config, scan_interval_s, rngs["scanner"], progress)


def _check_interval(scanner: LaserScanner, interval_s: float) -> None:
    if interval_s < scanner.duration_s - 1e-12:
        raise SimulationError(f"The 'scan_interval_s' argument of simulate_dataset must be >= the scan duration "
                              f"{scanner.duration_s:.3f} s (1 / scan_rate_hz). Got {interval_s} instead.")


def _simulate_scans(world: World, traj: Trajectory, scanner: LaserScanner, config: SimulatorConfig,
                    interval_s: float, rng: np.random.Generator, progress: bool):
    _check_interval(scanner, interval_s)
    records, clouds = [], {}
    for rec, cloud in _iter_scans(world, traj, scanner, config, interval_s, rng, progress):
        records.append(rec)
        clouds[rec.scan_id] = cloud
    return records, clouds


def _iter_scans(world: World, traj: Trajectory, scanner: LaserScanner, config: SimulatorConfig,
                interval_s: float, rng: np.random.Generator, progress: bool):
    caster = RayCaster(world.scene)
    T_vs = scanner.T_vehicle_scanner.matrix
    starts = np.arange(0.0, traj.duration_s - scanner.duration_s + 1e-9, interval_s)
    centres = np.array([o.T_world_object.translation_m for o in world.objects]).reshape(-1, 3)
    mids = traj.sample(starts + scanner.duration_s / 2).T_world_vehicle() @ T_vs
    scan_id = 0
    with progress_steps(progress, len(starts), "scans", "scan") as step:
        for k in range(len(starts)):
            step()
            # draw the scan's noise generator for every candidate so kept scans do not depend on gating
            scan_rng = np.random.default_rng(rng.integers(0, 2**63))
            if config.scanner.only_when_objects_in_view and not scanner.footprint_contains(mids[k], centres).any():
                continue
            stamps = scanner.line_stamps(starts[k])
            T_lines = traj.sample(stamps).T_world_vehicle() @ T_vs
            result = scanner.scan(
                caster, T_lines, seed=scan_rng, face_instance=world.face_instance, line_stamps_s=stamps
            )
            yield (ScanRecord(scan_id, float(stamps[0]), float(stamps[-1]), f"scans/scan_{scan_id:05d}.pcd",
                              result.cloud.n_points), result.cloud)
            scan_id += 1


def T_world_scanner_at(
    mission_truth: VehicleTruth, T_vehicle_scanner: RigidTransform, stamp_s: float
) -> RigidTransform:
    """Ground-truth scanner pose at a stamp (nearest truth sample's attitude, interpolated position)."""
    i = int(np.clip(np.searchsorted(mission_truth.stamp_s, stamp_s), 0, len(mission_truth.stamp_s) - 1))
    pos = mission_truth.interpolate_position(stamp_s)[0]
    return RigidTransform.from_xyz_rpy(pos, mission_truth.rpy_rad[i]) @ T_vehicle_scanner
