"""Verification's visibility cost against the whole scan (``verify_visibility_image="scene"``): a model point
hidden behind another object, or where the scanner did not look, is not a contradiction; one in front of what
the scanner saw (free space) is. Constructed scenes with a known answer: a plate 1 m in front of the sensor."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.errors import InputError
from semslam.pipeline import PipelineConfig
from semslam.pose.search import RangeImage

VP = np.zeros(3)
CELL = 0.008


def _grid(x0, x1, y0, y1, z, step=0.004):
    x, y = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step), indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


PLATE = _grid(-0.1, 0.1, -0.1, 0.1, 1.0)  # the model at its true pose (object frame = scanner frame)
NORMALS = np.tile([0.0, 0.0, -1.0], (len(PLATE), 1))  # facing the sensor
CLUSTER = PLATE[PLATE[:, 0] < 0.0]  # the scan saw only its left half
EYE, ZERO = np.eye(3)[None], np.zeros((1, 3))


def _cost(image, **kw):
    return float(image.visibility_cost(EYE, ZERO, PLATE, NORMALS, 0.01, **kw)[0])


def test_the_cluster_image_counts_the_unseen_half_as_contradictions():
    """The old rule (cluster alone): half the plate unseen by the cluster = half contradicts."""
    img = RangeImage.build(CLUSTER, VP, cell_m=CELL)
    assert _cost(img) == pytest.approx(0.5, abs=0.06)


def test_a_half_hidden_behind_an_occluder_is_not_a_contradiction():
    """Catches occluded objects rejected: the right half lies behind a plate at 0.8 m."""
    occluder = _grid(0.004, 0.1, -0.1, 0.1, 0.8)
    wall = _grid(-0.6, 0.6, -0.6, 0.6, 2.0, step=0.008)
    wall = wall[~((np.abs(wall[:, 0]) < 0.2) & (np.abs(wall[:, 1]) < 0.2))]
    scene = np.vstack([CLUSTER, occluder, wall])
    img = RangeImage.build_scene(scene, VP, CLUSTER, cell_m=CELL)
    assert _cost(img, unseen_is_contradiction=False) < 0.05


def test_a_half_where_the_scanner_sees_through_is_a_contradiction():
    """Catches the free-space test lost: no occluder, the scanner sees a wall at 2 m through the right half."""
    wall = _grid(-0.6, 0.6, -0.6, 0.6, 2.0, step=0.004)
    wall = wall[~((wall[:, 0] < 0.0) & (np.abs(wall[:, 1]) < 0.1) & (wall[:, 0] > -0.1))]  # hidden by the cluster
    scene = np.vstack([CLUSTER, wall])
    img = RangeImage.build_scene(scene, VP, CLUSTER, cell_m=CELL)
    assert _cost(img, unseen_is_contradiction=False) == pytest.approx(0.5, abs=0.08)


def test_a_half_outside_the_scan_footprint_is_unknown():
    """Catches border-cut objects rejected: the scan ends at x = 0, the scanner never looked at the right half."""
    img = RangeImage.build_scene(CLUSTER, VP, CLUSTER, cell_m=CELL)
    assert _cost(img, unseen_is_contradiction=False) < 0.05
    assert _cost(img) < 0.05 and not img.unseen_bad  # a scene image leaves the unseen out by default
    # the same image, unseen counted: the old answer
    assert _cost(img, unseen_is_contradiction=True) == pytest.approx(0.5, abs=0.06)


def test_the_setting_is_checked():
    assert PipelineConfig(verify_visibility_image="scene").verify_visibility_image == "scene"
    assert PipelineConfig(verify_visibility_image="border").verify_visibility_image == "border"
    with pytest.raises(InputError, match="verify_visibility_image"):
        PipelineConfig(verify_visibility_image="everything")


def test_only_objects_hide_a_model_point_a_plane_does_not():
    """Catches a hypothesis sunk into the floor accepted: the right half lies behind a plane (the floor, not an
    object). With the plane among the occluders it would be hidden; given the scene's objects only (the cluster),
    it contradicts the scan: the scanner sees the plane where the object would have to be."""
    floor = _grid(0.004, 0.1, -0.1, 0.1, 0.8)  # a plane patch in front of the right half
    wall = _grid(-0.6, 0.6, -0.6, 0.6, 2.0, step=0.008)
    wall = wall[~((np.abs(wall[:, 0]) < 0.2) & (np.abs(wall[:, 1]) < 0.2))]
    scene = np.vstack([CLUSTER, floor, wall])
    anything = RangeImage.build_scene(scene, VP, CLUSTER, cell_m=CELL)
    objects_only = RangeImage.build_scene(scene, VP, CLUSTER, cell_m=CELL, occluder_points=CLUSTER)
    assert _cost(anything, unseen_is_contradiction=False) < 0.05
    assert _cost(objects_only, unseen_is_contradiction=False) == pytest.approx(0.5, abs=0.08)
    occluded = RangeImage.build_scene(scene, VP, CLUSTER, cell_m=CELL, occluder_points=np.vstack([CLUSTER, floor]))
    assert _cost(occluded, unseen_is_contradiction=False) < 0.05  # the same patch as an object hides it
