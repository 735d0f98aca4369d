"""The model's and the scene's indexes for the pose search (:mod:`.search`): built once per class or per
cluster, queried for every hypothesis.

* :class:`DistanceField`: per-cell nearest model point on a regular grid (object frame), cached on disk.
* :class:`RangeImage`: the smallest observed range per angular cell (scanner frame), of a cluster or a whole scan.
* :class:`ViewCentroids`: the centroid of the model surface facing each viewing direction (translation start).
* :class:`RadiusGrid`: model points bucketed for exact nearest-neighbour queries within a radius.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from .._validation import check_int
from . import _search_kernels as K

_NO_CAMERA = np.full(3, np.nan)


@dataclass(frozen=True, eq=False)
class DistanceField:
    """Nearest model point per grid cell (object frame), compact: ``offsets (nx, ny, nz, 3)`` int8 = nearest
    point minus cell centre in units of ``quantum_m`` (-128: farther than ``truncation_m``). Cell ``cell_m``,
    grid origin ``origin`` (3,). ``index (nx, ny, nz, K)`` int32 holds the rows of the ``K`` points nearest to
    each cell's centre in the points the field was built from (-1: none within ``truncation_m``): the
    candidates of the ICP's nearest-neighbour search (:func:`._icp_kernels.icp_plane_field`)."""

    origin: np.ndarray
    cell_m: float
    offsets: np.ndarray
    truncation_m: float
    quantum_m: float
    index: np.ndarray | None = None

    @classmethod
    def build(cls, points_object: np.ndarray, *, cell_m: float = 0.0025, margin_m: float = 0.03,
              truncation_m: float = 0.03, n_index: int = 8) -> "DistanceField":
        quantum = max(truncation_m + cell_m, 1e-6) / 126.0
        lo = points_object.min(axis=0) - margin_m
        hi = points_object.max(axis=0) + margin_m
        dims = np.ceil((hi - lo) / cell_m).astype(int)
        axes = [lo[a] + cell_m * (np.arange(dims[a]) + 0.5) for a in range(3)]
        centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        # one query serves both: the nearest point (offsets) and the ICP's candidates (index)
        k = max(int(n_index), 1)
        dk, jk = cKDTree(points_object).query(centres, k=k, distance_upper_bound=truncation_m + np.sqrt(3.0) * cell_m,
                                              workers=-1)
        dk, jk = dk.reshape(len(centres), k), jk.reshape(len(centres), k)
        d, j = np.where(dk[:, 0] <= truncation_m, dk[:, 0], np.inf), jk[:, 0]
        off = np.full((len(centres), 3), -128, dtype=np.int8)
        ok = np.isfinite(d)
        off[ok] = np.clip(np.rint((points_object[j[ok]] - centres[ok]) / quantum), -127, 127).astype(np.int8)
        index = np.where(np.isfinite(dk), jk, -1).astype(np.int32).reshape(*dims, k)
        return cls(lo, float(cell_m), off.reshape(*dims, 3), float(truncation_m), float(quantum), index)

    @classmethod
    def build_cached(cls, points_object: np.ndarray, *, cell_m: float = 0.0025, margin_m: float = 0.03,
                     truncation_m: float = 0.03, n_index: int = 8) -> "DistanceField":
        """:meth:`build`, through the on-disk cache (:mod:`semslam._cache`): a cold ``semslam recognize`` would
        otherwise spend most of its time (0.5-1.3 s per class) building the same fields again."""
        from .._cache import cached_arrays

        pts = np.ascontiguousarray(points_object, dtype=np.float64)
        params = (float(cell_m), float(margin_m), float(truncation_m), int(n_index))

        def build() -> dict:
            f = cls.build(pts, cell_m=cell_m, margin_m=margin_m, truncation_m=truncation_m, n_index=n_index)
            return {"origin": f.origin, "scalars": np.array([f.cell_m, f.truncation_m, f.quantum_m]),
                    "offsets": f.offsets, "index": f.index}

        a = cached_arrays("distance_field_v1", [pts, *params], build)
        cell, trunc, quantum = (float(v) for v in a["scalars"])
        return cls(np.asarray(a["origin"], dtype=np.float64), cell, a["offsets"], trunc, quantum, a["index"])

    @property
    def params(self) -> np.ndarray:
        """``(origin x y z, cell, quantum)``, as the kernels take them."""
        return np.array([*self.origin, self.cell_m, self.quantum_m])

    def nearest_points(self, points_object: np.ndarray) -> np.ndarray:
        """The stored nearest model point (N, 3) of each point's cell (NaN outside the field)."""
        return K.field_nearest(np.ascontiguousarray(points_object, dtype=np.float64), self.params, self.offsets)


