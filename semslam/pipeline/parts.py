"""Part-based hypotheses: several clusters, one object.

Euclidean clustering splits an object wherever the scanner does not see what joins its parts: the gate valve's
handwheel is a cluster 6 cm from its body (its 1 cm stem unseen from the survey route), the ball valve's lever
one 2-3 cm from its body. Neither part alone matches any view, so both are reported unknown.

:func:`merge_parts` (``PipelineConfig(parts=PartsConfig())``, opt-in) runs after the per-cluster pipeline of
:meth:`~semslam.pipeline.ScanRecognizer.recognize`. Every cluster left unknown may seed a union with the
unknown clusters nearest to it (gap between their points at most ``max_gap_factor`` times the segmentation's
cluster tolerance, at most ``max_candidates`` of them, ``max_parts`` clusters per union, and the union no
longer than the longest class of the database allows). A union goes through the same recognition as a cluster
(descriptor, match and rejection, size test, pose, hypothesis verification with ``PipelineConfig.verify_*``; the
next classes when its nearest fails, ``verify_next_classes``, unless one of its clusters was recognised alone)
and is kept only if, in addition, **every part** is on the class's surface under the union's pose (share of its
points within ``PoseConfig.icp_max_correspondence_m`` of the model at least ``min_part_fitness``): a rock or a
pipe offcut beside an object does not fit the object's model, so it cannot ride along on a union whose overall
fitness the object's own points carry. With ``PartsConfig(scene_visibility=True)`` a union's visibility cost is
verified against the whole scan, not the union's points. Unions that pass are kept greedily (most points first, then
the better
fitness), each cluster in at most one.

The parts of a kept union get the union's class and its one :class:`~semslam.detection.Detection` (with
``extras["parts"]`` = the cluster indices); ``RecognitionResult.detections`` holds it once. The stage needs pose
verification (``verify_min_fitness``), since the descriptor alone accepts clutter.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from .._validation import check_int, check_positive
from ..detection import Detection
from ..errors import DescriptorError, InputError
from ..recognition import UNKNOWN_LABEL
from ..recognition.plausibility import principal_extent
from ._scan_helpers import _input_indices
from .hypothesis import Hypothesis, pose_and_verify
from .scan_records import ClusterOutcome, ScanContext
from .stages import next_classes

__all__ = ["PartsConfig", "merge_parts"]

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PartsConfig:
    """Settings of the part-based hypotheses (:func:`merge_parts`; ``PipelineConfig.parts``).

    Attributes
    ----------
    max_gap_factor : float
        Two clusters may be parts of one object when the smallest distance between their points is at most
        this times the segmentation's (resolved) cluster tolerance. Default 3.5 (7 cm at the default 2 cm: the
        gate valve's handwheel is 5.8-6.0 cm from its body in the catalogue benchmark's scans).
    max_candidates : int
        Nearest unknown clusters (by gap) tried with each seed cluster. Default 3.
    max_parts : int
        Clusters per union, 2-4. Default 3 (4 in the ``cluttered`` and ``seabed`` presets: the catalogue benchmark's
        gate valve is seen in up to four pieces).
    min_part_fitness : float or None
        Share of every part's points that must lie within ``PoseConfig.icp_max_correspondence_m`` of the model
        under the union's pose (the union as a whole must pass ``PipelineConfig.verify_min_fitness``). Default
        0.8: on the catalogue benchmark (seed 0) the parts of the accepted unions scored 0.87-1.0 (a handwheel
        fragment 0.871), and a rock beside an object scores below 0.5 (``tests/pipeline/test_pipeline_parts.py``);
        None =
        ``verify_min_fitness``.
    max_unions : int
        Unions evaluated per scan at most (nearest gaps first), a bound on the time. Default 24.
    view_gaps : bool
        Learn each class's gap limit from its database views (module docstring, :func:`view_gap_limits`): the
        largest gap between parts of at least ``VIEW_PART_SHARE`` of a view's points, times
        ``VIEW_GAP_MARGIN``, never below ``max_gap_factor`` times the tolerance; a union must be within its
        class's limit. Default False (on in the ``seabed`` preset).
    scene_visibility : bool
        Verify a union's visibility cost against the whole scan (the scene image of
        ``PipelineConfig(verify_visibility_image="scene")``) instead of what ``verify_visibility_image`` says.
        A union is a partial segmentation by construction: a part of the object may have gone to another
        cluster (the gate valve's handwheel joined to the floor's leftovers when the valve stands on a flange),
        and against the union's own points the model's surface there counts as a contradiction, although the
        scan has points there. Against the scene, only model points in front of what the scanner saw (free
        space) or behind a plane contradict. Default False.
    detected_parts : bool
        A cluster already recognised may be a part of a union with at least one unknown cluster, and a union that
        passes replaces the detections of its parts: a gate valve's body alone verifies as a blind flange (its end
        flange), and the union with its handwheel is the gate valve. Default False (on in the ``cluttered`` and
        ``seabed`` presets).
    fragments : bool
        After the unions, a cluster still unknown whose points lie on the surface of an object recognised in the
        same scan (at least ``min_part_fitness`` of them within ``PoseConfig.icp_max_correspondence_m`` of its
        posed model) is reported as a fragment of that object (:mod:`semslam.pipeline.fragments`): it gets the
        detection's class and its one detection, whose pose is unchanged. Default True.
    """

    max_gap_factor: float = 3.5
    max_candidates: int = 3
    max_parts: int = 3
    min_part_fitness: float | None = 0.8
    max_unions: int = 24
    scene_visibility: bool = False
    view_gaps: bool = False
    detected_parts: bool = False
    fragments: bool = True

    def __post_init__(self) -> None:
        c = "PartsConfig"
        check_positive("max_gap_factor", self.max_gap_factor, caller=c)
        check_int("max_candidates", self.max_candidates, caller=c, minimum=1)
        check_int("max_parts", self.max_parts, caller=c, minimum=2, maximum=4)
        check_int("max_unions", self.max_unions, caller=c, minimum=1)
        for name in ("scene_visibility", "view_gaps", "detected_parts", "fragments"):
            if not isinstance(getattr(self, name), bool):
                raise InputError(f"The {name!r} argument of {c} must be a bool. "
                                 f"Got {getattr(self, name)!r} instead.")
        if self.min_part_fitness is not None:
            check_positive("min_part_fitness", self.min_part_fitness, caller=c, allow_zero=True)
            if self.min_part_fitness > 1:
                raise InputError(f"The 'min_part_fitness' argument of {c} must be in [0, 1]. "
                                 f"Got {self.min_part_fitness!r} instead.")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


#: A view's part must hold at least this share of its points for its gap to count (a stray pair of points does not).
VIEW_PART_SHARE = 0.05
#: The learnt gap limit is the views' largest gap times this (the scan's sampling differs from the views').
VIEW_GAP_MARGIN = 1.15


def largest_part_gap(points_xyz_m: np.ndarray, tolerance_m: float, *, min_share: float = VIEW_PART_SHARE) -> float:
    """The widest gap that single-linkage joining of the clusters of ``points_xyz_m`` (Euclidean clusters at
    ``tolerance_m``) into one needs, counting only clusters of at least ``min_share`` of the points (0 when the
    points are one cluster): the longest edge of the minimum spanning tree between those clusters."""
    from ..segmentation import euclidean_labels

    p = np.ascontiguousarray(points_xyz_m, dtype=np.float64)
    n = len(p)
    if n < 2:
        return 0.0
    labels = euclidean_labels(p, tolerance_m=tolerance_m)
    counts = np.bincount(labels)
    parts = [p[labels == c] for c in np.flatnonzero(counts >= max(min_share * n, 1))]
    if len(parts) < 2:
        return 0.0
    trees = [cKDTree(q) for q in parts]
    dist = np.full((len(parts), len(parts)), np.inf)
    for i, j in itertools.combinations(range(len(parts)), 2):
        dist[i, j] = float(trees[i].query(parts[j], k=1)[0].min())
    return _spanning_gap(dist)


def view_gap_limits(db: Any, tolerance_m: float, floor_m: float) -> dict[str, float]:
    """Per class of ``db``: the gap two parts of one of its objects may have in a scan clustered at ``tolerance_m``,
    learnt from its views (``VIEW_GAP_MARGIN`` times the largest :func:`largest_part_gap` of its views), at least
    ``floor_m``."""
    out = {}
    for label in db.classes:
        widest = max((largest_part_gap(db.view_points(int(i)), tolerance_m) for i in db.views_of(label)), default=0.0)
        out[label] = max(float(floor_m), VIEW_GAP_MARGIN * widest)
    return out


def _gap_limits(rec: Any, tolerance_m: float) -> dict[str, float]:
    """The recogniser's per-class gap limits at ``tolerance_m`` (learnt once per tolerance when
    ``PartsConfig.view_gaps``, else ``max_gap_factor`` times the tolerance for every class)."""
    pcfg: PartsConfig = rec.config.parts
    floor = pcfg.max_gap_factor * tolerance_m
    if not pcfg.view_gaps:
        return {label: floor for label in rec.db.classes}
    cache = rec.__dict__.setdefault("_part_gap_limits", {})
    key = round(float(tolerance_m), 9)
    if key not in cache:
        cache[key] = view_gap_limits(rec.db, tolerance_m, floor)
    return cache[key]


def _eligible(outcome: ClusterOutcome, detected_parts: bool = False) -> bool:
    """Clusters that a union may use: unknown ones (not those too big for every class: a union is bigger still) and,
    with ``detected_parts``, recognised ones."""
    return (outcome.detection is None or detected_parts) and "for any class" not in outcome.reason


def _gaps(points: list[np.ndarray], limit_m: float) -> dict[tuple[int, int], float]:
    """Smallest point-to-point distance of every pair of ``points`` (lists of (N, 3)) within ``limit_m``."""
    lo = [p.min(axis=0) for p in points]
    hi = [p.max(axis=0) for p in points]
    trees: dict[int, cKDTree] = {}
    out = {}
    for i, j in itertools.combinations(range(len(points)), 2):
        box_gap = np.maximum(0.0, np.maximum(lo[i] - hi[j], lo[j] - hi[i]))
        if float(np.linalg.norm(box_gap)) > limit_m:
            continue
        a, b = (i, j) if len(points[i]) >= len(points[j]) else (j, i)
        if a not in trees:
            trees[a] = cKDTree(points[a])
        d = float(trees[a].query(points[b], k=1, distance_upper_bound=limit_m)[0].min())
        if d <= limit_m:
            out[(i, j)] = d
    return out


def _candidate_unions(n: int, gaps: dict, cfg: PartsConfig) -> list[tuple[int, ...]]:
    """Index tuples (sorted) of the unions to try, nearest gaps first, at most ``cfg.max_unions``."""
    neighbours: dict[int, list[tuple[float, int]]] = {i: [] for i in range(n)}
    for (i, j), d in gaps.items():
        neighbours[i].append((d, j))
        neighbours[j].append((d, i))
    scored: dict[tuple[int, ...], float] = {}
    for s in range(n):
        near = [j for _, j in sorted(neighbours[s])[:cfg.max_candidates]]
        for size in range(1, cfg.max_parts):
            for combo in itertools.combinations(near, size):
                key = tuple(sorted((s, *combo)))
                worst = max(gaps.get((min(s, j), max(s, j)), np.inf) for j in combo)
                scored[key] = min(scored.get(key, np.inf), worst)
    return [k for k, _ in sorted(scored.items(), key=lambda kv: (kv[1], len(kv[0]), kv[0]))][:cfg.max_unions]


def _widest_gap(members: tuple[int, ...], gaps: dict) -> float:
    """The longest edge of the minimum spanning tree joining ``members`` by the pairwise ``gaps`` (inf when they
    are not joined): :func:`_spanning_gap` on their gap matrix."""
    pos = {k: n for n, k in enumerate(members)}
    dist = np.full((len(members), len(members)), np.inf)
    for (a, b), d in gaps.items():
        if a in pos and b in pos:
            dist[pos[a], pos[b]] = d
    return _spanning_gap(dist)


def _spanning_gap(dist: np.ndarray) -> float:
    """The longest edge of the minimum spanning tree of the upper triangle of ``dist`` (inf: no edge; inf when the
    graph is not connected)."""
    from scipy.sparse.csgraph import connected_components, minimum_spanning_tree

    w = np.where(np.isfinite(dist), np.maximum(dist, 1e-12), 0.0)  # scipy: 0 is no edge
    if connected_components(np.triu(w, 1), directed=False)[0] > 1:
        return np.inf
    return float(minimum_spanning_tree(np.triu(w, 1)).toarray().max(initial=0.0))


def min_part_share(cfg: Any) -> float:
    """The share of a part's points that must lie on the posed model (``PartsConfig.min_part_fitness``, else the
    pipeline's ``verify_min_fitness``): every part of a union, and a fragment (:mod:`.fragments`)."""
    pcfg: PartsConfig = cfg.parts
    return pcfg.min_part_fitness if pcfg.min_part_fitness is not None else cfg.verify_min_fitness


