"""One point at 1e9 m (or 1e12 m) changes no segmentation: same plane, same clusters (issue #18, item 4)."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.cloud import PointCloud
from semslam.segmentation import segment_scene
from tests._support.scenes import tank_scene


@pytest.mark.parametrize("outlier", [[1e9, 1e9, 1e9], [-1e9, 0.0, 0.0], [1e12, 3.0, -1e12]])
def test_one_far_point_changes_no_segmentation(outlier):
    cloud, _ = tank_scene()
    base = segment_scene(cloud, seed=0)
    noisy = segment_scene(PointCloud(np.vstack([cloud.points_xyz_m, [outlier]]), frame_id="scanner"), seed=0)
    assert base.planes and noisy.planes
    assert len(noisy.clusters) == len(base.clusters)
    assert sorted(c.n_points for c in noisy.clusters) == sorted(c.n_points for c in base.clusters)
    assert np.allclose(noisy.planes[0].coefficients, base.planes[0].coefficients, atol=1e-9)
    assert noisy.planes[0].n_inliers == base.planes[0].n_inliers
    assert not any("collinear" in n for n in noisy.notes)
