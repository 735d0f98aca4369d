"""The pose search of a border-cut cluster against the whole scan (``estimate_object_pose(scene_scanner=)``,
``PipelineConfig.pose_border_scene``): the part of the object beyond the scan's border, where the scanner never
looked, is unknown to the search's visibility term instead of a contradiction; the verdict's visibility stays the
cluster's own.

The part: a 32 cm ring with a raised hub (tests/_support/scenes.py), seen 35 degrees off its axis; the scan ends
where 30 % of the view's points lie on one side (the border)."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.errors import InputError
from semslam.pipeline import PipelineConfig
from semslam.pose import PoseConfig, estimate_object_pose, prepare_pose_model
from semslam.simulation.scan_sim import mesh_model_cloud
from semslam.symmetry import Symmetry
from tests._support.scenes import flange_mesh, flange_view

AXIS = Symmetry(kind="continuous", axis_object=np.array([0.0, 0.0, 1.0]))
UPS = [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]


@pytest.fixture(scope="module")
def cut_ring():
    model = prepare_pose_model(mesh_model_cloud(flange_mesh(), seed=1), PoseConfig(partial_start_step_m=0.04))
    _, T, pts, _ = flange_view(35.0)
    cut = pts[pts[:, 0] < np.quantile(pts[:, 0], 0.3)]  # the scan's border at that scanner x
    return model, T, cut, T[:3, :3] @ [0.0, 0.0, 1.0]


def _pose(case, scene):
    model, T, cut, up = case
    est = estimate_object_pose(cut, model, symmetry=AXIS, up_scanner=up, up_object=UPS, partial=True,
                               scene_scanner=scene)
    Te = est.T_scanner_object.matrix
    rot = np.degrees(AXIS.rotation_error_rad(Te[:3, :3], T[:3, :3]))
    return est, rot, float(np.linalg.norm(Te[:3, 3] - T[:3, 3]))


def test_the_model_beyond_the_border_is_unknown_to_the_search_not_a_contradiction(cut_ring):
    _, _, cut, _ = cut_ring
    alone, rot_a, dt_a = _pose(cut_ring, None)
    scene, rot_s, dt_s = _pose(cut_ring, (cut, cut))  # the scan is the cluster: nothing seen beyond the border
    assert rot_a < 1.0 and dt_a < 0.002 and rot_s < 1.0 and dt_s < 0.002  # both right on this part
    # the search's visibility term of its best hypothesis: the unseen 70 % of the ring counted, then left out
    assert alone.extras["hypotheses"][0][2] > 0.5
    assert scene.extras["hypotheses"][0][2] < 0.05
    # the verdict's visibility is the cluster's own either way
    assert scene.visibility == pytest.approx(alone.visibility, abs=1e-6) and scene.visibility > 0.5


@pytest.mark.parametrize("bad, match", [
    ((np.zeros((4, 3)),), "pair"),
    ("scene", "pair"),
    ((np.zeros((4, 2)), np.zeros((4, 3))), r"scene_scanner\[0\]"),
    ((np.zeros((0, 3)), np.zeros((4, 3))), "at least one scene point"),
])
def test_a_malformed_scene_is_refused_by_name(cut_ring, bad, match):
    with pytest.raises(InputError, match=match):
        _pose(cut_ring, bad)


def test_the_pipeline_switch_is_a_bool_off_by_default():
    assert PipelineConfig().pose_border_scene is False
    with pytest.raises(InputError, match="pose_border_scene"):
        PipelineConfig(pose_border_scene=1)