def _part_fitness(rec: Any, det: Any, label: str, view_index: int, parts_points: list[np.ndarray]) -> list[float]:
    """Share of each part's points within ``icp_max_correspondence_m`` of the class's surface model
    (``ScanRecognizer.surface_model``: its pose-model and recognition views) under ``det``'s pose."""
    surface = rec.surface_model(label, view_index)
    bound = float(rec.config.pose.icp_max_correspondence_m)
    T_os = det.T_sensor_object.inverse().matrix
    out = []
    for p in parts_points:
        d = surface.distances(p @ T_os[:3, :3].T + T_os[:3, 3], bound)
        out.append(float(np.mean(np.isfinite(d))) if len(d) else 0.0)
    return out


def _recognized_unions(rec: Any, ctx: ScanContext, seg: Any, outcomes: list[ClusterOutcome], eligible: list[int],
                       seed: int, timings: dict) -> list[tuple]:
    """The candidate unions of the ``eligible`` clusters that are recognised, verified and whose every part fits:
    ``(points, fitness, cluster indices, detection, match, extent, touches border)`` each.

    :func:`merge_parts` keeps them greedily, the most points first (then the best fitness), none sharing a cluster
    with one kept before. The candidates are tried in that order, so a union sharing a cluster with one already
    kept from a union of more points is not tried at all (it could never be kept): the same unions are kept as when
    every candidate is tried, without posing those (each pose searches a grid of starts: most of a scan's time in
    a scene of parts). Unions of as many points are all tried before any of them is kept (the fitness decides)."""
    cfg = rec.config
    pcfg: PartsConfig = cfg.parts
    tolerance = float(seg.resolved.get("cluster_tolerance_m") or cfg.segmentation.cluster_tolerance_m)
    pts = [seg.clusters[k].points_xyz_m for k in eligible]
    limits = _gap_limits(rec, tolerance)
    gaps = _gaps(pts, max(limits.values()))
    unions = _candidate_unions(len(eligible), gaps, pcfg)
    raw = {k: _input_indices(seg, k) for k in eligible}
    members = [[eligible[i] for i in m] for m in unions]

    def evaluate(u: int) -> tuple | None:
        return _recognized_union(rec, ctx, seg, outcomes, members[u], [raw[k] for k in members[u]], gaps, unions[u],
                                 limits, seed + u, timings)

    return tried_in_keeping_order([sum(len(raw[k]) for k in m) for m in members], members, evaluate)


