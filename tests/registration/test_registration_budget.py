"""``register`` is bounded (issue #18, item 4): the time budget is honoured, planes and lines raise a clear
RegistrationError, a far outlier changes nothing, the voxel is chosen from the clouds, the CLI says so in
one line. Behaviour only: speed and memory targets live in ``benchmarks/register_budget.py``."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from semslam.cli.main import main
from semslam.errors import InputError, RegistrationError
from semslam.geometry import RigidTransform
from semslam.registration import RegisterConfig, register


def _scene(n=6000, seed=0):
    """Two boxes and a ball on a floor, ~1 m across: observable, with distinctive features."""
    rng = np.random.default_rng(seed)
    floor = np.c_[rng.uniform(-0.5, 0.5, (n // 2, 2)), rng.normal(0, 0.0005, n // 2)]
    box = rng.uniform([-0.3, -0.3, 0.0], [-0.05, -0.1, 0.2], (n // 4, 3))
    face = rng.integers(0, 3, n // 4)
    box[np.arange(n // 4), face] = np.array([-0.3, -0.3, 0.2])[face]
    d = rng.normal(size=(n - n // 2 - n // 4, 3))
    ball = [0.2, 0.15, 0.1] + 0.1 * d / np.linalg.norm(d, axis=1, keepdims=True)
    return np.vstack([floor, box, ball])


def _moved():
    return RigidTransform.from_xyz_rpy([0.03, -0.02, 0.01], [0.0, 0.0, np.radians(10.0)])


@pytest.fixture(scope="module")
def warm():
    """Compile the numba kernels once, so that the budget tests time the work and not the JIT."""
    pts = _scene(2000)
    register(pts, pts, RegisterConfig(time_budget_s=None, max_iterations=200))


def test_budget_is_honoured_on_a_hopeless_case(warm):
    rng = np.random.default_rng(1)
    src, tgt = rng.uniform(-1, 1, (3000, 3)), rng.uniform(-1, 1, (3000, 3))  # sparse noise: nothing to match
    cfg = RegisterConfig(voxel_m=0.02, time_budget_s=0.5, max_iterations=10**7, inlier_fraction=1.0)
    t0 = time.perf_counter()
    res = register(src, tgt, cfg)
    elapsed = time.perf_counter() - t0
    assert elapsed < 5.0  # generous: the budget is 0.5 s
    assert not res.converged and res.extras["budget_exhausted"] is True
    assert res.extras["coarse"]["n_iterations"] < 10**7


def test_converges_with_auto_voxel_and_reports_it(warm):
    tgt = _scene()
    T = _moved()
    src = T.inverse().apply(tgt)  # source frame: T maps it onto the target
    res = register(src, tgt, RegisterConfig(time_budget_s=None, max_iterations=20000), seed=0)
    assert res.converged
    assert 0 < res.extras["voxel_m"] < 0.1 and res.extras["n_source_voxels"] <= 2000
    assert res.extras["budget_exhausted"] is False
    assert np.allclose(res.T_target_source.matrix, T.matrix, atol=0.02)


def test_progress_reaches_100_percent(warm):
    seen = []
    register(_scene(3000), _scene(3000), RegisterConfig(max_iterations=500), progress=lambda d, t: seen.append((d, t)))
    assert seen and seen[-1] == (100, 100) and all(b >= a for (a, _), (b, _) in zip(seen, seen[1:]))


@pytest.mark.parametrize("kind, match", [("plane", "it is a plane"), ("noisy_plane", "planar"), ("line", "it is a line")])
def test_unobservable_geometry_raises_a_clear_error(kind, match):
    rng = np.random.default_rng(0)
    if kind == "plane":
        pts = np.c_[rng.uniform(-1, 1, (50000, 2)), np.zeros(50000)]
    elif kind == "noisy_plane":  # 3 mm noise on a 20 cm patch: thick enough for the covariance test
        pts = np.c_[rng.uniform(-0.1, 0.1, (20000, 2)), rng.normal(0, 0.003, 20000)]
    else:
        pts = np.c_[rng.uniform(-1, 1, 20000), rng.normal(0, 1e-4, (20000, 2))]
    t0 = time.perf_counter()
    with pytest.raises(RegistrationError, match=match):
        register(_scene(), pts, RegisterConfig(time_budget_s=None))
    with pytest.raises(RegistrationError, match="source"):
        register(pts, _scene(), RegisterConfig(time_budget_s=None))
    assert time.perf_counter() - t0 < 60.0  # fails up front, not after a long RANSAC


def test_one_far_outlier_changes_nothing(warm):
    tgt = _scene()
    src = tgt[::2]
    base = register(src, tgt, RegisterConfig(time_budget_s=None, max_iterations=3000), seed=0)
    noisy = register(src, np.vstack([tgt, [[1e9, 1e9, 1e9]]]), RegisterConfig(time_budget_s=None, max_iterations=3000),
                     seed=0)
    assert noisy.extras["n_far_outliers"] == 1 and base.extras["n_far_outliers"] == 0
    assert noisy.extras["voxel_m"] == base.extras["voxel_m"]
    np.testing.assert_allclose(noisy.T_target_source.matrix, base.T_target_source.matrix, atol=1e-12)


def test_statistical_outlier_removal_on_request(warm):
    rng = np.random.default_rng(3)
    tgt = np.vstack([_scene(), rng.uniform(-3, 3, (100, 3))])  # sparse clutter within the robust box margin
    res = register(tgt, tgt, RegisterConfig(time_budget_s=None, remove_outliers=True, max_iterations=500))
    assert res.extras["n_statistical_outliers"] > 0


def test_config_validation():
    with pytest.raises(InputError, match="voxel_m"):
        RegisterConfig(voxel_m="fine")
    with pytest.raises(InputError, match="time_budget_s"):
        RegisterConfig(time_budget_s=0)
    with pytest.raises(InputError, match="max_voxels"):
        RegisterConfig(max_voxels=1)


def test_cli_plane_is_a_one_line_error(tmp_path, capsys):
    rng = np.random.default_rng(0)
    np.save(tmp_path / "plane.npy", np.c_[rng.uniform(-1, 1, (5000, 2)), np.zeros(5000)])
    np.save(tmp_path / "scene.npy", _scene())
    rc = main(["register", str(tmp_path / "scene.npy"), str(tmp_path / "plane.npy")])
    err = capsys.readouterr().err.splitlines()
    assert rc == 1 and len(err) == 1 and err[0].startswith("semslam: error:") and "target" in err[0]
    assert "plane.npy" in err[0]
    assert "plane" in err[0]


def test_cli_budget_in_json(tmp_path, capsys, warm):
    rng = np.random.default_rng(1)
    np.save(tmp_path / "a.npy", rng.uniform(-1, 1, (3000, 3)))
    np.save(tmp_path / "b.npy", rng.uniform(-1, 1, (3000, 3)))
    rc = main(["register", str(tmp_path / "a.npy"), str(tmp_path / "b.npy"), "--time-budget", "1", "--voxel", "0.02",
               "--max-iterations", "10000000", "--inlier-fraction", "1", "--json"])
    payload = json.loads(capsys.readouterr().out)
    assert rc == 1 and payload["converged"] is False
    assert payload["config"]["voxel_m"] == 0.02 and payload["extras"]["budget_exhausted"] is True
    assert 0 < payload["config"]["time_budget_s"] <= 1.0  # what reading the files left of the budget


def test_a_budget_spent_before_the_ransac_is_a_clear_error():
    with pytest.raises(RegistrationError, match="time budget of register .* ran out while"):
        register(_scene(), _scene(), RegisterConfig(time_budget_s=1e-6))


def test_stage_deadlines_in_the_past_stop_at_once():
    from semslam.registration import align_icp, align_prerejective

    rng = np.random.default_rng(0)
    pts = _scene(2000)
    feats = rng.random((len(pts), 33))
    coarse = align_prerejective(pts, feats, pts, feats, max_iterations=10**6, deadline=time.perf_counter() - 1.0)
    assert coarse.n_iterations == 0 and not coarse.converged and coarse.extras["budget_exhausted"] is True
    fine = align_icp(pts + 0.001, pts, method="pcl", max_iterations=50, deadline=time.perf_counter() - 1.0)
    assert fine.n_iterations == 0 and not fine.converged and fine.extras["budget_exhausted"] is True
    done = align_icp(pts + 0.001, pts, method="pcl", max_iterations=50)
    assert done.n_iterations > 0 and "budget_exhausted" not in done.extras
