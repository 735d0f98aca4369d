"""A recognised cluster as a part of a union (``PartsConfig(detected_parts=True)``): an object's part alone can look
like another class (the catalogue's gate-valve body, verified as a blind flange by its end flange), and its union
with the object's other parts is the object. Here a 'dumbbell' (box and cylinder 4 cm apart) beside a database that
also holds the box alone ('block')."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.errors import InputError
from semslam.pipeline import PipelineConfig, ScanRecognizer
from semslam.pipeline.parts import PartsConfig
from semslam.simulation.cad_models import models_view_clouds
from semslam.simulation.kinect import POSE_MODEL_KINECT, SURVEY_KINECT
from semslam.simulation.objects import _box, _cyl, _solid, make_object
from semslam.symmetry import Symmetry

from .test_pipeline_parts import AZIMUTHS, VERIFY, _scene


@pytest.fixture(scope="module")
def world():
    return dumbbell_and_block()


def dumbbell_and_block():
    """The dumbbell of test_pipeline_parts and the same box alone, in one database."""
    from semslam.recognition import build_database

    mesh = _solid([_box((0.08, 0.08, 0.06), (-0.06, 0, 0)), _cyl(0.04, (0.06, 0, -0.03), (0.06, 0, 0.05)),
                   _cyl(0.003, (-0.03, 0, 0), (0.03, 0, 0))])
    dumbbell = make_object("dumbbell", mesh, Symmetry("none"))
    block = make_object("block", _solid([_box((0.08, 0.08, 0.06), (0, 0, 0))]), Symmetry("none"))
    models = {"dumbbell": dumbbell, "block": block}
    views, classes = models_view_clouds(models, seed=0, config=SURVEY_KINECT, n_views=8)
    model_views, _ = models_view_clouds(models, seed=0, config=POSE_MODEL_KINECT, tied_rests=True)
    return dumbbell, build_database(views, classes, seed=0, model_views=model_views)


def test_a_part_recognised_alone_joins_the_union_that_is_the_object(world):
    """Seen from azimuth 0.3 rad the box alone verifies as the block (from 2.5 rad it does not, and the union of the
    two unknown parts is found either way: test_pipeline_parts)."""
    dumbbell, db = world
    scan, _ = _scene(dumbbell, AZIMUTHS[0])
    alone = ScanRecognizer(db, PipelineConfig(**VERIFY, parts=PartsConfig())).recognize(scan, seed=0)
    assert sorted(c.label for c in alone.clusters) == ["block", "unknown"]  # the box taken for the block
    result = ScanRecognizer(db, PipelineConfig(**VERIFY, parts=PartsConfig(detected_parts=True))).recognize(
        scan, seed=0)
    assert [c.label for c in result.clusters] == ["dumbbell", "dumbbell"]
    assert len(result.detections) == 1 and result.detections[0].label == "dumbbell"  # the block's detection replaced
    det = result.detections[0]
    assert det.extras["parts"] == [0, 1] and all(c.detection is det for c in result.clusters)
    assert np.linalg.norm(det.T_sensor_object.translation_m) < 0.01  # the truth is the identity


def test_the_setting_is_a_bool():
    assert PartsConfig().detected_parts is False
    with pytest.raises(InputError, match="detected_parts"):
        PartsConfig(detected_parts=1)
