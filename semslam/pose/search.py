"""Global pose search of a partial scan of a known object: a deterministic SO(3) grid of orientations,
a translation aligned per orientation on a precomputed distance field of the model, and a score that
adds a visibility (free-space) term to the fit.

The fit alone cannot separate the near-ambiguous flips of partial views of pipe fittings (a 180-degree
flip of a tee fits its visible half almost as well). The visibility term can: under a wrong
orientation the model predicts surface where the scanner saw nothing (or in front of what it saw).

* :func:`so3_grid`: super-Fibonacci rotations (Alexa, CVPR 2022), nearly uniform and deterministic.
* :class:`DistanceField`, :class:`RangeImage`, :class:`ViewCentroids`, :class:`RadiusGrid`: the model's and the
  scene's indexes (:mod:`.search_index`, re-exported here).
* :class:`RotationHierarchy`: a coarse grid over the fine one (coarse-to-fine ranking).
* :func:`search_hypotheses`: every grid orientation scored; returns the best distinct hypotheses.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .._validation import check_int
from ..symmetry import Symmetry
from . import _search_kernels as K
from .search_index import DistanceField, RadiusGrid, RangeImage, ViewCentroids  # noqa: F401 (re-exported)

#: how much better (the normalised fit cost of :func:`search_hypotheses`, 0-1) a partial cluster's start off the
#: expected depth (along the view) must fit than the best start across it. Chosen on the shared models' seeds 0 and 3:
#: 0 lets a border-cut strip of the flat valve-panel base (12 mm thick) take the pose with its far face on the seen
#: one, lifted 12-14 mm towards the sensor (within the visibility test's 10 mm at its slant): 16 of its 30 poses on
#: seed 3; 0.1 none of the 4 strips looked at (0.05: 2), and the panel front's strips (0.1-0.4 better) are still
#: found. Held out, some strips of seeds 2 and 4 still take it (benchmarks/history/real-models.md, session 19)
PARTIAL_DEPTH_MARGIN = 0.1
#: the shifts (m) of the best hypothesis along the view from which :func:`_depth_twin` looks for the same orientation
#: at another depth (a flat plate's far face on the seen one: 12 mm for the shared valve-panel base)
DEPTH_TWIN_SHIFTS_M = (-0.024, -0.018, -0.012, -0.006, 0.006, 0.012, 0.018, 0.024)
#: how far (m, along the view) a translation must end from the best hypothesis's to be its depth twin
DEPTH_TWIN_MIN_M = 0.005
#: the default truncations (m) of :func:`search_hypotheses`'s translation-only steps, one step each
#: (``PoseConfig.translation_steps_m``)
TRANSLATION_STEPS_M = (0.03, 0.015, 0.008, 0.008, 0.006)
#: A partial cluster's grid of starts (:func:`_partial_offsets`) of at most this many is searched whole. A larger one
#: (a part larger than ~0.5 m across at 4 cm: a 1.4 m UXO body has ~2,200 starts, each aligned under every
#: orientation, seconds per sighting) keeps, when the floor it rests on and its up are known, only the starts whose
#: object origin lies within a band of its resting height (:func:`resting_height_bands`). Every class of the
#: benchmarks chosen on holds fewer (at most 232: the unseen parts' anode) and is searched as before.
MAX_FREE_STARTS = 256
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
class Hypothesis:
    """A pose hypothesis ``T_object_scanner`` (4, 4) with its fit, visibility and total costs. A ``depth_twin``
    (:func:`_depth_twin`) is the best hypothesis's orientation at another depth along the view: refined and scored
    for the pose covariance's spread, never chosen."""

    T_object_scanner: np.ndarray
    fit: float
    visibility: float
    score: float
    depth_twin: bool = False