@dataclass(frozen=True, eq=False)
class RangeImage:
    """The cluster's smallest observed range around each angular cell (gnomonic image about its mean
    ray). ``F`` (3, 3): rows = image u, v axes and the mean ray; ``range_min`` (nu, nv), inf = unseen."""

    viewpoint: np.ndarray
    F: np.ndarray
    u0: float
    v0: float
    cell: float
    range_min: np.ndarray
    #: :meth:`build_scene` with occluders: the smallest range of the scene's objects per cell (inf: none)
    occluder_min: np.ndarray | None = None
    #: the camera of a triangulation laser scanner (3,), same frame as ``viewpoint`` (None: one viewpoint, as a lidar
    #: or a depth camera): :meth:`visibility_cost` expects no return where the camera cannot see the laser's spot
    camera: np.ndarray | None = None
    #: a cell that saw nothing contradicts a model point there (the cluster's own image); False for
    #: :meth:`build_scene`'s image of the whole scan, where it is unknown (the scanner did not look there)
    unseen_bad: bool = True

    @classmethod
    def build(cls, points: np.ndarray, viewpoint: np.ndarray, *, cell_m: float, margin_m: float = 0.1,
              dilate: int = 1, extra_points: np.ndarray | None = None) -> "RangeImage":
        """The range image of ``points`` (N, 3) seen from ``viewpoint``: gnomonic about their mean ray, cells of
        ``cell_m`` at their median range, ``margin_m`` beyond them. ``extra_points`` (K, 3): further surfaces seen
        (a cluster's surroundings) entered where they fall on that same grid, so that they can only remove
        contradictions of :meth:`visibility_cost`, never move the grid."""
        rays = points - viewpoint
        rng = np.linalg.norm(rays, axis=1)
        z = rays.mean(axis=0)
        z /= max(np.linalg.norm(z), 1e-300)
        x = np.cross(z, [0.0, 0.0, 1.0] if abs(z[2]) < 0.9 else [1.0, 0.0, 0.0])
        x /= np.linalg.norm(x)
        F = np.vstack([x, np.cross(z, x), z])
        q = rays @ F.T
        front = q[:, 2] > 1e-6 * max(float(rng.max(initial=0.0)), 1e-12)  # a point at or behind the sensor has no pixel
        if not front.any():
            front = np.ones(len(q), dtype=bool)
            q = np.c_[q[:, :2], np.ones(len(q))]
        q, rng = q[front], rng[front]
        uv = q[:, :2] / q[:, 2:3]
        median_range = max(float(np.median(rng)), 1e-12)
        cell = cell_m / median_range
        margin = margin_m / median_range
        lo = uv.min(axis=0) - margin
        dims = np.ceil((uv.max(axis=0) + margin - lo) / cell).astype(int) + 1
        ij = np.floor((uv - lo) / cell).astype(np.int64)
        if extra_points is not None and len(extra_points):
            qe = (np.asarray(extra_points, dtype=np.float64) - viewpoint) @ F.T
            qe = qe[qe[:, 2] > 1e-9]
            ije = np.floor((qe[:, :2] / qe[:, 2:3] - lo) / cell).astype(np.int64)
            inside = np.all(ije >= 0, axis=1) & np.all(ije < dims, axis=1)
            ij, rng = np.vstack([ij, ije[inside]]), np.concatenate([rng, np.linalg.norm(qe[inside], axis=1)])
        # smallest range per cell, then over the (2 d + 1)^2 neighbourhood: tolerate sampling holes
        img = K.range_image(ij, rng, int(dims[0]), int(dims[1]), max(int(dilate), 0))
        return cls(np.asarray(viewpoint, dtype=np.float64), F, float(lo[0]), float(lo[1]), float(cell), img)

    @classmethod
    def build_scene(cls, scene_points: np.ndarray, viewpoint: np.ndarray, around_points: np.ndarray, *, cell_m: float,
                    occluder_points: np.ndarray | None = None, margin_m: float = 0.3, dilate: int = 1) -> "RangeImage":
        """The image of the whole scan in a cone about ``around_points`` (a cluster) widened by ``margin_m`` at the
        cluster's median range: what the scanner saw where an object's model may lie, the other objects and the
        free space included; outside the scan's footprint the cells stay unseen. ``occluder_points``: the scene's
        objects (its clusters, not its planes), the only surfaces that may hide a model point (without them, any
        surface may). For :meth:`visibility_cost` with ``unseen_is_contradiction=False``."""
        vp = np.asarray(viewpoint, dtype=np.float64)
        rays = np.asarray(around_points, dtype=np.float64) - vp
        dist = np.linalg.norm(rays, axis=1)
        z = rays.sum(axis=0)
        z /= max(float(np.linalg.norm(z)), 1e-300)
        cos_c = np.clip(rays @ z / np.maximum(dist, 1e-300), -1.0, 1.0)
        half = float(np.arccos(cos_c.min())) + float(margin_m) / max(float(np.median(dist)), 1e-12)
        scene = np.asarray(scene_points, dtype=np.float64)
        sr = scene - vp
        sd = np.linalg.norm(sr, axis=1)
        inside = (sd > 0.0) & (sr @ z > np.cos(min(half, 0.5 * np.pi - 1e-3)) * sd)
        pts = scene[inside] if inside.any() else np.asarray(around_points, dtype=np.float64)
        img = replace(cls.build(pts, vp, cell_m=cell_m, margin_m=0.0, dilate=dilate), unseen_bad=False)
        if occluder_points is None:
            return img
        occ = np.asarray(occluder_points, dtype=np.float64) - vp
        q = occ @ img.F.T
        front = q[:, 2] > 1e-9
        uv = q[front, :2] / q[front, 2:3]
        ij = np.floor((uv - [img.u0, img.v0]) / img.cell).astype(np.int64)
        nu, nv = img.range_min.shape
        ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < nu) & (ij[:, 1] < nv)
        occ_img = K.range_image(ij[ok], np.linalg.norm(occ[front][ok], axis=1), int(nu), int(nv), max(int(dilate), 0))
        return cls(img.viewpoint, img.F, img.u0, img.v0, img.cell, img.range_min, occ_img, unseen_bad=False)

    def visibility_cost(self, Rs: np.ndarray, ts: np.ndarray, model_pts: np.ndarray, model_nrm: np.ndarray,
                        tol_m: float, *, unseen_is_contradiction: bool | None = None) -> np.ndarray:
        """Share (H,) of the model points predicted visible under each hypothesis that contradict the scan. With
        ``unseen_is_contradiction`` False (default: not :attr:`unseen_bad`, as for an image of the scene,
        :meth:`build_scene`), model points where the
        scanner saw nothing are left out, and those behind what it saw are hidden (behind an object, when the image
        has ``occluder_min``), not contradictions."""
        return K.visibility_cost(
            np.ascontiguousarray(Rs),
            np.ascontiguousarray(ts),
            model_pts,
            model_nrm,
            self.viewpoint,
            self.F,
            self.u0,
            self.v0,
            1.0 / self.cell,
            self.range_min,
            float(tol_m),
            bool(self.unseen_bad if unseen_is_contradiction is None else unseen_is_contradiction),
            self.range_min if self.occluder_min is None else self.occluder_min,
            _NO_CAMERA if self.camera is None else self.camera,
        )

    def with_camera(self, camera_offset_m) -> "RangeImage":
        """The same image with the triangulation camera at ``viewpoint + camera_offset_m`` (None: none)."""
        if camera_offset_m is None:
            return self if self.camera is None else replace(self, camera=None)
        return replace(self, camera=self.viewpoint + np.asarray(camera_offset_m, dtype=np.float64).reshape(3))


