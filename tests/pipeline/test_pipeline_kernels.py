"""The pipeline's private kernels against the reference implementations they replace."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.pipeline._scan_helpers import _scan_angular_extent
from semslam.recognition.plausibility import scan_angular_extent


@pytest.mark.parametrize("in_front", [True, False])
def test_scan_angular_extent_kernel_equals_plausibility(in_front):
    rng = np.random.default_rng(0)
    for _ in range(50):
        pts = rng.normal(size=(int(rng.integers(1, 400)), 3))
        vp = rng.normal(size=3) * 0.1
        if in_front:  # a scan: every point in front of the scanner (z > 0), the fast path
            pts[:, 2] = np.abs(pts[:, 2]) + 0.5 + vp[2]
        np.testing.assert_allclose(_scan_angular_extent(pts, vp), scan_angular_extent(pts, vp), rtol=0, atol=1e-14)
    empty = np.zeros((0, 3))
    np.testing.assert_array_equal(_scan_angular_extent(empty, np.zeros(3)), scan_angular_extent(empty))


def _extent_reference(pts):
    """The array expression that cluster_extent_m used before its kernel."""
    if len(pts) < 2:
        return np.zeros(3)
    c = pts - pts.mean(axis=0)
    _, vecs = np.linalg.eigh(c.T @ c)
    proj = c @ vecs
    return np.sort(proj.max(axis=0) - proj.min(axis=0))[::-1]


def _border_reference(pts, ext, vp, margin):
    """touches_scan_border's array expression before its kernel (arctan2 / arcsin on every point)."""
    p = pts - vp
    r = np.linalg.norm(p, axis=1)
    a = np.arctan2(p[:, 0], p[:, 2])
    b = np.arcsin(np.clip(p[:, 1] / np.maximum(r, 1e-12), -1.0, 1.0))
    return bool(a.min() - ext[0] < margin or ext[1] - a.max() < margin or b.min() - ext[2] < margin
                or ext[3] - b.max() < margin)


def test_cluster_extent_kernel_equals_array_expression():
    from semslam.recognition.plausibility import cluster_extent_m

    rng = np.random.default_rng(1)
    for _ in range(40):
        n = int(rng.integers(0, 3000))
        # elongated, rotated, far from the origin (cancellation) clusters
        pts = rng.normal(size=(n, 3)) * rng.uniform(0.01, 0.3, size=3)
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        pts = pts @ q.T + rng.normal(size=3) * 10
        ref = _extent_reference(pts)
        got = cluster_extent_m(pts)
        np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-13)
        assert got.shape == (3,) and np.all(np.diff(got) <= 0)
    # analytic: a box 0.4 x 0.2 x 0.1 m sampled on its corners and edges
    corners = np.array([[x, y, z] for x in (0, 0.4) for y in (0, 0.2) for z in (0, 0.1)])
    np.testing.assert_allclose(cluster_extent_m(corners + 5.0), [0.4, 0.2, 0.1], atol=1e-12)


def test_border_kernel_equals_array_expression():
    from semslam.recognition.plausibility import touches_scan_border

    rng = np.random.default_rng(2)
    scan = rng.uniform(-1, 1, size=(20000, 3)) * [0.4, 0.4, 0.0] + [0, 0, 2.0]
    scan[:, 2] += rng.normal(size=len(scan)) * 0.05
    vp = np.array([0.01, -0.02, 0.0])
    ext = _scan_angular_extent(scan, vp)
    flags = []
    for _ in range(200):
        centre = scan[rng.integers(len(scan))]
        radius = rng.uniform(0.01, 0.2)
        cluster = scan[np.linalg.norm(scan - centre, axis=1) < radius]
        margin = float(rng.uniform(0, 0.05))
        got = touches_scan_border(cluster, ext, vp, margin_rad=margin)
        assert got == (len(cluster) > 0 and _border_reference(cluster, ext, vp, margin))
        flags.append(got)
    assert 20 < sum(flags) < 180  # both outcomes exercised
    behind = np.array([[0.1, 0.0, -1.0], [0.0, 0.1, 1.0]])  # a point behind the scanner: the exact path
    assert touches_scan_border(behind, ext, vp) == _border_reference(behind, ext, vp, np.radians(0.5))
    assert not touches_scan_border(np.zeros((0, 3)), ext, vp)
    assert not touches_scan_border(scan[:10], np.array([np.inf, -np.inf, np.inf, -np.inf]), vp)


def test_input_indices_kernel_equals_segmentation_result():
    from semslam.cloud import PointCloud
    from semslam.pipeline._scan_helpers import _input_indices
    from semslam.segmentation.scene import SegmentationConfig, segment_scene

    rng = np.random.default_rng(3)
    floor = np.c_[rng.uniform(-1, 1, (6000, 2)), rng.normal(0, 0.001, 6000)]
    blobs = [rng.normal(size=(800, 3)) * 0.03 + [x, y, 0.1] for x, y in ((-0.5, 0.0), (0.4, 0.3), (0.0, -0.5))]
    cloud = PointCloud(np.vstack([floor, *blobs])[rng.permutation(6000 + 2400)])
    seg = segment_scene(cloud, SegmentationConfig(), seed=0)
    assert len(seg.clusters) >= 3 and seg.point_voxel is not None
    for k in range(len(seg.clusters)):
        got = _input_indices(seg, k)
        assert got.dtype == np.int64
        np.testing.assert_array_equal(got, seg.input_indices(k))