def rotation_distances(R_a: np.ndarray, R_bs: np.ndarray, symmetry: Symmetry) -> np.ndarray:
    """Angles (K,) between the object orientations ``R_a^T`` and ``R_bs[k]^T`` modulo the symmetry, for
    ``R`` = rotations of ``T_object_scanner`` (the object's orientation in the scanner is ``R^T``)."""
    return pairwise_rotation_distances(np.asarray(R_a)[None], np.asarray(R_bs), symmetry)[0]


def pairwise_rotation_distances(R_as: np.ndarray, R_bs: np.ndarray, symmetry: Symmetry) -> np.ndarray:
    """Angles (A, B) between ``R_as[i]^T`` and ``R_bs[j]^T`` modulo the symmetry (see :func:`rotation_distances`)."""
    if symmetry.kind == "continuous":
        a = symmetry.axis_object
        ua, ub = np.einsum("i,kij->kj", a, R_as), np.einsum("i,kij->kj", a, R_bs)  # axes R^T a
        c = ua @ ub.T
        return np.arccos(np.clip(np.abs(c) if symmetry.flip else c, -1.0, 1.0))
    tr = np.full((len(R_as), len(R_bs)), -1.0)
    for S in symmetry.group_rotations():  # object frame: R_obj S  <=>  S^T R ; angle of S^T R_a R_b^T
        tr = np.maximum(tr, np.einsum("aij,bij->ab", np.einsum("ji,ajk->aik", S, R_as), R_bs))
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))