def kept_unions(accepted: list[tuple]) -> list[tuple]:
    """The entries of ``accepted`` (``(points, fitness, clusters, ...)``) :func:`merge_parts` keeps: the most points
    first, then the best fitness (then the order given), none sharing a cluster with one kept before."""
    used: set[int] = set()
    out = []
    for entry in sorted(accepted, key=lambda a: (-a[0], -a[1])):
        if not used & set(entry[2]):
            used |= set(entry[2])
            out.append(entry)
    return out


def tried_in_keeping_order(n_points: list[int], members: list[list[int]], evaluate) -> list[tuple]:
    """``evaluate(u)`` (an entry ``(points, fitness, clusters, ...)`` with ``points == n_points[u]``, or None) of the
    candidate unions in the order :func:`kept_unions` keeps them (the most points first, then the order given),
    skipping a candidate that shares a cluster with an entry kept among more points: it could never be kept. Unions
    of as many points are all evaluated before any is kept (the fitness decides among them). ``kept_unions`` of the
    result equals ``kept_unions`` of every candidate's entry."""
    accepted, group, kept = [], [], set()

    def keep_group() -> None:
        for entry in kept_unions(group):
            kept.update(entry[2])
        accepted.extend(group)
        group.clear()

    for u in sorted(range(len(members)), key=lambda u: (-n_points[u], u)):
        if group and n_points[u] != group[-1][0]:
            keep_group()
        if kept & set(members[u]):
            _log.debug("union %s: shares a cluster with a union of more points kept", members[u])
            continue
        entry = evaluate(u)
        if entry is not None:
            group.append(entry)
    keep_group()
    return accepted