@dataclass(frozen=True, eq=False)
class ViewCentroids:
    """Where a cluster's centroid may lie in the object frame, per viewing direction: ``centroids[a, k]`` (3,) is
    the mean of the model's surface samples seen from ``directions[k]`` (unit, object frame, from the object
    towards the sensor; a near-uniform Fibonacci set) under rule ``a``. Seen = the outward normal faces the
    direction and no sample hides it, in an orthographic depth buffer of ``cell_m`` cells: rule 0 keeps the
    samples at most ``cell_m`` behind the nearest one of their cell (a strict buffer: it drops the grazing samples
    of a convex surface, on a sphere the centroid is 0.63 r towards the sensor instead of r/2), rule 1 those in
    front of the first jump in depth larger than ``depth_gap_m`` (another sheet of surface; a sphere: r/2).
    NaN where no sample faces the direction. They are starting points of the translation steps of
    :func:`search_hypotheses`, which pull a start in from up to 3 cm. Measured on the catalogue benchmark's scans at
    the true orientation: the butterfly valve's starts are 0.2-1.3 cm from the true translation (the radius rule's
    ~10 cm), the gate valve's (body and handwheel) 2.3-3.8 cm (radius rule: 5-5.5 cm); no single rule is best for
    both."""

    directions: np.ndarray
    centroids: np.ndarray

    @classmethod
    def build(cls, points: np.ndarray, normals: np.ndarray, n_directions: int = 256, cell_m: float = 0.01,
              depth_gap_m: float = 0.015) -> "ViewCentroids":
        n_directions = check_int("n_directions", n_directions, caller="ViewCentroids.build", minimum=1)
        pts = np.asarray(points, dtype=np.float64)
        nrm = np.asarray(normals, dtype=np.float64)
        i = np.arange(n_directions) + 0.5
        z = 1.0 - 2.0 * i / n_directions
        phi = np.pi * (1.0 + 5.0 ** 0.5) * i
        rho = np.sqrt(np.maximum(1.0 - z * z, 0.0))
        dirs = np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])
        cent = np.full((2, n_directions, 3), np.nan)  # NaN: no sample faces the direction (no start from it)
        for k, v in enumerate(dirs):
            facing = nrm @ v > 0.0
            if not facing.any():
                continue
            p = pts[facing]
            a = np.cross(v, [0.0, 0.0, 1.0] if abs(v[2]) < 0.9 else [1.0, 0.0, 0.0])
            a /= np.linalg.norm(a)
            b = np.cross(v, a)
            i0 = np.floor(p @ a / cell_m).astype(np.int64)
            j0 = np.floor(p @ b / cell_m).astype(np.int64)
            key = (i0 - i0.min()) * (int(j0.max() - j0.min()) + 1) + (j0 - j0.min())
            depth = p @ v  # larger = nearer the sensor
            order = np.lexsort((-depth, key))  # per cell, nearest first
            ks, ds, ps = key[order], depth[order], p[order]
            same = np.r_[False, ks[1:] == ks[:-1]]
            start = np.flatnonzero(~same)
            counts = np.diff(np.r_[start, len(order)])
            cent[0, k] = ps[ds >= np.repeat(ds[start], counts) - cell_m].mean(axis=0)
            seen = np.cumsum(same & (np.r_[np.inf, ds[:-1]] - ds > depth_gap_m))  # a jump: another sheet begins
            cent[1, k] = ps[seen == np.repeat(seen[start], counts)].mean(axis=0)
        return cls(np.ascontiguousarray(dirs), np.ascontiguousarray(cent))

    @classmethod
    def build_cached(cls, points: np.ndarray, normals: np.ndarray, n_directions: int = 256, cell_m: float = 0.01,
                     depth_gap_m: float = 0.015) -> "ViewCentroids":
        """:meth:`build` through the on-disk cache (:mod:`semslam._cache`): ~60 ms per class, which a cold
        ``semslam recognize`` would otherwise pay for every class it estimates a pose of."""
        from .._cache import cached_arrays

        pts = np.ascontiguousarray(points, dtype=np.float64)
        nrm = np.ascontiguousarray(normals, dtype=np.float64)

        def build() -> dict:
            v = cls.build(pts, nrm, n_directions=n_directions, cell_m=cell_m, depth_gap_m=depth_gap_m)
            return {"directions": v.directions, "centroids": v.centroids}

        a = cached_arrays("view_centroids_v1", [pts, nrm, int(n_directions), float(cell_m), float(depth_gap_m)], build)
        return cls(np.ascontiguousarray(a["directions"], dtype=np.float64),
                   np.ascontiguousarray(a["centroids"], dtype=np.float64))

    def lookup(self, directions: np.ndarray) -> np.ndarray:
        """The centroids (A, K, 3) of the stored direction nearest to each of ``directions`` (K, 3)."""
        return self.centroids[:, np.argmax(np.asarray(directions) @ self.directions.T, axis=1)]


