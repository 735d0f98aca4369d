"""The camera of a triangulation laser scanner in the visibility term: a model point the camera cannot see (its
shadow behind another part) is not expected in the scan. Oracle: the shadow of a rectangular roof over a floor
plate, cast analytically (a ray from each floor point to the camera through the roof's plane)."""

import numpy as np
import pytest

from semslam.pose import _search_kernels as K
from semslam.pose.model import PoseConfig
from semslam.pose.search import RangeImage
from tests._support.scenes import ROOF_CAMERA, ROOF_FLOOR_Z, ROOF_X, ROOF_Y, ROOF_Z, roof_plates, under_roof

CAMERA = ROOF_CAMERA
FLOOR_Z = ROOF_FLOOR_Z
_plates, _under_roof = roof_plates, under_roof


def test_the_camera_shadow_of_a_roof_matches_the_analytic_shadow():
    pts, nrm, n_floor = _plates()
    hidden = K._camera_hidden(np.eye(3), np.zeros(3), pts, nrm, CAMERA, 0.008 / 1.4, 0.01, np.zeros(0, bool))
    want = _under_roof(pts[:n_floor], CAMERA)
    assert want.sum() > 500 and not hidden[n_floor:].any()  # the roof is seen whole
    # every point of the shadow is hidden; the z-buffer's 3 x 3 cells (~1.3 cm here) widen it: every other hidden
    # point lies within 2 cm of its edge
    assert hidden[:n_floor][want].all()
    wrong = hidden[:n_floor] != want
    x = pts[:n_floor, 0]
    s = (ROOF_Z - FLOOR_Z) / (CAMERA[2] - FLOOR_Z)  # where a floor point's ray to the camera meets the roof plane
    xr = x + s * (CAMERA[0] - x)
    yr = pts[:n_floor, 1] * (1.0 - s)
    edge = np.minimum.reduce([np.abs(xr - ROOF_X[0]), np.abs(xr - ROOF_X[1]), np.abs(yr - ROOF_Y[0]),
                              np.abs(yr - ROOF_Y[1])])
    assert (edge[wrong] < 0.02).all() and wrong.sum() < 0.4 * want.sum()
    # no camera: nothing hidden
    out = K._camera_hidden(np.eye(3), np.zeros(3), pts, nrm, np.full(3, np.nan), 0.008 / 1.4, 0.01,
                           np.zeros(len(pts), bool))
    assert len(out) == len(pts) and not out.any()


@pytest.mark.parametrize("camera", [None, tuple(CAMERA)])
def test_a_scan_missing_the_camera_shadow_contradicts_the_model_only_without_the_camera(camera):
    pts, nrm, n_floor = _plates()
    laser_seen = np.ones(len(pts), dtype=bool)
    laser_seen[:n_floor] = ~_under_roof(pts[:n_floor], np.zeros(3))
    measured = laser_seen.copy()
    measured[:n_floor] &= ~_under_roof(pts[:n_floor], CAMERA)  # what a triangulation scanner returns
    img = RangeImage.build(pts[measured], np.zeros(3), cell_m=0.008).with_camera(camera)
    cost = img.visibility_cost(np.eye(3)[None], np.zeros((1, 3)), pts, nrm, 0.01)[0]
    shadow_share = (laser_seen & ~measured).sum() / laser_seen.sum()
    assert shadow_share > 0.05
    if camera is None:
        # the camera's shadow taken for unseen surface (the image's dilation excuses some of it)
        assert cost > 0.4 * shadow_share
    else:
        assert cost < 0.02


def test_the_pose_configuration_checks_the_camera_offset():
    from semslam.errors import InputError

    assert PoseConfig(camera_offset_m=[0.3, 0, 0]).camera_offset_m == (0.3, 0.0, 0.0)
    with pytest.raises(InputError, match="camera_offset_m"):
        PoseConfig(camera_offset_m=(0.3, 0.0))
