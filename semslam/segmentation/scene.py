"""The segmentation stage of the recognition pipeline (Rusu et al. 2009, as in the seed papers):
optional voxel grid, removal of the dominant plane(s) by RMSAC, Euclidean clustering of the rest."""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from .._validation import as_rng, check_int, check_positive
from ..cloud import PointCloud
from ..errors import InputError, SegmentationError
from . import _voxel_kernels
from .clusters import _clusters
from .plane import PlaneModel, _remove_planes
from .prefilter import check_length_or_auto, resolve_lengths, valid_return_mask
from .voxel import _voxel_grid

__all__ = ["SegmentationConfig", "SegmentationResult", "segment_scene"]


@dataclass(frozen=True)
class SegmentationConfig:
    """Parameters of :func:`segment_scene`, validated on construction.

    Defaults suit our laser scans of pipe fittings (10-40 cm) on a tank floor, seen from 1-3 m:

    * ``voxel_leaf_m = 0.005``: 5 mm keeps the fittings' shape for ESF/VFH and evens out the scan
      density (closer surfaces are sampled more densely); ``None`` disables the voxel grid.
    * ``distance_threshold_m = 0.01``: floor points within 1 cm are removed (scanner noise is a few
      mm; a larger value eats the bottom of objects resting on the floor).
    * ``cluster_tolerance_m = 0.02``: 4 voxels; parts of one object closer than 2 cm merge.
    * ``min_cluster_size = 50``: at 5 mm, 50 points is ~12 cm^2 of surface, below which ESF/VFH are
      unreliable; ``max_cluster_size = 25000`` is ~0.6 m^2 at 5 mm, larger clusters are walls or
      structure, not fittings.
    * ``max_planes = 1``: the floor; raise it to also remove tank walls. A further plane is removed
      only if it holds at least ``min_plane_inliers`` points (default 5 % of the cloud).

    Before the voxel grid (:mod:`.prefilter`): ``drop_origin = True`` leaves out the points exactly at the
    sensor origin (a depth camera's invalid pixels; never a real return; off by default so that synthetic
    clouds through the origin stay whole; the CLI turns it on), ``min_range_m`` / ``max_range_m``
    keep the sensor's working range (default: everything). ``voxel_leaf_m`` and ``cluster_tolerance_m`` may
    be ``"auto"``: measured from the kept points' spacing ``s`` (leaf ``s``, tolerance 4 leaves), for
    sensors other than the laser, e.g. a RealSense frame at 30 cm (``s`` ~ 1.7 mm).
    """

    voxel_leaf_m: float | str | None = 0.005
    distance_threshold_m: float = 0.01
    max_planes: int = 1
    min_plane_inliers: int | None = None
    plane_confidence: float = 0.99
    plane_max_iterations: int = 1000
    plane_n_pretest: int = 1
    cluster_tolerance_m: float | str = 0.02
    min_cluster_size: int = 50
    max_cluster_size: int | None = 25000
    drop_origin: bool = False
    min_range_m: float = 0.0
    max_range_m: float | None = None

    def __post_init__(self) -> None:
        c = "SegmentationConfig"
        for name, value in (("voxel_leaf_m", self.voxel_leaf_m), ("cluster_tolerance_m", self.cluster_tolerance_m)):
            if isinstance(value, str):  # only "auto"
                check_length_or_auto(name, value, caller=c)
            elif value is not None or name == "cluster_tolerance_m":
                check_positive(name, value, caller=c)
        if not isinstance(self.drop_origin, bool):
            raise InputError(f"The 'drop_origin' argument of {c} must be True or False. "
                             f"Got {self.drop_origin!r} instead.")
        lo_r = check_positive("min_range_m", self.min_range_m, caller=c, allow_zero=True)
        if self.max_range_m is not None:
            hi_r = check_positive("max_range_m", self.max_range_m, caller=c)
            if hi_r <= lo_r:
                raise InputError(f"The 'max_range_m' argument of {c} must be > min_range_m={lo_r}. "
                                 f"Got {self.max_range_m!r} instead.")
        check_positive("distance_threshold_m", self.distance_threshold_m, caller=c)
        check_int("max_planes", self.max_planes, caller=c, minimum=0)
        if self.min_plane_inliers is not None:
            check_int("min_plane_inliers", self.min_plane_inliers, caller=c, minimum=3)
        check_positive("plane_confidence", self.plane_confidence, caller=c)
        if not self.plane_confidence < 1:
            raise InputError(
                f"The 'plane_confidence' argument of {c} must be in (0, 1). "
                f"Got {self.plane_confidence!r} instead."
            )
        check_int("plane_max_iterations", self.plane_max_iterations, caller=c, minimum=1)
        check_int("plane_n_pretest", self.plane_n_pretest, caller=c, minimum=0)
        lo = check_int("min_cluster_size", self.min_cluster_size, caller=c, minimum=1)
        if self.max_cluster_size is not None:
            hi = check_int("max_cluster_size", self.max_cluster_size, caller=c, minimum=1)
            if hi < lo:
                raise InputError(
                    f"The 'max_cluster_size' argument of {c} must be >= min_cluster_size={lo}. "
                    f"Got {hi} instead."
                )

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True, eq=False)
class SegmentationResult:
    """Output of :func:`segment_scene`.

    Attributes
    ----------
    segmented_cloud : PointCloud
        The cloud the planes and clusters were computed on: the voxel centroids (frame and viewpoint
        of the input; intensity averaged per voxel; normals and other fields dropped), or the input
        itself without a voxel grid.
    planes : list of PlaneModel
        Removed planes (coefficients in the input frame, ``n_inliers`` counted in ``segmented_cloud``).
    cluster_indices : list of ndarray of int64
        Sorted indices into ``segmented_cloud``, one array per cluster, largest first.
    clusters : list of PointCloud
        ``segmented_cloud.select(indices)`` for each cluster.
    point_voxel : ndarray of shape (N_kept,) or None
        Row of ``segmented_cloud`` each kept input point was averaged into (None without voxel grid).
    n_input_points : int
    n_after_planes : int
        Points of ``segmented_cloud`` left for clustering.
    timings_ms : dict of str to float
        Wall time of each stage (``voxel``, with the prefilter and the spacing of ``"auto"``; ``planes``,
        ``clusters``, ``total``), milliseconds.
    notes : list of str
        Why a stage removed nothing or the result is empty (never silent).
    kept_indices : ndarray of int64 or None
        Indices into the input of the points segmented (the valid returns within the working range, see
        :mod:`.prefilter`); None when every input point was kept. ``point_voxel`` is indexed like them.
    resolved : dict
        The lengths used: ``voxel_leaf_m`` (None: no grid), ``cluster_tolerance_m``, and the measured
        ``spacing_m`` when an ``"auto"`` length needed it (else None).
    """

    segmented_cloud: PointCloud
    planes: list[PlaneModel]
    cluster_indices: list[np.ndarray]
    clusters: list[PointCloud]
    point_voxel: np.ndarray | None
    n_input_points: int
    n_after_planes: int
    timings_ms: dict[str, float]
    notes: list[str] = field(default_factory=list)
    # (packed point-by-voxel order, voxel run starts) from the voxel grid, for input_indices
    _voxel_points: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)
    kept_indices: np.ndarray | None = field(default=None, repr=False)
    resolved: dict = field(default_factory=dict)

    @property
    def cluster_sizes(self) -> list[int]:
        """Number of points of each cluster, largest first."""
        return [len(c) for c in self.cluster_indices]

    @property
    def n_clusters(self) -> int:
        return len(self.cluster_indices)

    def input_indices(self, cluster: int) -> np.ndarray:
        """Sorted indices into the INPUT cloud of the points of cluster ``cluster`` (through the voxel map)."""
        idx = self.cluster_indices[cluster]
        if self.point_voxel is not None:
            idx = self._kept_input_indices(idx)
        return idx if self.kept_indices is None else self.kept_indices[idx]

    def _kept_input_indices(self, idx: np.ndarray) -> np.ndarray:
        if self._voxel_points is not None and 16 * len(idx) < len(self.point_voxel):
            packed, start = self._voxel_points  # small cluster: gather its points, sort them
            if 16 * int((start[idx + 1] - start[idx]).sum()) < len(self.point_voxel):
                return _voxel_kernels.points_of_voxels(packed, start, idx)
        return _voxel_kernels.points_in_voxels(self.point_voxel, idx, self.segmented_cloud.n_points)

    def to_dict(self) -> dict:
        return {
            "n_input_points": self.n_input_points,
            "n_kept_points": self.n_input_points if self.kept_indices is None else len(self.kept_indices),
            "resolved": dict(self.resolved),
            "n_segmented_points": self.segmented_cloud.n_points,
            "n_after_planes": self.n_after_planes,
            "planes": [p.to_dict() for p in self.planes],
            "cluster_sizes": self.cluster_sizes,
            "timings_ms": dict(self.timings_ms),
            "notes": list(self.notes),
        }


