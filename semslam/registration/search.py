"""Global pose search of a partial scan of a known object: a deterministic SO(3) grid of orientations,
a translation aligned per orientation on a precomputed distance field of the model, and a score that
adds a visibility (free-space) term to the fit.

The fit alone cannot separate the near-ambiguous flips of partial views of pipe fittings (a 180-degree
flip of a tee fits its visible half almost as well). The visibility term can: under a wrong
orientation the model predicts surface where the scanner saw nothing (or in front of what it saw).

* :func:`so3_grid`: super-Fibonacci rotations (Alexa, CVPR 2022), nearly uniform and deterministic.
* :class:`DistanceField`: per-cell nearest model point on a regular grid (object frame).
* :class:`RangeImage`: the cluster's smallest observed range per angular cell (scanner frame).
* :class:`ViewCentroids`: the centroid of the model surface facing each viewing direction (translation start).
* :class:`RotationHierarchy`: a coarse grid over the fine one (coarse-to-fine ranking).
* :func:`search_hypotheses`: every grid orientation scored; returns the best distinct hypotheses.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from .._validation import check_int
from ..symmetry import Symmetry
from . import _search_kernels as K

_PSI = 1.533751168755204288118041  # super-Fibonacci constant (Alexa 2022)


def so3_grid(n: int) -> np.ndarray:
    """``n`` nearly uniform, deterministic rotations ``(n, 3, 3)`` (super-Fibonacci spiral on S^3)."""
    n = check_int("n", n, caller="so3_grid", minimum=1)
    s = np.arange(n) + 0.5
    r, R = np.sqrt(s / n), np.sqrt(1.0 - s / n)
    a, b = 2.0 * np.pi * s / np.sqrt(2.0), 2.0 * np.pi * s / _PSI
    quat_xyzw = np.column_stack([r * np.sin(a), r * np.cos(a), R * np.sin(b), R * np.cos(b)])
    return Rotation.from_quat(quat_xyzw).as_matrix()


@dataclass(frozen=True, eq=False)
class RotationHierarchy:
    """A coarse SO(3) grid over a fine one for a coarse-to-fine search: ``coarse`` (C, 3, 3) rotations and,
    for each coarse rotation ``c``, its children ``children[offsets[c]:offsets[c + 1]]`` = indices of the
    fine rotations nearer to it than to any other coarse rotation (every fine rotation has one parent)."""

    coarse: np.ndarray
    children: np.ndarray
    offsets: np.ndarray

    @classmethod
    def build(cls, fine: np.ndarray, n_coarse: int) -> "RotationHierarchy":
        coarse = so3_grid(n_coarse)
        qf = Rotation.from_matrix(fine).as_quat()
        qc = Rotation.from_matrix(coarse).as_quat()
        parent = np.empty(len(fine), dtype=np.int64)
        for s in range(0, len(fine), 1024):  # |<q_f, q_c>| largest = smallest angle (q and -q are the same)
            parent[s:s + 1024] = np.argmax(np.abs(qf[s:s + 1024] @ qc.T), axis=1)
        order = np.argsort(parent, kind="stable")
        offsets = np.concatenate([[0], np.cumsum(np.bincount(parent, minlength=len(coarse)))])
        return cls(coarse, order, offsets)

    def children_of(self, coarse_indices: np.ndarray) -> np.ndarray:
        """Sorted fine-grid indices of the children of ``coarse_indices``."""
        coarse_indices = np.asarray(coarse_indices, dtype=np.int64)
        selected = np.zeros(len(self.coarse), dtype=bool)
        selected[coarse_indices] = True
        if np.count_nonzero(selected) == len(coarse_indices):  # distinct: a mask of the fine grid
            return np.flatnonzero(selected[self.parents])
        parts = [self.children[self.offsets[c]:self.offsets[c + 1]] for c in coarse_indices]
        return np.sort(np.concatenate(parts)) if parts else np.zeros(0, dtype=np.int64)

    @functools.cached_property
    def parents(self) -> np.ndarray:
        """Index (F,) of the coarse parent of every fine rotation."""
        parent = np.empty(len(self.children), dtype=np.int64)
        parent[self.children] = np.repeat(np.arange(len(self.coarse)), np.diff(self.offsets))
        return parent


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

    @classmethod
    def build(cls, points: np.ndarray, viewpoint: np.ndarray, *, cell_m: float, margin_m: float = 0.1,
              dilate: int = 1) -> "RangeImage":
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
        img = cls.build(pts, vp, cell_m=cell_m, margin_m=0.0, dilate=dilate)
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
        return cls(img.viewpoint, img.F, img.u0, img.v0, img.cell, img.range_min, occ_img)

    def visibility_cost(self, Rs: np.ndarray, ts: np.ndarray, model_pts: np.ndarray, model_nrm: np.ndarray,
                        tol_m: float, *, unseen_is_contradiction: bool = True) -> np.ndarray:
        """Share (H,) of the model points predicted visible under each hypothesis that contradict the scan. With
        ``unseen_is_contradiction`` False (an image of the scene, :meth:`build_scene`), model points where the
        scanner saw nothing are left out, and those behind what it saw are hidden (behind an object, when the image
        has ``occluder_min``), not contradictions."""
        return K.visibility_cost(np.ascontiguousarray(Rs), np.ascontiguousarray(ts), model_pts, model_nrm,
                                 self.viewpoint, self.F, self.u0, self.v0, 1.0 / self.cell, self.range_min, float(tol_m),
                                 bool(unseen_is_contradiction),
                                 self.range_min if self.occluder_min is None else self.occluder_min)


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
class Hypothesis:
    """A pose hypothesis ``T_object_scanner`` (4, 4) with its fit, visibility and total costs."""

    T_object_scanner: np.ndarray
    fit: float
    visibility: float
    score: float


def rotation_distances(R_a: np.ndarray, R_bs: np.ndarray, symmetry: Symmetry) -> np.ndarray:
    """Angles (K,) between the object orientations ``R_a^T`` and ``R_bs[k]^T`` modulo the symmetry, for
    ``R`` = rotations of ``T_object_scanner`` (the object's orientation in the scanner is ``R^T``)."""
    return pairwise_rotation_distances(np.asarray(R_a)[None], np.asarray(R_bs), symmetry)[0]


def pairwise_rotation_distances(R_as: np.ndarray, R_bs: np.ndarray, symmetry: Symmetry) -> np.ndarray:
    """Angles (A, B) between ``R_as[i]^T`` and ``R_bs[j]^T`` modulo the symmetry (see :func:`rotation_distances`)."""
    if symmetry.kind == "continuous":
        a = symmetry.axis_object
        ua, ub = np.einsum("i,kij->kj", a, R_as), np.einsum("i,kij->kj", a, R_bs)  # axes R^T a
        return np.arccos(np.clip(ua @ ub.T, -1.0, 1.0))
    tr = np.full((len(R_as), len(R_bs)), -1.0)
    for S in symmetry.group_rotations():  # object frame: R_obj S  <=>  S^T R ; angle of S^T R_a R_b^T
        tr = np.maximum(tr, np.einsum("aij,bij->ab", np.einsum("ji,ajk->aik", S, R_as), R_bs))
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))


