"""Fragments (``PartsConfig(fragments=True)``, semslam.pipeline.fragments): a cluster left unknown whose points lie on
the surface of an object recognised in the same scan is reported as a piece of that object; a rock beside it is
not, nor is a piece the detection's pose does not explain."""

from __future__ import annotations

import dataclasses

import pytest

from semslam.errors import InputError
from semslam.geometry import RigidTransform
from semslam.pipeline import PipelineConfig, ScanRecognizer
from semslam.pipeline.fragments import absorb_fragments
from semslam.pipeline.parts import PartsConfig
from semslam.pipeline.scan_records import scan_context

from .test_pipeline_parts import AZIMUTHS, VERIFY, _scene, world  # noqa: F401 (the module's fixture)


def _one_part_detected(db, scan, *, config: PipelineConfig, shift_m: float = 0.0):
    """The dumbbell's union detection with only its first cluster (the second made unknown, as if the union had
    left it out), its pose shifted by ``shift_m`` along x: ``(recogniser, context, segmentation, outcomes,
    detection, the other cluster)``."""
    rec = ScanRecognizer(db, config)
    result = rec.recognize(scan, seed=0)
    det = result.detections[0]
    first, other = det.extras["parts"][0], det.extras["parts"][1]
    T = det.T_sensor_object.matrix.copy()
    T[0, 3] += shift_m
    det = dataclasses.replace(det, T_sensor_object=RigidTransform(T), extras={**det.extras, "parts": [first]})
    outcomes = [dataclasses.replace(o, detection=det) if o.detection is not None else o for o in result.clusters]
    outcomes[other] = dataclasses.replace(outcomes[other], label="unknown", detection=None,
                                          reason="rejected: distance 1.2 > threshold 0.75")
    return rec, scan_context(scan, seed=0, default_up_scanner=None, stamp_s=None, scan_id=None,
                                       point_stamps_s=None, up_scanner=None), result.segmentation, outcomes, det, other


@pytest.mark.parametrize("azimuth", AZIMUTHS)
def test_an_unknown_cluster_on_a_recognised_objects_surface_becomes_its_fragment(world, azimuth):
    dumbbell, db = world
    scan, _ = _scene(dumbbell, azimuth)
    rec, ctx, seg, outcomes, det, other = _one_part_detected(db, scan, config=PipelineConfig(**VERIFY,
                                                                                             parts=PartsConfig()))
    timings: dict = {}
    out = absorb_fragments(rec, ctx, seg, outcomes, [det], timings=timings)
    assert out[other].detection is det and out[other].label == "dumbbell"
    assert out[other].reason == f"detected as a fragment of the dumbbell of clusters {det.extras['parts']}"
    assert det.extras["fragments"] == [other] and det.extras["fragment_fitness"][0] >= 0.95
    assert outcomes[other].detection is None  # the outcomes given are not changed
    assert timings["fragments"] >= 0


def test_a_piece_the_detections_pose_does_not_explain_stays_unknown(world):
    """The same cluster against the detection posed 3 cm off: its points are off the model's surface."""
    dumbbell, db = world
    scan, _ = _scene(dumbbell, AZIMUTHS[0])
    rec, ctx, seg, outcomes, det, other = _one_part_detected(db, scan, config=PipelineConfig(**VERIFY,
                                                             parts=PartsConfig()), shift_m=0.03)
    out = absorb_fragments(rec, ctx, seg, outcomes, [det], timings={})
    assert out[other].detection is None and out[other].label == "unknown" and "fragments" not in det.extras


@pytest.mark.parametrize("reason, touches_border, border, kept", [
    ("rejected: extent 0.9 m > 0.4 m, too big for any class", False, "keep", False),
    ("rejected: touches the scan border", True, "reject", False),
    ("rejected: distance 1.2 > threshold 0.75", True, "flag", True),
])
def test_which_unknown_clusters_may_be_fragments(world, reason, touches_border, border, kept):
    """Not a cluster too big for every class, nor a border-cut one when the border policy rejects them; a border-cut
    one under ``"flag"`` is (it says so)."""
    dumbbell, db = world
    scan, _ = _scene(dumbbell, AZIMUTHS[0])
    config = PipelineConfig(**{**VERIFY, "border": border}, parts=PartsConfig())
    rec, ctx, seg, outcomes, det, other = _one_part_detected(db, scan, config=config)
    outcomes[other] = dataclasses.replace(outcomes[other], reason=reason, touches_border=touches_border)
    out = absorb_fragments(rec, ctx, seg, outcomes, [det], timings={})
    assert (out[other].detection is det) == kept
    if kept:
        assert out[other].reason.endswith(", touches the scan border")


def test_a_rock_beside_a_recognised_object_is_not_its_fragment(world):
    """A rock as big as a part (630 points) 3.5 cm from the dumbbell, fragments on (the default): it stays
    unknown."""
    dumbbell, db = world
    scan, n_rock = _scene(dumbbell, AZIMUTHS[0], 0.03)
    assert PartsConfig().fragments is True
    result = ScanRecognizer(db, PipelineConfig(**VERIFY, parts=PartsConfig())).recognize(scan, seed=0)
    n_obj = scan.n_points - n_rock - 160 ** 2
    rock_k = [k for k in range(len(result.clusters)) if result.segmentation.input_indices(k).min() >= n_obj]
    assert len(rock_k) == 1 and len(result.detections) == 1
    assert result.clusters[rock_k[0]].detection is None and "fragments" not in result.detections[0].extras
    assert "fragments" in result.timings_ms


def test_fragments_off_leaves_the_step_out(world):
    dumbbell, db = world
    scan, _ = _scene(dumbbell, AZIMUTHS[0])
    result = ScanRecognizer(db, PipelineConfig(**VERIFY, parts=PartsConfig(fragments=False))).recognize(scan, seed=0)
    assert "fragments" not in result.timings_ms and len(result.detections) == 1
    with pytest.raises(InputError, match="fragments"):
        PartsConfig(fragments="yes")

