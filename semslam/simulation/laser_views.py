"""View-database acquisition with the mission's own laser scanner (an alternative to the Kinect-like views).

The Kinect-like survey views (:mod:`semslam.simulation.kinect`) see an object from a fixed distance and
elevation, with a camera at the eye. The vehicle's laser scanner sees it differently: it passes over the object
at 1-2 m, the camera that triangulates the laser sits 0.3 m along the track (so it has its own shadows), the
sweep and the vehicle's motion stretch or squeeze the object along the track, and objects off the route are seen
at the swath's oblique angles. :func:`laser_view_clouds` renders database views *with that scanner*, from
viewpoints sampled as the simulated missions fly (:class:`LaserViewConfig`: altitude, cross-track offset,
position along the sweep, roll/pitch, speed), each object alone on a flat floor in its most probable resting
pose. The points that the segmentation's floor removal would take (within ``floor_cut_m`` of the floor) are
dropped; the rest are expressed in the object's canonical frame, with the scanner origin at the object's
middle line as ``viewpoint_xyz_m``. Each point is carried into the object frame from its own line's pose: the view
the scan pipeline sees once it has deskewed the scan with the vehicle's motion (``PipelineConfig.deskew``, on by
default); ``LaserViewConfig(deskew=False)`` keeps the motion's stretch (the whole view carried by the middle line's
pose, as a scan that is not deskewed).

The views are the inputs of :func:`~semslam.recognition.build_database` (as
:func:`~semslam.simulation.cad_models.models_view_clouds` returns them); they can be combined with Kinect views.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
import trimesh

from .._progress import Progress, progress_steps
from .._validation import as_rng, check_int
from ..cloud import PointCloud
from ..errors import SimulationError
from ..geometry import RigidTransform
from ._ray_kernels import RayCaster
from .config import ScannerConfig
from .objects import ObjectModel
from .scanner import LaserScanner
from .world import _T_world_rest

__all__ = ["LaserViewConfig", "laser_view", "laser_view_clouds"]

#: Depth of the view's flat floor (world NED; any value, the floor is only there to be scanned and removed).
_FLOOR_DEPTH_M = 5.0
#: Tries per view to draw a viewpoint whose view is not cut by the swath's border (when ``allow_cut`` is False).
_MAX_TRIES = 40


@dataclass(frozen=True)
class LaserViewConfig:
    """Where the laser scanner sees the objects from, sampled per view (defaults: the simulated missions).

    Attributes
    ----------
    scanner : ScannerConfig
        The scanner (the missions' default: 320 x 320, 50 x 50 degrees, mounted 0.3 m below the vehicle origin,
        looking down).
    altitude_m : (float, float)
        Range of the vehicle's altitude above the floor (the missions: ``TrajectoryConfig`` 1.5 m +- 0.1 m wave).
    cross_track_m : float
        Largest cross-track offset of the object from the track (drawn uniformly in +-; the route passes over
        the four corner objects, a fifth object lies 0.44 m inside the square).
    along_sweep : float
        Largest position of the object along the sweep at the scan's mid stamp, as a fraction of the half
        sweep at the object's range (drawn uniformly in +-; 1 = the swath's edge).
    speed_mps : float
        Vehicle speed along the track during the scan (the missions: 0.3 m/s).
    roll_pitch_rad : (float, float)
        Largest roll and pitch of the vehicle (drawn uniformly in +-; the missions: 1.5 and 2 degrees).
    floor_cut_m : float
        Points within this height of the floor are dropped (the segmentation's plane removal: 1 cm).
    border_margin_rad : float
        A view with a point within this angle of the swath's edge is cut by the border.
    allow_cut : bool
        Keep views cut by the swath's border (partial views as the scanner cuts them); False draws another
        viewpoint until the object is whole in the swath (up to 40 tries, then the last one is kept).
    min_points : int
        Fewer object points than this: another viewpoint is drawn.
    deskew : bool
        Each point carried into the object frame from its own line's pose (the view the scan pipeline sees after
        deskewing, ``PipelineConfig.deskew``, the default); False: the whole view by the middle line's pose, the
        motion's stretch kept.
    """

    scanner: ScannerConfig = field(default_factory=ScannerConfig)
    altitude_m: tuple = (1.4, 1.6)
    cross_track_m: float = 0.45
    along_sweep: float = 0.8
    speed_mps: float = 0.3
    roll_pitch_rad: tuple = (math.radians(1.5), math.radians(2.0))
    floor_cut_m: float = 0.01
    border_margin_rad: float = math.radians(1.0)
    allow_cut: bool = False
    min_points: int = 50
    deskew: bool = True

    def __post_init__(self) -> None:
        lo, hi = (float(v) for v in self.altitude_m)
        mount = float(self.scanner.T_vehicle_scanner_xyz_m[2])
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi) or lo - mount <= self.scanner.min_range_m:
            raise SimulationError(
                f"The 'altitude_m' field of LaserViewConfig must be (low, high) with 0 < low <= high and "
                f"the scanner (mounted {mount:g} m below the vehicle) above its minimum range. "
                f"Got {self.altitude_m!r} instead."
            )
        for name in ("cross_track_m", "speed_mps", "floor_cut_m", "border_margin_rad"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise SimulationError(
                    f"The {name!r} field of LaserViewConfig must be a finite number >= 0. Got {v!r} instead."
                )
        if not (0 <= self.along_sweep <= 1):
            raise SimulationError(
                f"The 'along_sweep' field of LaserViewConfig must be in [0, 1]. Got {self.along_sweep!r} instead."
            )
        if len(self.roll_pitch_rad) != 2 or not all(0 <= float(v) < math.pi / 4 for v in self.roll_pitch_rad):
            raise SimulationError(f"The 'roll_pitch_rad' field of LaserViewConfig must be two angles in [0, pi/4). "
                                  f"Got {self.roll_pitch_rad!r} instead.")
        check_int("min_points", self.min_points, caller="LaserViewConfig", minimum=1)


@dataclass(frozen=True)
class _Viewpoint:
    heading_rad: float
    altitude_m: float
    cross_track_m: float
    along_sweep: float
    roll_rad: float
    pitch_rad: float


def _floor(size_m: float = 8.0) -> trimesh.Trimesh:
    h = size_m / 2
    v = np.array([(h, h, _FLOOR_DEPTH_M), (-h, h, _FLOOR_DEPTH_M), (-h, -h, _FLOOR_DEPTH_M), (h, -h, _FLOOR_DEPTH_M)])
    return trimesh.Trimesh(v, np.array([(0, 1, 2), (0, 2, 3)]), process=False)


class _Scene:
    """One object (resting pose, yaw 0, at the world origin's north/east) on a flat floor, ready to scan."""

    def __init__(self, model: ObjectModel):
        self.T_world_object = _T_world_rest(0.0, 0.0, _FLOOR_DEPTH_M, 0.0) @ model.resting_poses[0]
        mesh = model.mesh.copy().apply_transform(self.T_world_object)
        floor = _floor()
        self.caster = RayCaster(trimesh.util.concatenate([floor, mesh]))
        self.face_instance = np.concatenate([np.full(len(floor.faces), -1), np.zeros(len(mesh.faces))]).astype(np.int64)
        self.centre = np.asarray(mesh.bounds.mean(axis=0), dtype=float)
        self.radius = float(np.linalg.norm(mesh.vertices - self.centre, axis=1).max())


def _scan_view(scene: _Scene, scanner: LaserScanner, cfg: LaserViewConfig, vp: _Viewpoint,
               rng: np.random.Generator) -> tuple[PointCloud, bool, np.ndarray]:
    """Scan ``scene`` from ``vp``: (object-frame cloud, cut by the swath's border, scanner origin in the object
    frame at the object's middle line)."""
    sc = cfg.scanner
    T_vs = scanner.T_vehicle_scanner.matrix
    fwd = np.array([math.cos(vp.heading_rad), math.sin(vp.heading_rad), 0.0])
    right = np.array([-fwd[1], fwd[0], 0.0])  # NED: starboard
    scanner_height = vp.altitude_m - float(T_vs[2, 3])
    range_to_centre = scanner_height - (_FLOOR_DEPTH_M - scene.centre[2])  # scanner height above the object centre
    half_sweep = math.tan(sc.sweep_fov_rad / 2) * range_to_centre
    # the sweep goes from -x to +x of the scanner (= forward) during the scan; at the mid stamp it looks straight
    # down, so an object ``s`` ahead of the scanner at mid-scan is lit at sweep angle ~atan(s / range)
    along = vp.along_sweep * half_sweep
    duration = 1.0 / sc.scan_rate_hz
    stamps = np.arange(sc.n_lines) * (duration / sc.n_lines)
    t_mid = duration / 2
    centre_xy = scene.centre.copy()
    centre_xy[2] = 0.0
    scanner_mid = centre_xy - along * fwd - vp.cross_track_m * right
    scanner_mid[2] = _FLOOR_DEPTH_M - scanner_height
    T_lines = np.empty((sc.n_lines, 4, 4))
    R_wv = RigidTransform.from_xyz_rpy((0.0, 0.0, 0.0), (vp.roll_rad, vp.pitch_rad, vp.heading_rad)).matrix
    for k, t in enumerate(stamps):
        T_wv = R_wv.copy()
        p_scanner = scanner_mid + cfg.speed_mps * (t - t_mid) * fwd
        T_wv[:3, 3] = p_scanner - R_wv[:3, :3] @ T_vs[:3, 3]
        T_lines[k] = T_wv @ T_vs
    res = scanner.scan(scene.caster, T_lines, seed=rng, face_instance=scene.face_instance)
    cloud = res.cloud
    inst = cloud.fields["instance"]
    line = cloud.fields["line"]
    sel = inst == 0
    pts, lines = cloud.points_xyz_m[sel], line[sel]
    world = np.einsum("nij,nj->ni", T_lines[lines, :3, :3], pts) + T_lines[lines, :3, 3]  # each from its own line
    keep = (_FLOOR_DEPTH_M - world[:, 2]) >= cfg.floor_cut_m  # true world heights for the floor cut
    pts, lines, world = pts[keep], lines[keep], world[keep]
    if len(pts) == 0:
        return PointCloud(np.zeros((0, 3)), viewpoint_xyz_m=np.zeros(3), frame_id="object"), False, np.zeros(3)
    a = np.arctan2(pts[:, 0], pts[:, 2])
    phi = np.arcsin(np.clip(pts[:, 1] / np.linalg.norm(pts, axis=1), -1.0, 1.0))
    cut = bool(np.max(np.abs(a)) > sc.sweep_fov_rad / 2 - cfg.border_margin_rad
               or np.max(np.abs(phi)) > sc.line_fov_rad / 2 - cfg.border_margin_rad)
    ref = int(np.round(np.median(lines)))
    T_object_world = np.linalg.inv(scene.T_world_object)
    T_object_scanner = T_object_world @ T_lines[ref]
    if cfg.deskew:
        pts_obj = world @ T_object_world[:3, :3].T + T_object_world[:3, 3]
    else:
        pts_obj = pts @ T_object_scanner[:3, :3].T + T_object_scanner[:3, 3]
    eye = T_object_scanner[:3, 3].copy()
    return PointCloud(pts_obj, viewpoint_xyz_m=eye, frame_id="object"), cut, eye


def laser_view(model: ObjectModel, heading_rad: float, *, config: LaserViewConfig | None = None,
               seed: int | np.random.Generator | None = 0, _scene: _Scene | None = None,
               _scanner: LaserScanner | None = None) -> tuple[PointCloud, dict]:
    """One laser view of ``model`` with the vehicle's heading ``heading_rad`` relative to the object's yaw, the
    rest of the viewpoint drawn from ``config`` with ``seed``.

    Returns
    -------
    cloud : PointCloud
        The object's points (floor cut, object canonical frame, metres), ``viewpoint_xyz_m`` the scanner origin.
    info : dict
        The viewpoint drawn (``altitude_m``, ``cross_track_m``, ``along_sweep``, ``roll_rad``, ``pitch_rad``),
        ``range_m`` (scanner origin to the object's bounding-box centre), ``cut`` (the view touches the swath's
        border) and ``tries``.
    """
    cfg = config or LaserViewConfig()
    rng = as_rng(seed, caller="laser_view")
    scene = _scene or _Scene(model)
    scanner = _scanner or LaserScanner(cfg.scanner)
    centre_obj = np.linalg.inv(scene.T_world_object) @ np.append(scene.centre, 1.0)
    best = None
    for tries in range(1, _MAX_TRIES + 1):
        vp = _Viewpoint(float(heading_rad), float(rng.uniform(*cfg.altitude_m)),
                        float(rng.uniform(-cfg.cross_track_m, cfg.cross_track_m)),
                        float(rng.uniform(-cfg.along_sweep, cfg.along_sweep)),
                        float(rng.uniform(-cfg.roll_pitch_rad[0], cfg.roll_pitch_rad[0])),
                        float(rng.uniform(-cfg.roll_pitch_rad[1], cfg.roll_pitch_rad[1])))
        cloud, cut, eye = _scan_view(scene, scanner, cfg, vp, rng)
        info = {**dataclasses.asdict(vp), "range_m": float(np.linalg.norm(eye - centre_obj[:3])), "cut": cut,
                "tries": tries}
        ok = cloud.n_points >= cfg.min_points and (cfg.allow_cut or not cut)
        if ok:
            return cloud, info
        if cloud.n_points >= cfg.min_points:
            best = (cloud, info)
    if best is None:
        raise SimulationError(f"The laser saw fewer than {cfg.min_points} points of {model.label!r} in {_MAX_TRIES} "
                              f"viewpoints (heading {math.degrees(heading_rad):.0f} deg); check LaserViewConfig.")
    return best


def laser_view_clouds(models: dict[str, ObjectModel], *, seed: int | np.random.Generator | None = 0,
                      n_views: int = 48, config: LaserViewConfig | None = None, progress: Progress = False,
                      return_info: bool = False):
    """Database views of ``models`` seen by the mission's laser scanner (see the module docstring).

    View ``k`` of a class is taken with the vehicle's heading at ``360 * k / n_views`` degrees from the
    object's yaw; the rest of its viewpoint is drawn from ``config`` (seeded by ``seed``).

    Returns
    -------
    views : list of (label, view_id, PointCloud)
        ``n_views`` views per class (``view_id`` ``<label>_laser_hdg<degrees>``), object frame.
    classes : dict
        Per label ``{"symmetry": Symmetry, "size_xyz_m": ndarray (3,)}``.
    infos : list of dict, only with ``return_info``
        The viewpoint of every view (:func:`laser_view`).
    """
    if not isinstance(models, dict) or not models or not all(isinstance(m, ObjectModel) for m in models.values()):
        raise SimulationError(f"The 'models' argument of laser_view_clouds must be a non-empty dict label -> "
                              f"ObjectModel. Got {models!r:.60} instead.")
    n = check_int("n_views", n_views, caller="laser_view_clouds", minimum=1, maximum=3600)
    cfg = config or LaserViewConfig()
    rng = as_rng(seed, caller="laser_view_clouds")
    scanner = LaserScanner(cfg.scanner)
    views, classes, infos = [], {}, []
    with progress_steps(progress, n * len(models), "laser views", "view") as step:
        for label, model in models.items():
            scene = _Scene(model)
            for k in range(n):
                heading = 2 * math.pi * k / n
                cloud, info = laser_view(model, heading, config=cfg, seed=rng, _scene=scene, _scanner=scanner)
                views.append((label, f"{label}_laser_hdg{math.degrees(heading):05.1f}", cloud))
                infos.append({"label": label, **info})
                step()
            classes[label] = {"symmetry": model.symmetry, "size_xyz_m": np.array(model.size_xyz_m)}
    return (views, classes, infos) if return_info else (views, classes)