def search_hypotheses(points: np.ndarray, viewpoint: np.ndarray, field: DistanceField, rotations: np.ndarray,
                      model_vis_pts: np.ndarray, model_vis_nrm: np.ndarray, *, object_radius_m: float,
                      symmetry: Symmetry, image_cell_m: float, tau_m: float, visibility_weight: float,
                      visibility_tol_m: float, truncations_m: tuple = (0.03, 0.015, 0.008, 0.008, 0.006),
                      n_keep: int = 5, n_candidates: int = 512, n_coarse_points: int = 48,
                      min_separation_rad: float = np.radians(20.0), hierarchy: RotationHierarchy | None = None,
                      n_coarse_keep: int = 128, view_centroids: "ViewCentroids | None" = None,
                      start_separation_m: float = 0.015, local_steps_rad: tuple = ()
                      ) -> tuple[list[Hypothesis], RangeImage]:
    """Score every orientation of ``rotations`` (``R`` of ``T_object_scanner``) and keep the ``n_keep``
    best hypotheses more than ``min_separation_rad`` apart (modulo the symmetry). The fit of
    ``n_coarse_points`` of the points ranks all orientations; the ``n_candidates`` best are aligned and fitted
    again with all the points and get the visibility term.

    With a ``hierarchy`` over ``rotations``, the first ranking is coarse to fine: the coarse grid is ranked,
    and only the children of its ``n_coarse_keep`` best orientations are ranked in ``rotations``.

    ``points`` (N, 3) is the (downsampled) cluster in the scanner frame. The translation starts with the
    cluster's centroid mapped ``object_radius_m / 2`` from the object's origin towards the scanner and, given
    ``view_centroids`` (:class:`ViewCentroids`), also onto the centroids of the model surface seen from the
    scanner under the orientation, where these are more than ``start_separation_m`` from the first; each start
    is aligned by translation-only steps on the distance field (one per entry of ``truncations_m``, the first
    3 cm: a start farther than that from the true translation is never pulled in) and the best fit is kept. The visible-surface starts matter for parts whose origin (bounding-box
    centre) is far from their surface, e.g. an L-shaped valve (ring and lever): there the radius rule starts
    ~10 cm off.

    ``local_steps_rad`` (e.g. 8, 4 then 2 degrees; () = none): each kept hypothesis is then refined on a local
    3 x 3 x 3 grid of rotations (+-step about each object axis, about the cluster's centroid) per step, with the
    same translation alignment and score, keeping the best (:func:`_local_refine`); the refined hypothesis is
    returned right after its original when it differs (both are worth an ICP: on a border-cut butterfly valve the
    refined start scored better but its ICP ended worse). The grid is ~10 degrees apart, and for a large object
    (the gate valve, whose handwheel is 14 cm from its centre) that is beyond the ICP's basin: a start 10 degrees
    off moves the far points by ~2.5 cm, and the ICP stops in a wrong minimum.
    """
    c = points.mean(axis=0)
    view = viewpoint - c
    view /= max(np.linalg.norm(view), 1e-12)
    sub = np.ascontiguousarray(points[np.linspace(0, len(points) - 1, min(len(points), n_coarse_points)).astype(int)])
    coarse_truncations = np.asarray(truncations_m[:-2], dtype=np.float64)

    def aligned_starts(R, src, truncations):
        """The fit (H,) and translation (H, 3) of the best start of each orientation after translation steps."""
        flat = R.reshape(-1, 3)  # (R.reshape(-1, 3) @ v).reshape(-1, 3): the bits of R @ v, faster
        towards = (flat @ view).reshape(-1, 3)  # the direction to the scanner, object frame
        radius = 0.5 * object_radius_m * towards
        rc = (flat @ c).reshape(-1, 3)
        best_t = np.ascontiguousarray(radius - rc)
        best_fit = K.align_and_score(R, best_t, src, field.params, field.cell_m, field.offsets, truncations,
                                     float(tau_m))
        for anchor in view_centroids.lookup(towards) if view_centroids is not None else ():
            far = np.flatnonzero(np.linalg.norm(anchor - radius, axis=1) > start_separation_m)  # NaN: False
            if not len(far):
                continue
            Rf, t = np.ascontiguousarray(R[far]), np.ascontiguousarray(anchor[far] - rc[far])
            fit = K.align_and_score(Rf, t, src, field.params, field.cell_m, field.offsets, truncations, float(tau_m))
            better = fit < best_fit[far]
            best_fit[far[better]], best_t[far[better]] = fit[better], t[better]
        return best_fit, best_t

    Rs = np.ascontiguousarray(rotations, dtype=np.float64)
    if hierarchy is not None and n_coarse_keep < len(hierarchy.coarse):
        Rc = np.ascontiguousarray(hierarchy.coarse, dtype=np.float64)
        fitc = aligned_starts(Rc, sub, coarse_truncations)[0]
        Rs = np.ascontiguousarray(Rs[hierarchy.children_of(np.argsort(fitc, kind="stable")[:n_coarse_keep])])
    # coarse to fine: every orientation with a few points, then the best n_candidates with all of them
    fit0, ts = aligned_starts(Rs, sub, coarse_truncations)
    cand = np.argsort(fit0, kind="stable")[:n_candidates]
    Rs, ts = np.ascontiguousarray(Rs[cand]), np.ascontiguousarray(ts[cand])
    fit = K.align_and_score(Rs, ts, np.ascontiguousarray(points), field.params, field.cell_m, field.offsets,
                            np.asarray(truncations_m[-2:], dtype=np.float64), float(tau_m))
    cand = np.arange(len(Rs))
    # the visibility term on the n_candidates best fits only (it costs ~model size per hypothesis)
    cand = np.argsort(fit, kind="stable")[:n_candidates]
    image = RangeImage.build(points, viewpoint, cell_m=image_cell_m)
    vis = image.visibility_cost(Rs[cand], ts[cand], model_vis_pts, model_vis_nrm, visibility_tol_m)
    score = fit[cand] + visibility_weight * vis
    order = np.argsort(score, kind="stable")
    kept = _greedy_distinct(Rs[cand[order]], symmetry, min_separation_rad, n_keep)
    out = []
    for i in kept:
        j = cand[order[i]]
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = Rs[j], ts[j]
        h0 = h = Hypothesis(T, float(fit[j]), float(vis[order[i]]), float(score[order[i]]))
        out.append(h0)
        for step in local_steps_rad:
            h = _local_refine(h, points, c, field, image, model_vis_pts, model_vis_nrm, float(step),
                              np.asarray(truncations_m[1:], dtype=np.float64), tau_m, visibility_weight,
                              visibility_tol_m)
        if h is not h0:  # both go to the ICP: a better search score is not always a better ICP start
            out.append(h)
    return out, image