def search_hypotheses(points: np.ndarray, viewpoint: np.ndarray, field: DistanceField, rotations: np.ndarray,
                      model_vis_pts: np.ndarray, model_vis_nrm: np.ndarray, *, object_radius_m: float,
                      symmetry: Symmetry, image_cell_m: float, tau_m: float, visibility_weight: float,
                      visibility_tol_m: float, truncations_m: tuple = TRANSLATION_STEPS_M,
                      n_keep: int = 5, n_candidates: int = 512, n_coarse_points: int = 48,
                      min_separation_rad: float = np.radians(20.0), hierarchy: RotationHierarchy | None = None,
                      n_coarse_keep: int = 128, view_centroids: "ViewCentroids | None" = None,
                      start_separation_m: float = 0.015, local_steps_rad: tuple = (),
                      camera_offset_m: tuple | None = None, partial_step_m: float = 0.0, start_heights=None,
                      surroundings: np.ndarray | None = None, scene: tuple | None = None) -> tuple[list, RangeImage]:
    """Score every orientation of ``rotations`` (``R`` of ``T_object_scanner``) and keep the ``n_keep``
    best hypotheses more than ``min_separation_rad`` apart (modulo the symmetry). The fit of ``n_coarse_points`` of
    the points ranks all orientations; the ``n_candidates`` best are aligned, fitted with all, get the visibility.

    With a ``hierarchy`` over ``rotations``, the first ranking is coarse to fine: the coarse grid is ranked, and only
    the children of its ``n_coarse_keep`` best orientations are ranked in ``rotations``.

    ``points`` (N, 3) is the (downsampled) cluster in the scanner frame. The translation starts with the
    cluster's centroid mapped ``object_radius_m / 2`` from the object's origin towards the scanner and, given
    ``view_centroids`` (:class:`ViewCentroids`), also onto the centroids of the model surface seen from the
    scanner under the orientation, where these are more than ``start_separation_m`` from the first; each start
    is aligned by translation-only steps on the distance field (one per entry of ``truncations_m``, the first
    3 cm: a start farther than that from the true translation is never pulled in) and the best fit is kept. The
    visible-surface starts matter for parts whose origin (bounding-box centre) is far from their surface, e.g. an
    L-shaped valve (ring and lever): there the radius rule starts ~10 cm off. ``partial_step_m`` > 0 (a cluster
    cut by the scan's border) adds the starts of :func:`_partial_offsets` within ``object_radius_m`` of the first
    (:func:`_resting_starts` of ``start_heights``): the part seen may lie anywhere on the object; a start off the
    first's depth wins only by :data:`PARTIAL_DEPTH_MARGIN`, and the best start of the best orientation at another
    depth is returned last as its ``depth_twin`` (:func:`_depth_twin`) when it fits within that margin. The range
    image of the visibility term is that of ``points`` with ``surroundings`` (K, 3: the scan's other objects about
    the cluster), or :meth:`RangeImage.build_scene` of a ``scene`` (scene, occluders; beyond the border unknown).

    ``local_steps_rad`` (e.g. 8, 4 then 2 degrees; () = none): each kept hypothesis is then refined on a local
    3 x 3 x 3 grid of rotations per step (:func:`_local_refine`), returned after its original when it differs (both
    are worth an ICP: on a border-cut butterfly valve the refined start scored better, its ICP ended worse)."""
    c = points.mean(axis=0)
    view = viewpoint - c
    view /= max(np.linalg.norm(view), 1e-12)
    sub = np.ascontiguousarray(points[np.linspace(0, len(points) - 1, min(len(points), n_coarse_points)).astype(int)])
    coarse_truncations, fine = (np.asarray(t, dtype=np.float64) for t in (truncations_m[:-2], truncations_m[-2:]))

    starts = _TranslationStarts(field, view, c, object_radius_m, view_centroids, start_separation_m, float(tau_m),
                                _resting_starts(_partial_offsets(view, object_radius_m, partial_step_m),
                                                c - 0.5 * object_radius_m * view, start_heights))
    Rs = np.ascontiguousarray(rotations, dtype=np.float64)
    if hierarchy is not None and n_coarse_keep < len(hierarchy.coarse):
        Rc = np.ascontiguousarray(hierarchy.coarse, dtype=np.float64)
        fitc = starts.best_aligned(Rc, sub, coarse_truncations)[0]
        Rs = np.ascontiguousarray(Rs[hierarchy.children_of(np.argsort(fitc, kind="stable")[:n_coarse_keep])])
    # coarse to fine: every orientation with a few points, then the best n_candidates with all of them
    fit0, ts = starts.best_aligned(Rs, sub, coarse_truncations)
    cand = np.argsort(fit0, kind="stable")[:n_candidates]
    Rs, ts = np.ascontiguousarray(Rs[cand]), np.ascontiguousarray(ts[cand])
    fit = K.align_and_score(Rs, ts, np.ascontiguousarray(points), field.params, field.cell_m, field.offsets, fine,
                            float(tau_m))
    # the visibility term on the n_candidates best fits only (it costs ~model size per hypothesis)
    cand = np.argsort(fit, kind="stable")[:n_candidates]
    image = (RangeImage.build(points, viewpoint, cell_m=image_cell_m, extra_points=surroundings) if scene is None
             else RangeImage.build_scene(scene[0], viewpoint, points, cell_m=image_cell_m, occluder_points=scene[1])
             ).with_camera(camera_offset_m)
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
    twin = _depth_twin(out[0], points, view, field, image, model_vis_pts, model_vis_nrm, fine, tau_m, visibility_weight,
                       visibility_tol_m) if out and partial_step_m > 0 else None
    return out + ([twin] if twin is not None else []), image


