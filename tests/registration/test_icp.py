"""ICP: PCL's unit test (bun0 -> bun4) in PCL mode, small_gicp variants on an analytic case."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semslam.errors import InputError, RegistrationError
from semslam.registration import align_icp, prepare_icp_target

# PCL test_registration.cpp (and PCL 1.13 via pcl_ref, design/golden/pcl-1.13.txt: ICP_bun0_bun4)
PCL_BUN_T = np.array([[0.88059, 0.0364865, -0.472476, 0.0345311],
                      [-0.023652, 0.999174, 0.0330751, -0.0015063],
                      [0.473292, -0.0179498, 0.880723, 0.0411255]])


def _load_ascii_pcd(path):
    lines = path.read_text().splitlines()
    start = next(i for i, l in enumerate(lines) if l.startswith("DATA")) + 1
    return np.array([[float(v) for v in l.split()[:3]] for l in lines[start:] if l.strip()])


def test_pcl_unit_test_bun0_bun4(real_data):
    src, tgt = _load_ascii_pcd(real_data / "bun0.pcd"), _load_ascii_pcd(real_data / "bun4.pcd")
    res = align_icp(src, tgt, method="pcl", max_correspondence_m=0.05, max_iterations=50, transformation_epsilon=1e-8)
    T = res.T_target_source.matrix[:3]
    tol = np.full((3, 4), 1e-3)
    tol[0, 1] = 1e-2
    assert (np.abs(T - PCL_BUN_T) <= tol).all(), np.abs(T - PCL_BUN_T)
    assert res.converged and res.fitness == 1.0


def test_small_gicp_point_icp_close_to_pcl_on_bunny(real_data):
    src, tgt = _load_ascii_pcd(real_data / "bun0.pcd"), _load_ascii_pcd(real_data / "bun4.pcd")
    res = align_icp(src, tgt, method="point", max_correspondence_m=0.05, max_iterations=50,
                    rotation_eps_rad=1e-8, translation_eps_m=1e-8)
    # converges to the same minimum, PCL stops slightly earlier: within 2e-3
    assert np.abs(res.T_target_source.matrix[:3] - PCL_BUN_T).max() < 2e-3


def _box_surface(n, seed):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-1, 1, (n, 3)) * [0.10, 0.06, 0.04]
    axis = rng.integers(0, 3, n)
    pts[np.arange(n), axis] = np.sign(rng.uniform(-1, 1, n)) * np.array([0.10, 0.06, 0.04])[axis]
    return pts


@pytest.mark.parametrize("method", ["plane", "point", "gicp", "pcl"])
def test_methods_recover_small_offset(method):
    tgt = _box_surface(6000, 0)
    R = Rotation.from_euler("xyz", [3, -2, 4], degrees=True).as_matrix()
    t = np.array([0.004, -0.003, 0.002])
    src = (_box_surface(3000, 1) - t) @ R  # target = R src + t
    res = align_icp(src, tgt, method=method, max_correspondence_m=0.02, max_iterations=60)
    T = res.T_target_source
    assert Rotation.from_matrix(T.rotation.T @ R).magnitude() < np.radians(0.3)
    assert np.linalg.norm(T.translation_m - t) < 1.5e-3
    assert res.fitness > 0.95 and res.inlier_rmse_m < 3e-3


def test_prepared_target_is_reused_and_matches():
    tgt = _box_surface(4000, 2)
    prepared = prepare_icp_target(tgt, method="plane")
    assert prepared.normals_xyz.shape == (4000, 3)
    src = _box_surface(1000, 3) + [0.002, 0.0, -0.001]
    a = align_icp(src, prepared, max_correspondence_m=0.02)
    b = align_icp(src, tgt, method="plane", max_correspondence_m=0.02)
    np.testing.assert_allclose(a.T_target_source.matrix, b.T_target_source.matrix, atol=1e-9)


def test_bad_inputs():
    with pytest.raises(InputError, match="method"):
        align_icp(np.zeros((10, 3)), np.zeros((10, 3)), method="nope")
    with pytest.raises(RegistrationError, match="at least 3"):
        align_icp(np.zeros((2, 3)), _box_surface(100, 0))
    with pytest.raises(InputError, match="max_correspondence_m"):
        align_icp(_box_surface(100, 0), _box_surface(100, 1), max_correspondence_m=-1)
