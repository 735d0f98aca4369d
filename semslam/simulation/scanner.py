"""The underwater laser scanner: a laser line swept by a galvanometer mirror, and a camera that
triangulates it (the Girona scanner of the papers).

Scanner frame: origin at the laser (mirror) centre, z along the optical axis (out of the viewport), x
along the baseline towards the camera, y = z x x. Line k is the laser plane spanned by y and
``(sin a_k, 0, cos a_k)``, ``a_k`` swept linearly across ``sweep_fov_rad`` during the scan; each line is
taken at its own stamp with the scanner where the vehicle was then. A point exists only where the laser
ray hits a surface that the camera (at ``baseline_m`` along x, toed in) also sees unobstructed, inside
its field of view and the range limits. Like the real sensor, each line's points are expressed in the
scanner frame *at that line's stamp* (no motion compensation), so motion during a scan distorts it.

Errors: Gaussian noise along the camera ray with sigma = ``noise_floor_m + noise_range2_per_m * r**2``
(r = camera range), random dropouts, and backscatter outliers (a point in the water column along the
laser ray). Intensity: ``|cos(incidence)| * exp(-attenuation * (laser range + camera range))``.

Ray casting (float64 where it matters): the scene's few large faces (the tank) are intersected by numba
kernels, each line testing only the faces its laser plane cuts; the small faces (objects, clutter) are
grouped into bounding spheres and only the rays and camera segments that pass through one go to Embree
(see :meth:`semslam.simulation._ray_kernels.RayCaster.split`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import _describe, as_rng
from ..cloud import PointCloud
from ..errors import SimulationError
from ..geometry import RigidTransform
from . import _scanner_kernels as _k
from ._ray_kernels import RayCaster, SplitScene
from .config import ScannerConfig

#: ``instance`` value of a backscatter outlier (tank surfaces are -1, objects their index).
BACKSCATTER = -2
#: The camera's view of a lit point must be free up to this distance (m) before the point.
_END_GAP_M = 1e-3
#: Angular margin (rad) of the ray culling by bounding spheres (covers rounding only).
_PHI_TOL_RAD = 1e-6


@dataclass(frozen=True, eq=False)
class _Trace:
    """Noise-free ray casting of one scan: hit face (N,) (-1 none) and laser range (N,) (inf none) of
    every ray; for the K hits in range and in the camera's view: ray index, camera range, and whether
    the camera sees the point."""

    tri: np.ndarray
    laser_m: np.ndarray
    idx: np.ndarray
    camera_m: np.ndarray
    seen: np.ndarray


@dataclass(frozen=True, eq=False)
class ScanResult:
    """One scan. ``cloud`` has ``intensity`` and the per-point fields ``line`` (int32, line index: the
    point's stamp is ``line_stamps_s[line]``) and ``instance`` (int32 ground truth: object index, -1 tank,
    -2 backscatter)."""

    cloud: PointCloud
    line_stamps_s: np.ndarray
    n_rays: int


class LaserScanner:
    """A scanner with a fixed configuration (the geometry of its rays is precomputed)."""

    def __init__(self, config: ScannerConfig | None = None):
        self.config = cfg = config or ScannerConfig()
        self.T_vehicle_scanner = RigidTransform.from_xyz_rpy(cfg.T_vehicle_scanner_xyz_m, cfg.T_vehicle_scanner_rpy_rad)
        a = np.linspace(-cfg.sweep_fov_rad / 2, cfg.sweep_fov_rad / 2, cfg.n_lines)
        phi = np.linspace(-cfg.line_fov_rad / 2, cfg.line_fov_rad / 2, cfg.points_per_line)
        A, P = np.meshgrid(a, phi, indexing="ij")  # (lines, points)
        d = np.stack([np.cos(P) * np.sin(A), np.sin(P), np.cos(P) * np.cos(A)], axis=-1)
        self.ray_dirs_scanner = d.reshape(cfg.n_lines, cfg.points_per_line, 3)
        self._dirs_flat = np.ascontiguousarray(self.ray_dirs_scanner.reshape(-1, 3))
        self._sin_a, self._cos_a, self._phi = np.sin(a), np.cos(a), phi
        self.camera_xyz_scanner = np.array([cfg.baseline_m, 0.0, 0.0])
        tau = cfg.camera_toe_in_rad
        self.camera_axis_scanner = np.array([-np.sin(tau), 0.0, np.cos(tau)])

    @property
    def duration_s(self) -> float:
        return 1.0 / self.config.scan_rate_hz

    def line_stamps(self, start_stamp_s: float) -> np.ndarray:
        """Stamp of each line: ``start + k * duration / n_lines``; the scan's end stamp is the last one."""
        return start_stamp_s + np.arange(self.config.n_lines) * (self.duration_s / self.config.n_lines)

    def scan(self, caster: RayCaster, T_world_scanner_lines: np.ndarray, *, seed=0,
             face_instance: np.ndarray | None = None, line_stamps_s: np.ndarray | None = None) -> ScanResult:
        """Scan a scene.

        Parameters
        ----------
        caster : RayCaster
            The scene (world frame).
        T_world_scanner_lines : array (n_lines, 4, 4) or (4, 4)
            Scanner pose at each line's stamp (one pose = static scanner).
        seed : int or Generator
            Noise, dropouts and backscatter.
        face_instance : array (F,), optional
            Ground-truth instance of each scene face (default -1 everywhere).
        """
        cfg = self.config
        rng = as_rng(seed, caller="LaserScanner.scan")
        T = np.asarray(T_world_scanner_lines, dtype=float)
        if T.shape == (4, 4):
            T = np.broadcast_to(T, (cfg.n_lines, 4, 4))
        if T.shape != (cfg.n_lines, 4, 4) or not np.isfinite(T).all():
            raise SimulationError(
                f"The 'T_world_scanner_lines' argument of LaserScanner.scan must have shape ({cfg.n_lines}, 4, 4) and "
                f"be finite. Got {T.shape} instead."
            )
        n_faces = len(caster.face_normals)
        inst = np.zeros(0, np.int64) if face_instance is None else np.asarray(face_instance)
        if face_instance is not None and (inst.shape != (n_faces,) or not np.issubdtype(inst.dtype, np.integer)):
            raise SimulationError(
                f"The 'face_instance' argument of LaserScanner.scan must be an integer array of shape ({n_faces},) "
                f"(one per scene face). Got {_describe(inst)} instead."
            )
        inst = inst.astype(np.int64, copy=False)
        R, t = np.ascontiguousarray(T[:, :3, :3]), np.ascontiguousarray(T[:, :3, 3])
        tr = self._trace(caster, R, t)
        dirs_local = self._dirs_flat
        n_rays = len(dirs_local)
        # errors (drawn for every ray so that the stream does not depend on the scene)
        gauss = rng.normal(0.0, 1.0, n_rays)
        uniform = rng.random((3, n_rays))  # dropout, backscatter, backscatter range: same stream as 3 draws
        keep = uniform[0] >= cfg.dropout_prob
        scatter = uniform[1] < cfg.backscatter_prob
        scatter_u = uniform[2]
        pts, inten, line, inst = _k.assemble(
            tr.idx, tr.camera_m, tr.seen, keep, scatter, scatter_u, gauss, dirs_local, R, tr.tri, tr.laser_m,
            caster.face_normals, inst, self.camera_xyz_scanner, cfg.points_per_line, cfg.noise_floor_m,
            cfg.noise_range2_per_m, cfg.attenuation_per_m, cfg.min_range_m, cfg.max_range_m, BACKSCATTER)
        fields = {"line": line, "instance": inst}
        stamps = line_stamps_s if line_stamps_s is not None else np.zeros(cfg.n_lines)
        cloud = PointCloud(pts, intensity=inten, viewpoint_xyz_m=np.zeros(3), frame_id="scanner", fields=fields)
        return ScanResult(cloud, np.asarray(stamps, dtype=float), n_rays)

    def _trace(self, caster: RayCaster, R: np.ndarray, t: np.ndarray, split: SplitScene | None = None) -> _Trace:
        """Cast the laser rays and the camera rays (no noise): line poses ``R`` (n_lines, 3, 3), ``t``
        (n_lines, 3), world frame. ``split`` defaults to ``caster.split()``."""
        cfg = self.config
        m = cfg.points_per_line
        dirs_local = self._dirs_flat
        sp = caster.split() if split is None else split
        large = (sp.large_verts, sp.large_v0, sp.large_normal, sp.large_edge_normal, sp.large_edge_offset)
        spheres = (sp.sphere_centre, sp.sphere_radius)
        # laser: large faces in float64 here, small faces by Embree for the rays that may reach them
        tri, t_hit, cand, o32, d32, tf32 = _k.laser_pass(
            dirs_local, R, t, m, self._sin_a, self._cos_a, self._phi, _PHI_TOL_RAD, sp.large_ids, *large, *spheres,
            caster.offset)
        _k.merge_small_hits(tri, t_hit, cand, sp.first_small_hit_ids(o32, d32, tf32), dirs_local, R, t, m,
                            caster.v0, caster.face_normals)
        # camera: in view, and is the segment to the lit point free (large faces here, small ones by Embree)?
        idx, r_cam, blocked, ocand, co32, cd32, len32 = _k.camera_pass(
            dirs_local, t_hit, R, t, m, self.camera_xyz_scanner, self.camera_axis_scanner,
            np.cos(cfg.camera_fov_rad / 2), cfg.min_range_m, cfg.max_range_m, _END_GAP_M, *large[1:], *spheres,
            caster.offset)
        seen = ~blocked
        seen[ocand] &= sp.small_unobstructed(co32, cd32, len32)
        return _Trace(tri, t_hit, idx, r_cam, seen)

    def footprint_contains(
        self, T_world_scanner: np.ndarray, points_world_m: np.ndarray, margin_rad: float = 0.05
    ) -> np.ndarray:
        """True for each world point inside the laser's swept field of view and range (cheap gating)."""
        T = np.asarray(T_world_scanner, dtype=float)
        p = (np.asarray(points_world_m, dtype=float) - T[:3, 3]) @ T[:3, :3]
        rng_m = np.linalg.norm(p, axis=1)
        a = np.arctan2(p[:, 0], p[:, 2])
        phi = np.arcsin(np.clip(p[:, 1] / np.maximum(rng_m, 1e-12), -1, 1))
        cfg = self.config
        return ((np.abs(a) <= cfg.sweep_fov_rad / 2 + margin_rad) & (np.abs(phi) <= cfg.line_fov_rad / 2 + margin_rad)
                & (rng_m <= cfg.max_range_m) & (p[:, 2] > 0))