@dataclass(frozen=True, eq=False)
class RadiusGrid:
    """Model points bucketed in cubic cells of edge ``cell_m``, for exact nearest-neighbour queries within a
    bound <= ``cell_m`` (:meth:`query`: the same distances and indices as ``cKDTree.query(..., k=1,
    distance_upper_bound=bound)``, exact ties aside; ~2x faster on clusters of a few hundred points, as
    only the 27 cells around each point are visited). :meth:`build` returns None when the model's bounding
    box would need more than ``max_cells`` cells (use the KD-tree then)."""

    points: np.ndarray
    origin: np.ndarray
    cell_m: float
    dims: np.ndarray
    cell_start: np.ndarray
    cell_points: np.ndarray

    @classmethod
    def build(cls, points: np.ndarray, cell_m: float, *, max_cells: int = 1 << 22) -> "RadiusGrid | None":
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if len(pts) == 0 or not np.isfinite(pts).all():
            return None
        origin = pts.min(axis=0)
        ijk = np.floor((pts - origin) / cell_m).astype(np.int64)
        dims = ijk.max(axis=0) + 1
        if float(np.prod(dims.astype(np.float64))) > max_cells:
            return None
        keys = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
        order = np.argsort(keys, kind="stable")
        start = np.searchsorted(keys[order], np.arange(int(np.prod(dims)) + 1)).astype(np.int64)
        return cls(pts, origin, float(cell_m), dims.astype(np.int64), start, order.astype(np.int64))

    def query(self, points: np.ndarray, bound_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Distances (N,) (inf beyond ``bound_m``) and indices (N,) (``len(points)`` beyond) of the nearest
        model point of each of ``points`` (N, 3); ``bound_m`` must not exceed ``cell_m``."""
        return K.grid_nearest(np.ascontiguousarray(points, dtype=np.float64), self.points, self.origin,
                              1.0 / self.cell_m, self.dims, self.cell_start, self.cell_points, float(bound_m))
