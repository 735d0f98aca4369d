"""The next classes (``PipelineConfig.verify_next_classes``): a cluster whose nearest class fails hypothesis
verification is tried as the next-nearest classes the rejection accepts. ``Recognizer.other_classes`` is checked
against a brute-force chi-square search; the stage's control flow against a recogniser whose poses verify for
chosen classes only (the plate strip of benchmarks/real_models.py: nearer the flange, whose pose sinks into the
floor, than the plate)."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.cloud import PointCloud
from semslam.detection import Detection
from semslam.errors import InputError
from semslam.pipeline import PipelineConfig
from semslam.pipeline import stages
from semslam.pipeline.scan_records import scan_context
from semslam.recognition import Recognizer, ViewDescriptors
from semslam.recognition.database import ViewDatabase
from semslam.recognition.matching import chi2_distances
from semslam.recognition.recognizer import Match
from semslam.segmentation.scene import SegmentationConfig, segment_scene
from semslam.symmetry import Symmetry


def _database(rng) -> ViewDatabase:
    """Three classes of 6 views each, their ESF histograms in three blobs (labels a, b, c)."""
    centres = rng.gamma(2.0, size=(3, 640))
    X = np.vstack([c + rng.gamma(0.3, size=(6, 640)) for c in centres])
    y = np.repeat(np.array(list("abc")), 6)
    n = len(y)
    return ViewDatabase(y, np.array([f"v{i}" for i in range(n)]), np.arange(0, 3 * n + 1, 3),
                        np.zeros((3 * n, 3), np.float32), np.zeros((n, 3)), X.astype(np.float32),
                        np.ones((n, 308), np.float32),
                        {c: {"symmetry": Symmetry(), "size_xyz_m": np.ones(3)} for c in "abc"})


def test_other_classes_are_each_classes_nearest_view_nearest_first_within_its_threshold():
    rng = np.random.default_rng(3)
    db = _database(rng)
    rec = Recognizer(db, descriptor="esf", rejection="none")
    query = 0.2 * db.esf[2] + 0.8 * db.esf[8]  # between a view of a and one of b, nearer b
    desc = ViewDescriptors(query, db.vfh[0])
    d = chi2_distances(query[None], db.esf)[0]
    brute = sorted((float(d[i]), i) for c in "bc" for i in [min(np.flatnonzero(db.labels == c), key=d.__getitem__)])
    got = rec.other_classes(desc, "a")
    assert [m.view_index for m in got] == [i for _, i in brute]
    assert [m.distance for m in got] == pytest.approx([di for di, _ in brute], rel=1e-5)
    assert [m.label for m in got] == [str(db.labels[i]) for _, i in brute] and all(m.accepted for m in got)
    assert got[0].label == "b"  # the query is built from a view of b
    strict = Recognizer(db, descriptor="esf", rejection="global", reject_quantile=0.5)
    thr = strict.thresholds.global_threshold
    within = [str(db.labels[i]) for di, i in brute if di <= thr]
    assert [m.label for m in strict.other_classes(desc, "a")] == within == ["b"]  # c is beyond the threshold


class _Recognizer:
    """A stand-in for ScanRecognizer: the nearest class ``first``, then ``others`` in that order; every class's
    size limit 1 m but ``too_small``'s."""

    def __init__(self, config, first, others, too_small=()):
        self.config, self.db, self.recognizer = config, self, self
        self.first, self.others, self.too_small = first, others, set(too_small)

    def describe(self, cluster, seed):
        return ViewDescriptors(np.ones(640), np.ones(308))

    def classify(self, desc):
        return Match(self.first, 0, self.first, 0.1, 1.0, desc), self.first, 0

    def other_classes(self, desc, exclude):
        return [Match(c, i + 1, c, 0.2 + 0.1 * i, 1.0, desc) for i, c in enumerate(self.others) if c != exclude]

    def class_size_limit_m(self, label):
        return 0.01 if label in self.too_small else 1.0

    def max_plausible_extent_m(self):
        return 1.0


def plates_on_a_floor(x_ranges_m: list[tuple[float, float]]):
    """A floor 1 m below the scanner with 12 mm plates on it (x from-to each, 20 cm along y), segmented (the floor
    removed, each plate's top one cluster), and its ScanContext."""
    x, y = np.meshgrid(np.arange(-0.5, 0.5, 0.005), np.arange(-0.5, 0.5, 0.005), indexing="ij")
    floor = np.column_stack([x.ravel(), y.ravel(), np.ones(x.size)])
    lo, hi = min(a for a, _ in x_ranges_m), max(b for _, b in x_ranges_m)
    floor = floor[~((floor[:, 0] > lo) & (floor[:, 0] < hi) & (np.abs(floor[:, 1]) < 0.1))]
    plates = []
    for a, b in x_ranges_m:
        px, py = np.meshgrid(np.arange(a, b, 0.004), np.arange(-0.1, 0.1, 0.004), indexing="ij")
        plates.append(np.column_stack([px.ravel(), py.ravel(), np.full(px.size, 0.988)]))
    scan = PointCloud(np.vstack([floor] + plates))
    seg = segment_scene(scan, SegmentationConfig(max_planes=1), seed=0)
    assert len(seg.clusters) == len(x_ranges_m)
    ctx = scan_context(scan, default_up_scanner=None, seed=0, stamp_s=0.0, scan_id=0, point_stamps_s=None,
                       up_scanner=None)
    return ctx, seg