def _recognized_union(rec: Any, ctx: ScanContext, seg: Any, outcomes: list[ClusterOutcome], ks: list[int],
                      raw: list[np.ndarray], gaps: dict, members: tuple, limits: dict, seed: int,
                      timings: dict) -> tuple | None:
    """Union ``ks`` (clusters; ``members`` their positions among the eligible ones, ``raw`` their input indices)
    recognised, posed and verified with every part on the surface: its entry of :func:`_recognized_unions`, or
    None."""
    cfg = rec.config
    if all(outcomes[k].detection is not None for k in ks):
        return None  # recognised parts only: each has its detection (PartsConfig.detected_parts)
    idx = np.concatenate([seg.cluster_indices[k] for k in ks])
    cloud = seg.segmented_cloud.select(idx)
    extent = principal_extent(np.ascontiguousarray(cloud.points_xyz_m, dtype=np.float64))
    if extent[0] > rec.max_plausible_extent_m():
        _log.debug("union %s: extent %.3f m too big", ks, extent[0])
        return None
    try:
        desc = rec.db.describe(cloud, seed=seed)
    except DescriptorError:
        return None
    match, label, view_index = rec.classify(desc)
    if label == UNKNOWN_LABEL:
        _log.debug("union %s: unknown (nearest %s, distance %.3g > %.3g)", ks, match.nearest_label, match.distance,
                   match.threshold)
        return None
    raw_idx = np.sort(np.concatenate(raw))
    border = any(outcomes[k].touches_border for k in ks)
    # the next classes when the nearest one fails, as a cluster's (PipelineConfig.verify_next_classes); not for a
    # union holding a recognised part: its verified detection gives way only to the union's nearest class
    nexts = cfg.verify_next_classes and all(outcomes[k].detection is None for k in ks)
    tries = [(label, view_index, match)] + [(m.label, m.view_index, m) for m in (
        next_classes(rec, match, label, extent) if nexts else ())]
    for label, view_index, found in tries:
        entry = _union_as(rec, ctx, seg, ks, raw, raw_idx, cloud, extent, border, (label, view_index, found),
                          _widest_gap(members, gaps) <= limits[label], seed, timings)
        if entry is not None:
            if found is not match:
                entry[3].extras["next_class_of"] = match.label  # the nearest class, whose pose failed
            return entry
    return None