@functools.lru_cache(maxsize=8)
def _local_rotations(step_rad: float) -> np.ndarray:
    """The 27 rotations (27, 3, 3) of the 3 x 3 x 3 grid of rotation vectors {-step, 0, step}^3 (identity first)."""
    g = np.array([0.0, -1.0, 1.0]) * step_rad
    vecs = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    return Rotation.from_rotvec(vecs).as_matrix()


def _local_refine(h: Hypothesis, points: np.ndarray, centroid: np.ndarray, field: DistanceField, image: RangeImage,
                  model_vis_pts: np.ndarray, model_vis_nrm: np.ndarray, step_rad: float, truncations: np.ndarray,
                  tau_m: float, visibility_weight: float, visibility_tol_m: float) -> Hypothesis:
    """The best of ``h`` and its 26 neighbours ``R' = D R`` (``D`` of :func:`_local_rotations`, a rotation of the
    object about the point ``m`` the cluster's centroid maps to: ``t' = D (t - m) + m``), each translation-aligned
    on the distance field and scored as in :func:`search_hypotheses` (fit + weighted visibility cost)."""
    D = _local_rotations(step_rad)
    R, t = h.T_object_scanner[:3, :3], h.T_object_scanner[:3, 3]
    m = R @ centroid + t
    Rs = np.ascontiguousarray(np.einsum("kij,jl->kil", D, R))
    ts = np.ascontiguousarray((t - m) @ D.transpose(0, 2, 1) + m)
    fit = K.align_and_score(Rs, ts, np.ascontiguousarray(points), field.params, field.cell_m, field.offsets,
                            truncations, float(tau_m))
    vis = image.visibility_cost(Rs, ts, model_vis_pts, model_vis_nrm, visibility_tol_m)
    score = fit + visibility_weight * vis
    k = int(np.argmin(score))
    if not score[k] < h.score:
        return h
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = Rs[k], ts[k]
    return Hypothesis(T, float(fit[k]), float(vis[k]), float(score[k]))


def _greedy_distinct(Rs_sorted: np.ndarray, symmetry: Symmetry, min_separation_rad: float, n_keep: int,
                     head: int = 16) -> list[int]:
    """Indices of the first ``n_keep`` rotations of ``Rs_sorted`` (best first) more than ``min_separation_rad``
    from every earlier kept one. The distances among the ``head`` best are computed first (the kept ones are
    almost always among them: the third within the best 8 on the simulator's scans); only if fewer than
    ``n_keep`` are found there are those among the ``4 head`` best, then the whole matrix computed."""
    for m in sorted({min(head, len(Rs_sorted)), min(4 * head, len(Rs_sorted)), len(Rs_sorted)}):
        D = pairwise_rotation_distances(Rs_sorted[:m], Rs_sorted[:m], symmetry)
        kept: list[int] = []
        for i in range(m):
            if kept and D[i, kept].min() < min_separation_rad:
                continue
            kept.append(i)
            if len(kept) >= n_keep:
                return kept
    return kept


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