def segment_scene(
    cloud: PointCloud,
    config: SegmentationConfig | None = None,
    *,
    seed: int | np.random.Generator | None = 0,
) -> SegmentationResult:
    """Segment a scan into object clusters: voxel grid, dominant plane(s) removal, Euclidean clusters.

    Parameters
    ----------
    cloud : PointCloud
        The scene, any frame (plane coefficients are returned in it); typically the scanner frame.
    config : SegmentationConfig, optional
        Stage parameters; default ``SegmentationConfig()``.
    seed : int, numpy Generator or None
        Randomness of the plane fitting (RMSAC); an int makes the result reproducible.

    Returns
    -------
    SegmentationResult
        Never raises on a scene that is too small or degenerate: the planes or clusters are then
        empty and ``notes`` says why.
    """
    cfg = _checked_inputs(cloud, config)
    notes: list[str] = []
    timings: dict[str, float] = {}
    n_input = cloud.n_points
    t_start = t0 = time.perf_counter()

    cloud, kept_indices = _prefiltered(cloud, cfg, notes)
    leaf, tolerance, spacing = resolve_lengths(cloud.points_xyz_m, cfg.voxel_leaf_m, cfg.cluster_tolerance_m,
                                               seed=0)
    resolved = {"voxel_leaf_m": leaf, "cluster_tolerance_m": tolerance, "spacing_m": spacing}
    seg_cloud, point_voxel, voxel_points = _voxel_stage(cloud, leaf)
    timings["voxel"] = (time.perf_counter() - t0) * 1e3

    t0 = time.perf_counter()
    pts = seg_cloud.points_xyz_m
    planes, remaining = _plane_stage(pts, cfg, seed, notes)
    timings["planes"] = (time.perf_counter() - t0) * 1e3

    t0 = time.perf_counter()
    cluster_indices = _cluster_stage(pts, remaining, tolerance, cfg, notes)
    clusters = [seg_cloud.select(idx) for idx in cluster_indices]
    timings["clusters"] = (time.perf_counter() - t0) * 1e3
    timings["total"] = (time.perf_counter() - t_start) * 1e3
    return SegmentationResult(
        seg_cloud,
        planes,
        cluster_indices,
        clusters,
        point_voxel,
        n_input,
        len(remaining),
        timings,
        notes,
        voxel_points,
        kept_indices,
        resolved,
    )


