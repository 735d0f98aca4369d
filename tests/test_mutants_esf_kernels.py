"""Tests that kill surviving mutants of ``semslam/descriptors/_esf_kernels.py`` (benchmarks/mutation.py)."""

from __future__ import annotations

import numpy as np


def test_esf_prepare_returns_the_documented_voxel_array():
    """Catches a voxel array of the wrong shape (``np.zeros((n, 4))``): ``esf_prepare`` returns ``vox`` as
    documented, (N, 3) int64, each row the voxels (``_vox``, PCL's rounding into its 64^3 grid) of the point's
    scaled local coordinates."""
    from semslam.descriptors import _esf_kernels as K

    rng = np.random.default_rng(3)
    pts = np.ascontiguousarray(rng.normal(size=(50, 3)), dtype=np.float32)
    local, vox, lut, maxd = K.esf_prepare(pts)
    assert vox.shape == (50, 3) and vox.dtype == np.int64
    assert np.all((vox >= 0) & (vox <= 64))
    np.testing.assert_array_equal(vox, [[K._vox(c) for c in row] for row in local])
