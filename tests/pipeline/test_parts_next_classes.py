"""A union of clusters whose nearest class fails is tried as the next classes (``PipelineConfig.verify_next_classes``),
as a single cluster is (tests/pipeline/test_next_classes.py): the catalogue's pieces of one fitting whose union is
nearest a neighbour of its family. The stage's control flow against a recogniser whose poses verify for chosen
classes only."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.detection import Detection
from semslam.pipeline import PipelineConfig, parts
from semslam.pipeline.parts import PartsConfig
from semslam.pipeline.scan_records import ClusterOutcome

from .test_next_classes import _Recognizer, plates_on_a_floor


@pytest.fixture(scope="module")
def two_plates():
    """A floor with two 12 mm plates 4 cm apart on it, segmented (each plate's top one cluster), and its
    ScanContext."""
    return plates_on_a_floor([(-0.12, -0.02), (0.02, 0.12)])


@pytest.fixture
def verifies_only(monkeypatch):
    """Union poses that verify for the classes given (None for the others), every part on the surface; the labels
    posed, in order."""
    posed = []

    def arm(*good):
        def pose(rec, ctx, seg, hyp, *, seed, timings, what, scene_visibility_cost):
            posed.append(hyp.label)
            if hyp.label not in good:
                return None
            return Detection(hyp.label, hyp.match.distance, np.eye(4), np.eye(6) * 1e-4, fitness=1.0, reliable=True)
        monkeypatch.setattr(parts, "pose_and_verify", pose)
        monkeypatch.setattr(parts, "_part_fitness", lambda rec, det, label, view_index, pts: [1.0] * len(pts))
        return posed
    return arm


def _union(rec, scene, gap_limits=None):
    ctx, seg = scene
    outcomes = [ClusterOutcome(k, c.n_points, "unknown", "", np.nan, np.nan, None, "rejected") for k, c in
                enumerate(seg.clusters)]
    raw = [seg.cluster_indices[k] for k in (0, 1)]
    limits = gap_limits or {c: 1.0 for c in ("flange", "valve", "plate", "elbow")}
    return parts._recognized_union(rec, ctx, seg, outcomes, [0, 1], raw, {(0, 1): 0.04}, (0, 1), limits, 0,
                                   {"descriptors": 0.0, "matching": 0.0})


def _config(**kw):
    return PipelineConfig(verify_min_fitness=0.95, parts=PartsConfig(), **kw)


def test_the_union_is_the_next_class_whose_pose_verifies(two_plates, verifies_only):
    posed = verifies_only("plate")
    entry = _union(_Recognizer(_config(verify_next_classes=2), "flange", ["valve", "plate", "elbow"]), two_plates)
    assert posed == ["flange", "valve", "plate"]
    n_points, fitness, ks, det, match = entry[:5]
    assert det.label == "plate" and ks == [0, 1] and det.extras["parts"] == [0, 1]
    assert match.label == "plate" and det.extras["next_class_of"] == "flange"  # the nearest class is recorded
    assert n_points == sum(c.n_points for c in two_plates[1].clusters)


def test_without_next_classes_the_union_is_its_nearest_class_alone(two_plates, verifies_only):
    """Catches unions that silently try other classes where the setting is off (every preset but seabed)."""
    posed = verifies_only("plate")
    assert _union(_Recognizer(_config(), "flange", ["plate"]), two_plates) is None
    assert posed == ["flange"]


def test_the_next_classes_are_at_most_the_configured_number_and_each_meets_its_size_and_gap(two_plates,
                                                                                          verifies_only):
    posed = verifies_only("plate")
    assert _union(_Recognizer(_config(verify_next_classes=1), "flange", ["valve", "plate"]), two_plates) is None
    assert posed == ["flange", "valve"]
    posed.clear()  # a class the union is too big for is not tried, nor counted
    cfg = _config(verify_next_classes=1, size_tolerance=0.1)
    entry = _union(_Recognizer(cfg, "flange", ["valve", "plate"], too_small=["valve"]), two_plates)
    assert posed == ["flange", "plate"] and entry[3].label == "plate"
    posed.clear()  # nor posed as a class whose parts are never this far apart
    limits = {"flange": 1.0, "valve": 1.0, "plate": 0.01}
    assert _union(_Recognizer(_config(verify_next_classes=2), "flange", ["valve", "plate"]), two_plates,
                  gap_limits=limits) is None
    assert posed == ["flange", "valve"]


def test_a_union_holding_a_recognised_part_is_its_nearest_class_alone(two_plates, verifies_only):
    """Catches a part's verified detection replaced by a union that only a next class explains (the real models'
    seed 0: a border-cut valve-panel front, recognised, and a sliver beside it taken for a wheel valve together)."""
    posed = verifies_only("plate")
    ctx, seg = two_plates
    rec = _Recognizer(_config(verify_next_classes=2), "flange", ["valve", "plate"])
    found = Detection("flange", 0.1, np.eye(4), np.eye(6) * 1e-4, fitness=1.0, reliable=True)
    outcomes = [ClusterOutcome(0, seg.clusters[0].n_points, "flange", "flange", 0.1, 1.0, found, "detected"),
                ClusterOutcome(1, seg.clusters[1].n_points, "unknown", "", np.nan, np.nan, None, "rejected")]
    limits = {c: 1.0 for c in ("flange", "valve", "plate")}
    assert parts._recognized_union(rec, ctx, seg, outcomes, [0, 1], [seg.cluster_indices[k] for k in (0, 1)],
                                   {(0, 1): 0.04}, (0, 1), limits, 0, {}) is None
    assert posed == ["flange"]