def _checked_inputs(cloud: PointCloud, config: SegmentationConfig | None) -> SegmentationConfig:
    """The configuration of :func:`segment_scene` (default ``SegmentationConfig()``), after checking the types."""
    if not isinstance(cloud, PointCloud):
        raise InputError(
            f"The 'cloud' argument of segment_scene must be a PointCloud. Got {type(cloud).__name__} instead."
        )
    cfg = SegmentationConfig() if config is None else config
    if not isinstance(cfg, SegmentationConfig):
        raise InputError(
            f"The 'config' argument of segment_scene must be a SegmentationConfig. "
            f"Got {type(config).__name__} instead."
        )
    return cfg


def _prefiltered(
    cloud: PointCloud, cfg: SegmentationConfig, notes: list[str]
) -> tuple[PointCloud, np.ndarray | None]:
    """The valid returns within the working range (:mod:`.prefilter`) and their indices into ``cloud`` (None when
    every point is kept); a note says how many points were left out and why."""
    kept = valid_return_mask(cloud.points_xyz_m, cloud.viewpoint_xyz_m, drop_origin=cfg.drop_origin,
                             min_range_m=float(cfg.min_range_m), max_range_m=cfg.max_range_m)
    kept_indices = None
    if kept is not None:
        kept_indices = np.flatnonzero(kept)
        notes.append(f"{cloud.n_points - len(kept_indices)} point(s) left out: "
                     + _dropped_text(cloud, kept, cfg))
        cloud = cloud.select(kept_indices)
    return cloud, kept_indices


def _voxel_stage(
    cloud: PointCloud, leaf: float | None
) -> tuple[PointCloud, np.ndarray | None, tuple[np.ndarray, np.ndarray] | None]:
    """The cloud to segment (voxel centroids, or ``cloud`` itself without a grid or points), each point's voxel
    row and the voxel grid's (packed point order, run starts); both None without a grid."""
    point_voxel = None
    voxel_points = None
    seg_cloud = cloud
    if leaf is not None and cloud.n_points:
        # the cloud was validated on construction: skip the public functions' re-validation
        grid, intensity, voxel_points = _voxel_grid(
            cloud.points_xyz_m, float(leaf), False, cloud.intensity
        )
        point_voxel = grid.point_voxel
        # fresh arrays owned by this result: read-only up front so PointCloud does not copy them
        grid.points_xyz_m.setflags(write=False)
        if intensity is not None:
            intensity.setflags(write=False)
        seg_cloud = PointCloud(
            grid.points_xyz_m,
            intensity=intensity,
            viewpoint_xyz_m=cloud.viewpoint_xyz_m,
            frame_id=cloud.frame_id,
        )
    return seg_cloud, point_voxel, voxel_points


