"""The pipeline's private kernels against the reference implementations they replace."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.pipeline import _scan_angular_extent
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
