"""A union of clusters is posed as a partial view (``Hypothesis.union``): its pose search also starts the translation
on the grid across the object that a border-cut cluster gets (``PoseConfig.partial_start_step_m``), because a part of
the object may be missing from the union (the catalogue's gate valve in pieces, its union's centroid far from where
the whole object's would be: benchmarks/history/catalogue.md, session 24)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import semslam.pipeline.hypothesis as hypothesis_module
from semslam.pipeline import PipelineConfig, ScanRecognizer
from semslam.pipeline.parts import PartsConfig
from semslam.pose import PoseConfig

from .test_pipeline_parts import AZIMUTHS, VERIFY, _scene, world  # noqa: F401 (the module's fixture)


def _recognize_spying(db, scan, step_m: float, monkeypatch) -> tuple[list[tuple[int, bool]], object]:
    """Recognise ``scan`` with part unions and the translation grid ``step_m``; returns (points, partial) of every
    pose search and the result."""
    calls = []
    real = hypothesis_module.estimate_object_pose

    def spy(points, *args, **kwargs):
        calls.append((len(points), bool(kwargs.get("partial"))))
        return real(points, *args, **kwargs)

    monkeypatch.setattr(hypothesis_module, "estimate_object_pose", spy)
    cfg = PipelineConfig(**VERIFY, parts=PartsConfig(), pose=dataclasses.replace(PoseConfig(),
                                                                                 partial_start_step_m=step_m))
    return calls, ScanRecognizer(db, cfg).recognize(scan, seed=0)


@pytest.mark.parametrize("azimuth", AZIMUTHS)
def test_a_union_is_searched_as_a_partial_view_and_a_single_cluster_is_not(world, azimuth, monkeypatch):  # noqa: F811
    dumbbell, db = world
    scan, _ = _scene(dumbbell, azimuth)
    calls, result = _recognize_spying(db, scan, 0.04, monkeypatch)
    parts = [len(result.segmentation.input_indices(k)) for k in range(len(result.clusters))]
    assert len(parts) == 2
    union = [partial for n, partial in calls if n == sum(parts)]
    assert union and all(union), (parts, calls)  # the union: a partial view
    # with the grid the union still finds the true pose (the identity)
    assert [c.label for c in result.clusters] == ["dumbbell", "dumbbell"]
    det = result.detections[0]
    assert np.linalg.norm(det.T_sensor_object.translation_m) < 0.01
    assert np.degrees(np.arccos(np.clip((np.trace(det.T_sensor_object.rotation) - 1) / 2, -1, 1))) < 3.0



def test_a_single_cluster_is_not_searched_as_a_partial_view(monkeypatch):
    """The dumbbell's box alone verifies as the 'block' of test_pipeline_parts_detected's database: one whole
    cluster, posed as a whole view."""
    from .test_pipeline_parts_detected import dumbbell_and_block

    dumbbell, db = dumbbell_and_block()
    scan, _ = _scene(dumbbell, AZIMUTHS[0])
    calls, result = _recognize_spying(db, scan, 0.04, monkeypatch)
    assert sorted(c.label for c in result.clusters) == ["block", "unknown"]
    block = [len(result.segmentation.input_indices(k)) for k, c in enumerate(result.clusters) if c.label == "block"]
    posed = [partial for n, partial in calls if n == block[0]]
    assert posed and not any(posed), calls