def _union_as(rec: Any, ctx: ScanContext, seg: Any, ks: list[int], raw: list[np.ndarray], raw_idx: np.ndarray,
              cloud: Any, extent: np.ndarray, border: bool, as_class: tuple, gap_ok: bool, seed: int,
              timings: dict) -> tuple | None:
    """Union ``ks`` posed and verified as ``as_class`` (``(label, view_index, match)``): its entry of
    :func:`_recognized_unions`, or None."""
    cfg = rec.config
    label, view_index, match = as_class
    if cfg.size_tolerance is not None and extent[0] > rec.class_size_limit_m(label):
        _log.debug("union %s: extent %.3f m too big for %s", ks, extent[0], label)
        return None
    if not gap_ok:
        _log.debug("union %s: its parts too far apart for %s", ks, label)
        return None
    hyp = Hypothesis(raw_idx, cloud, label, view_index, match, border, union=True)
    det = pose_and_verify(rec, ctx, seg, hyp, seed=seed, timings=timings, what=f"union {ks}",
                          scene_visibility_cost=cfg.parts.scene_visibility)
    if det is None:
        return None
    fits = _part_fitness(rec, det, label, view_index, [ctx.scan.points_xyz_m[r] for r in raw])
    if min(fits) < min_part_share(cfg):
        _log.debug("union %s: %s, a part off the surface (part fitness %s)", ks, label, np.round(fits, 3))
        return None
    det.extras["parts"] = [int(k) for k in ks]
    det.extras["part_fitness"] = fits
    return len(raw_idx), det.fitness, ks, det, match, extent, border


