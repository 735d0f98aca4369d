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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import as_rng
from ..cloud import PointCloud
from ..errors import SimulationError
from ..geometry import RigidTransform
from . import _scanner_kernels as _k
from ._ray_kernels import RayCaster
from .config import ScannerConfig

#: ``instance`` value of a backscatter outlier (tank surfaces are -1, objects their index).
BACKSCATTER = -2


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
            raise SimulationError(f"The 'T_world_scanner_lines' argument of LaserScanner.scan must have shape ({cfg.n_lines}, 4, 4) and be finite. Got {T.shape} instead.")
        m = cfg.points_per_line
        R, t = np.ascontiguousarray(T[:, :3, :3]), np.ascontiguousarray(T[:, :3, 3])
        dirs_local = self.ray_dirs_scanner.reshape(-1, 3)
        n_rays = len(dirs_local)
        o32, d32, d64 = _k.laser_rays(dirs_local, R, t, m, caster.offset)
        tri = caster.first_hit_ids_raw(o32, d32)
        idx, dist, r_cam, co32, cd32, dist_all = _k.camera_rays(
            dirs_local, d64, tri, R, t, m, caster.v0, caster.face_normals, self.camera_xyz_scanner,
            self.camera_axis_scanner, np.cos(cfg.camera_fov_rad / 2), cfg.min_range_m, cfg.max_range_m, caster.offset)
        seen = caster.unobstructed_raw(co32, cd32, r_cam - 1e-3)
        # errors (drawn for every ray so that the stream does not depend on the scene)
        gauss = rng.normal(0.0, 1.0, n_rays)
        keep = rng.random(n_rays) >= cfg.dropout_prob
        scatter = rng.random(n_rays) < cfg.backscatter_prob
        scatter_u = rng.random(n_rays)
        sel = seen & keep[idx]
        idx, dist, r_cam = idx[sel], dist[sel], r_cam[sel]
        # points in the scanner frame of their own line
        p_local, intensity = _k.measure(idx, dist, r_cam, dirs_local, d64, tri, caster.face_normals, self.camera_xyz_scanner,
                                        gauss, cfg.noise_floor_m, cfg.noise_range2_per_m, cfg.attenuation_per_m)
        line = idx // m
        inst = np.full(len(idx), -1, dtype=np.int32) if face_instance is None else np.asarray(face_instance)[tri[idx]].astype(np.int32)
        # backscatter: a point in the water column between min range and the surface (or max range)
        bs = np.flatnonzero(scatter)
        far = np.minimum(dist_all[bs], cfg.max_range_m)
        r_bs = cfg.min_range_m + scatter_u[bs] * np.maximum(far - cfg.min_range_m, 0.0)
        bs_pts = dirs_local[bs] * r_bs[:, None]
        order = np.argsort(np.concatenate([idx, bs]), kind="stable")  # ray order: line by line
        pts = np.concatenate([p_local, bs_pts])[order]
        inten = np.concatenate([intensity, 0.05 * np.exp(-cfg.attenuation_per_m * 2 * r_bs)])[order]
        fields = {"line": np.concatenate([line, bs // m]).astype(np.int32)[order],
                  "instance": np.concatenate([inst, np.full(len(bs), BACKSCATTER, np.int32)])[order]}
        stamps = line_stamps_s if line_stamps_s is not None else np.zeros(cfg.n_lines)
        cloud = PointCloud(pts, intensity=inten, viewpoint_xyz_m=np.zeros(3), frame_id="scanner", fields=fields)
        return ScanResult(cloud, np.asarray(stamps, dtype=float), n_rays)

    def footprint_contains(self, T_world_scanner: np.ndarray, points_world_m: np.ndarray, margin_rad: float = 0.05) -> np.ndarray:
        """True for each world point inside the laser's swept field of view and range (cheap gating)."""
        T = np.asarray(T_world_scanner, dtype=float)
        p = (np.asarray(points_world_m, dtype=float) - T[:3, 3]) @ T[:3, :3]
        rng_m = np.linalg.norm(p, axis=1)
        a = np.arctan2(p[:, 0], p[:, 2])
        phi = np.arcsin(np.clip(p[:, 1] / np.maximum(rng_m, 1e-12), -1, 1))
        cfg = self.config
        return ((np.abs(a) <= cfg.sweep_fov_rad / 2 + margin_rad) & (np.abs(phi) <= cfg.line_fov_rad / 2 + margin_rad)
                & (rng_m <= cfg.max_range_m) & (p[:, 2] > 0))