def _depth_twin(h: Hypothesis, points: np.ndarray, view: np.ndarray, field: DistanceField, image: RangeImage,
                model_vis_pts: np.ndarray, model_vis_nrm: np.ndarray, truncations: np.ndarray, tau_m: float,
                visibility_weight: float, visibility_tol_m: float) -> Hypothesis | None:
    """The orientation of ``h`` at another depth: its translation shifted along the unit ``view`` (scanner frame) by
    each of :data:`DEPTH_TWIN_SHIFTS_M`, aligned with the fine ``truncations`` (so that a start stays in the basin it
    is in), and the best fit of those ending more than :data:`DEPTH_TWIN_MIN_M` from ``h`` along the view, when it
    fits within :data:`PARTIAL_DEPTH_MARGIN` of ``h`` (else None). A part of a cluster cut by the scan's border can
    sit at two depths (a flat plate's seen face is its near or its far face, the plate 12 mm apart); the search
    keeps one translation per orientation, so the covariance would not know of the other."""
    R, t = h.T_object_scanner[:3, :3], h.T_object_scanner[:3, 3]
    shifts = np.asarray(DEPTH_TWIN_SHIFTS_M)
    Rs = np.ascontiguousarray(np.broadcast_to(R, (len(shifts), 3, 3)))
    ts = np.ascontiguousarray(t + shifts[:, None] * (R @ view))  # the cluster moved by s view: t + R (s view)
    fit = K.align_and_score(Rs, ts, np.ascontiguousarray(points), field.params, field.cell_m, field.offsets,
                            truncations, float(tau_m))
    depth = (ts - t) @ (R @ view)  # how far each ended from h along the view
    ok = np.flatnonzero((np.abs(depth) > DEPTH_TWIN_MIN_M) & (fit < h.fit + PARTIAL_DEPTH_MARGIN))
    if not len(ok):
        return None
    k = ok[np.argmin(fit[ok])]
    vis = float(image.visibility_cost(Rs[k:k + 1], ts[k:k + 1], model_vis_pts, model_vis_nrm, visibility_tol_m)[0])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, ts[k]
    return Hypothesis(T, float(fit[k]), vis, float(fit[k]) + visibility_weight * vis, depth_twin=True)