@pytest.fixture(scope="module")
def plate_scene():
    """A floor with a 12 mm plate on it, segmented (the floor removed, the plate's top one cluster), and its
    ScanContext."""
    return plates_on_a_floor([(-0.1, 0.1)])


@pytest.fixture
def verifies_only(monkeypatch):
    """Poses whose fitness is 1 for the classes given, 0.5 for the others; the labels posed, in order."""
    posed = []

    def arm(*good):
        def pose(rec, ctx, seg, hyp, *, seed, timings):
            posed.append(hyp.label)
            return Detection(hyp.label, hyp.match.distance, np.eye(4), np.eye(6) * 1e-4,
                             fitness=1.0 if hyp.label in good else 0.5, reliable=True)
        monkeypatch.setattr(stages, "pose_hypothesis", pose)
        return posed
    return arm


def _outcome(rec, scene):
    ctx, seg = scene
    return stages._recognize_cluster(rec, ctx, seg, 0, None, 1.0, {"descriptors": 0.0, "matching": 0.0})


def test_the_cluster_is_the_next_class_whose_pose_verifies(plate_scene, verifies_only):
    posed = verifies_only("plate")
    cfg = PipelineConfig(verify_min_fitness=0.95, verify_next_classes=2)
    out = _outcome(_Recognizer(cfg, "flange", ["valve", "plate", "elbow"]), plate_scene)
    assert posed == ["flange", "valve", "plate"]
    assert out.label == "plate" and out.detection.label == "plate" and out.nearest_label == "flange"
    assert out.distance == pytest.approx(0.3) and out.detection.score == pytest.approx(0.3)
    assert out.reason.startswith("detected, as the next class (flange: pose verification: fitness 0.500 < 0.95; "
                                 "valve: pose verification: fitness 0.500")


def test_without_next_classes_the_nearest_class_alone_is_tried(plate_scene, verifies_only):
    """Catches a default that silently changes what every run detects."""
    posed = verifies_only("plate")
    out = _outcome(_Recognizer(PipelineConfig(verify_min_fitness=0.95), "flange", ["plate"]), plate_scene)
    assert posed == ["flange"] and out.detection is None and out.label == "unknown"
    assert out.reason == "rejected: pose verification: fitness 0.500 < 0.95"


def test_at_most_the_configured_number_of_next_classes_and_only_those_that_fit_their_size(plate_scene,
                                                                                           verifies_only):
    posed = verifies_only("plate")
    cfg = PipelineConfig(verify_min_fitness=0.95, verify_next_classes=1)
    out = _outcome(_Recognizer(cfg, "flange", ["valve", "plate"]), plate_scene)
    assert posed == ["flange", "valve"] and out.detection is None
    assert out.reason == ("rejected: pose verification: fitness 0.500 < 0.95; then as valve: pose verification: "
                          "fitness 0.500 < 0.95")
    posed.clear()  # a class the cluster is too big for is not tried and not counted
    out = _outcome(_Recognizer(cfg, "flange", ["valve", "plate"], too_small=["valve"]), plate_scene)
    assert posed == ["flange", "plate"] and out.label == "plate"


def test_the_setting_is_checked_and_needs_a_verification():
    assert PipelineConfig().verify_next_classes == 0
    with pytest.raises(InputError, match="verify_next_classes"):
        PipelineConfig(verify_min_fitness=0.95, verify_next_classes=-1)
    with pytest.raises(InputError, match="verify_next_classes"):
        PipelineConfig(verify_min_fitness=0.95, verify_next_classes=1.5)
    with pytest.raises(InputError, match="verify_next_classes' argument of PipelineConfig needs a verification"):
        PipelineConfig(verify_next_classes=1)


def test_a_cluster_too_big_for_its_nearest_class_is_tried_as_the_next_classes(plate_scene, verifies_only):
    """Catches a size test that ends the cluster where a failed verification would try the next class (a border-cut
    reducing tee 0.271 m across, nearest an equal tee of 0.266 m at most: rejected without being tried as itself)."""
    posed = verifies_only("plate")
    cfg = PipelineConfig(verify_min_fitness=0.95, verify_next_classes=1, size_tolerance=0.1)
    out = _outcome(_Recognizer(cfg, "flange", ["plate"], too_small=["flange"]), plate_scene)
    assert posed == ["plate"] and out.label == "plate" and out.nearest_label == "flange"
    assert out.reason.startswith("detected, as the next class (flange: extent ") and "too big for flange" in out.reason
    posed.clear()  # no next class fits: the reason gives the size test first
    out = _outcome(_Recognizer(cfg, "flange", ["valve"], too_small=["flange"]), plate_scene)
    assert posed == ["valve"] and out.detection is None
    assert out.reason.startswith("rejected: extent ") and "too big for flange; then as valve: pose verification" in \
        out.reason
    posed.clear()  # without next classes the size test ends it, as before
    out = _outcome(_Recognizer(PipelineConfig(verify_min_fitness=0.95, size_tolerance=0.1), "flange", ["plate"],
                               too_small=["flange"]), plate_scene)
    assert posed == [] and out.detection is None and out.reason.startswith("rejected: extent ")