def _plane_stage(
    pts: np.ndarray, cfg: SegmentationConfig, seed: int | np.random.Generator | None, notes: list[str]
) -> tuple[list[PlaneModel], np.ndarray]:
    """The planes removed from ``pts`` (RMSAC, far outliers left out of the fit) and the sorted indices of the
    remaining points (all of them when no plane is removed); notes say why fewer planes than asked were removed."""
    planes: list[PlaneModel] = []
    remaining = None
    if len(pts) == 0:
        notes.append("empty input cloud: nothing to segment")
    elif cfg.max_planes > 0:
        try:
            near = _near_points(pts)
            plane_pts = pts if near is None else pts[near]
            n = len(plane_pts)
            min_inliers = max(3, math.ceil(0.05 * n)) if cfg.min_plane_inliers is None else cfg.min_plane_inliers
            removal = _remove_planes(plane_pts, float(cfg.distance_threshold_m), cfg.max_planes, min_inliers, False,
                                     float(cfg.plane_confidence), cfg.plane_max_iterations, cfg.plane_n_pretest,
                                     as_rng(seed, caller="segment_scene"), "remove_dominant_planes")
            planes, remaining = removal.planes, removal.remaining_indices
            if near is not None:  # far outliers are in no plane: back with the remaining points, in order
                keep = np.ones(len(pts), dtype=bool)
                keep[near[np.setdiff1d(np.arange(len(near)), remaining)]] = False
                remaining = np.flatnonzero(keep)
                notes.append(f"{len(pts) - len(near)} far outlier point(s) left out of the plane fit")
            if len(planes) < cfg.max_planes:
                notes.append(
                    f"removed {len(planes)} of max {cfg.max_planes} planes: {removal.stop_reason}"
                )
        except SegmentationError as exc:
            notes.append(f"no plane removed: {exc}")
    if remaining is None:
        remaining = np.arange(len(pts), dtype=np.int64)
    return planes, remaining


def _cluster_stage(
    pts: np.ndarray, remaining: np.ndarray, tolerance: float, cfg: SegmentationConfig, notes: list[str]
) -> list[np.ndarray]:
    """Euclidean clusters of ``pts[remaining]`` as sorted indices into ``pts``, largest first; a note says why
    there is none."""
    cluster_indices: list[np.ndarray] = []
    if len(pts) and len(remaining) == 0:
        notes.append("no points left after plane removal: no clusters")
    elif len(remaining):
        local = _clusters(
            pts if len(remaining) == len(pts) else pts[remaining],
            float(tolerance),
            cfg.min_cluster_size,
            cfg.max_cluster_size,
        )
        cluster_indices = [remaining[c] for c in local]
        if not cluster_indices:
            notes.append(
                f"no cluster of {cfg.min_cluster_size} to {cfg.max_cluster_size} points among the "
                f"{len(remaining)} points left after plane removal"
            )
    return cluster_indices


def _dropped_text(cloud: PointCloud, kept: np.ndarray, cfg: SegmentationConfig) -> str:
    """How many of the left-out points were at the sensor origin and how many out of the working range."""
    parts = []
    if cfg.drop_origin:
        n0 = int((cloud.points_xyz_m == np.asarray(cloud.viewpoint_xyz_m)[None, :]).all(axis=1).sum())
        if n0:
            parts.append(f"{n0} at the sensor origin (invalid returns)")
    n_range = int((~kept).sum()) - (n0 if cfg.drop_origin else 0)
    if n_range:
        hi = "inf" if cfg.max_range_m is None else f"{cfg.max_range_m:g}"
        parts.append(f"{n_range} outside the working range [{cfg.min_range_m:g}, {hi}] m")
    return ", ".join(parts)


#: Points farther than this many robust extents outside the 1-99 % box are left out of the plane fit.
FAR_OUTLIER_EXTENTS = 10.0
#: Points of the sample the 1-99 % box is measured on.
_PERCENTILE_SAMPLE = 4096


def _near_points(pts: np.ndarray) -> np.ndarray | None:
    """Indices (increasing) of the points within ``FAR_OUTLIER_EXTENTS`` robust extents of the 1-99 percentile
    box, or None when that is all of them: one point at 1e9 m must not change the planes RMSAC finds."""
    if len(pts) < 100:
        return None
    # the percentiles of an evenly strided sample of ~4k points (a 100k-point scan: 8x faster; the box only
    # scales a margin of 10 extents), and the test per axis on flat columns
    lo, hi = np.percentile(pts[::max(1, len(pts) // _PERCENTILE_SAMPLE)], [1.0, 99.0], axis=0)
    margin = FAR_OUTLIER_EXTENTS * float((hi - lo).max())
    inside = np.ones(len(pts), dtype=bool)
    for k in range(pts.shape[1]):
        col = pts[:, k]
        inside &= (col >= lo[k] - margin) & (col <= hi[k] + margin)
    return None if inside.all() else np.flatnonzero(inside)