@dataclass(frozen=True, eq=False)
class _TranslationStarts:
    """The translation starts of an orientation in :func:`search_hypotheses`: the cluster's ``centroid`` mapped
    ``object_radius_m / 2`` from the object's origin towards the scanner (``view``: the unit direction from the
    centroid to the scanner, scanner frame) and, given ``view_centroids``, the centroids of the model surface seen
    from the scanner where these are more than ``start_separation_m`` from the first; then the first shifted by
    each of ``offsets`` (K, 3), scanner frame (a partial cluster: :func:`_partial_offsets`)."""

    field: DistanceField
    view: np.ndarray
    centroid: np.ndarray
    object_radius_m: float
    view_centroids: "ViewCentroids | None"
    start_separation_m: float
    tau_m: float
    offsets: np.ndarray

    def best_aligned(self, R: np.ndarray, src: np.ndarray, truncations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The fit (H,) and translation (H, 3) of the best start of each orientation after translation steps."""
        field = self.field
        flat = R.reshape(-1, 3)  # (R.reshape(-1, 3) @ v).reshape(-1, 3): the bits of R @ v, faster
        towards = (flat @ self.view).reshape(-1, 3)  # the direction to the scanner, object frame
        radius = 0.5 * self.object_radius_m * towards
        rc = (flat @ self.centroid).reshape(-1, 3)
        best_t = np.ascontiguousarray(radius - rc)
        best_fit = K.align_and_score(R, best_t, src, field.params, field.cell_m, field.offsets, truncations,
                                     self.tau_m)
        for anchor in self.view_centroids.lookup(towards) if self.view_centroids is not None else ():
            far = np.flatnonzero(np.linalg.norm(anchor - radius, axis=1) > self.start_separation_m)  # NaN: False
            if not len(far):
                continue
            Rf, t = np.ascontiguousarray(R[far]), np.ascontiguousarray(anchor[far] - rc[far])
            fit = K.align_and_score(Rf, t, src, field.params, field.cell_m, field.offsets, truncations, self.tau_m)
            better = fit < best_fit[far]
            best_fit[far[better]], best_t[far[better]] = fit[better], t[better]
        first = radius - rc
        for d in self.offsets:  # the cluster shifted by d in the scanner frame: t + R d
            t = np.ascontiguousarray(first + (flat @ d).reshape(-1, 3))
            # a start off the expected depth must fit clearly better: a flat plate's seen face fits the far face of
            # the plate lifted towards the sensor as well as its own, and only the first keeps it where it lies
            bound = best_fit - (PARTIAL_DEPTH_MARGIN if abs(float(d @ self.view)) > 1e-9 else 0.0)
            fit = K.align_and_score_below(R, t, src, field.params, field.cell_m, field.offsets, truncations,
                                          self.tau_m, bound)
            better = fit < bound
            best_fit[better], best_t[better] = fit[better], t[better]
        return best_fit, best_t


def resting_height_bands(points_object: np.ndarray, ups_object: np.ndarray, step_m: float) -> np.ndarray:
    """The heights (B, 2: low, high; m) above the floor at which the object's origin may start the search of a partial
    cluster, one band per up direction ``ups_object`` (B, 3; object frame): the origin's height when the object rests
    upright on the floor (its lowest point ``points_object`` on it), plus or minus two grid steps ``step_m`` (the
    grid's layers along the view are two steps apart: at least one is kept)."""
    ups = np.asarray(ups_object, dtype=float).reshape(-1, 3)
    ups = ups / np.linalg.norm(ups, axis=1, keepdims=True)
    rest = -np.min(np.asarray(points_object, dtype=float) @ ups.T, axis=0)  # the origin above the lowest point
    return np.column_stack([rest - 2.0 * step_m, rest + 2.0 * step_m])


def _resting_starts(offsets: np.ndarray, first_origin: np.ndarray, start_heights: tuple | None) -> np.ndarray:
    """``offsets`` (K, 3) as they are when they are at most :data:`MAX_FREE_STARTS` or ``start_heights`` is None;
    else those whose start puts the object's origin (``first_origin - offset``, scanner frame) at a height above the
    floor of ``start_heights`` = ((unit normal, d), bands (B, 2)) within one of the bands, in their order."""
    if start_heights is None or len(offsets) <= MAX_FREE_STARTS:
        return offsets
    (n, d), bands = start_heights
    heights = (first_origin - offsets) @ n + d
    keep = np.any((heights[:, None] >= bands[None, :, 0]) & (heights[:, None] <= bands[None, :, 1]), axis=1)
    return offsets[keep]


def _partial_offsets(view: np.ndarray, radius_m: float, step_m: float) -> np.ndarray:
    """The nonzero points (K, 3) within ``radius_m`` of the origin of a grid of spacing ``step_m`` across the unit
    ``view`` and ``2 step_m`` along it (layers: about half the starts of a cubic grid, 50 instead of 92 for a
    12 cm part at 4 cm, and the shared valve panel's front strips still found); the layer across the view (the
    plane through the origin perpendicular to ``view``) first, then the others by their distance along it; (0, 3)
    when ``step_m`` is 0."""
    if not step_m > 0:
        return np.zeros((0, 3))
    a = np.cross(view, [1.0, 0.0, 0.0] if abs(view[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(view, a)
    n = int(radius_m // step_m)
    i, j, k = (g.ravel() for g in np.meshgrid(*[np.arange(-n, n + 1)] * 3, indexing="ij"))
    keep = ((i != 0) | (j != 0) | (k != 0)) & ((i * i + j * j + k * k) * step_m ** 2 <= radius_m ** 2) & (k % 2 == 0)
    i, j, k = i[keep], j[keep], k[keep]
    o = np.argsort(np.abs(k), kind="stable")  # the layer across the view first, then deeper and nearer ones
    return step_m * (i[o, None] * a + j[o, None] * b + k[o, None] * view)


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
    on the distance field and scored as in :func:`search_hypotheses` (fit + weighted visibility cost). The search's
    grid is ~10 degrees apart, and for a large object (the gate valve, whose handwheel is 14 cm from its centre) that
    is beyond the ICP's basin: a start 10 degrees off moves the far points by ~2.5 cm, and the ICP stops in a wrong
    minimum."""
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