def merge_parts(rec: Any, ctx: ScanContext, seg: Any, outcomes: list[ClusterOutcome], detections: list[Detection], *,
                seed: int, timings: dict) -> tuple[list[ClusterOutcome], list[Detection]]:
    """The part-based stage of one scan (see the module docstring): ``outcomes`` and ``detections`` (those of the
    stages before) with the unions of unknown clusters that were recognised (new lists). ``rec``: the
    :class:`~semslam.pipeline.scan.ScanRecognizer`; ``timings["parts"]`` gets the time (ms)."""
    t0 = time.perf_counter()
    cfg = rec.config
    outcomes, detections = list(outcomes), list(detections)
    eligible = [o.cluster_index for o in outcomes if _eligible(o, cfg.parts.detected_parts)]
    if cfg.border == "reject":
        eligible = [k for k in eligible if not outcomes[k].touches_border]
    timings["parts"] = 0.0
    if len(eligible) < 2:
        return outcomes, detections
    accepted = _recognized_unions(rec, ctx, seg, outcomes, eligible, seed, timings)
    for _, _, ks, det, match, extent, border in kept_unions(accepted):
        replaced = [outcomes[k].detection for k in ks if outcomes[k].detection is not None]
        detections = [d for d in detections if not any(d is r for r in replaced)] + [det]
        nearest = det.extras.get("next_class_of", match.nearest_label)
        reason = (f"detected as a union of clusters {ks}" + ("" if det.reliable else " (unreliable pose)")
                  + (f", as the next class (nearest {nearest})" if "next_class_of" in det.extras else "")
                  + (", touches the scan border" if border else ""))
        for k in ks:
            outcomes[k] = dataclasses.replace(outcomes[k], label=det.label, nearest_label=nearest,
                                              distance=match.distance, threshold=match.threshold, detection=det,
                                              reason=reason)
    timings["parts"] = (time.perf_counter() - t0) * 1e3
    return outcomes, detections
