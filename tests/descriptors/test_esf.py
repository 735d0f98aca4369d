"""ESF against PCL 1.13: bit for bit with the glibc sampler, statistically with the numpy sampler; the voxel
array of ``_esf_kernels.py``."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from semslam.descriptors import compute_esf, glibc_rand
from semslam.errors import DescriptorError, InputError


def golden(test_data, name):
    for line in (test_data / "descriptors" / "pcl-1.13.txt").read_text().splitlines():
        if line.startswith(name + " "):
            return line.split()[1:]
    raise KeyError(name)


@pytest.fixture(scope="module")
def runs(test_data):
    g = np.load(test_data / "descriptors" / "esf_pcl_runs.npz")
    names = [k[:-2] for k in g.files if k.endswith("_q")]
    clouds = {n: g[f"{n}_q"].astype(np.float32) * g[f"{n}_scale"] for n in names}
    return clouds, {n: g[f"{n}_pcl"] for n in names}, [int(s) for s in g["seeds"]]


def chi2(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    s = a + b
    m = s > 0
    return float(((a - b)[m] ** 2 / s[m]).sum())


def test_glibc_rand_matches_golden(test_data):
    expected = [int(v) for v in golden(test_data, "glibc_rand_seed12345")]
    np.testing.assert_array_equal(glibc_rand(12345, len(expected)), expected)
    # srand(0) behaves as srand(1) in glibc; the well-known first value of srand(1) is 1804289383
    assert glibc_rand(0, 1)[0] == glibc_rand(1, 1)[0] == 1804289383


@pytest.mark.parametrize("cloud,seed", [("bun0", 12345), ("bun0", 1), ("milk", 12345)])
def test_pcl_sampler_is_bit_exact(test_data, cloud, seed):
    if cloud == "bun0":
        pts = np.load(test_data / "descriptors" / "bun0.npy")[:, :3]
    else:
        pts = np.load(test_data / "descriptors" / "milk.npz")["points"]
    expected = np.array(golden(test_data, f"ESF_{cloud}_seed{seed}"), dtype=np.float32)
    esf = compute_esf(pts, seed=seed, sampler="pcl")
    assert esf.dtype == np.float32 and esf.shape == (640,)
    np.testing.assert_array_equal(esf, expected)


def test_pcl_sampler_bit_exact_on_20_clouds(runs):
    clouds, pcl, seeds = runs
    assert len(clouds) >= 20
    for name, pts in clouds.items():
        np.testing.assert_array_equal(compute_esf(pts, seed=seeds[0], sampler="pcl"), pcl[name][0], err_msg=name)


def _ratios(clouds, pcl, **kw):
    ratios = []
    for i, (name, pts) in enumerate(clouds.items()):
        ours = compute_esf(pts, seed=100 + i, **kw)
        pp = np.mean([chi2(a, b) for a, b in itertools.combinations(pcl[name], 2)])
        op = np.mean([chi2(ours, p) for p in pcl[name]])
        ratios.append(op / pp)
    return np.array(ratios)


def test_numpy_sampler_indistinguishable_from_pcl(runs):
    # chi-square distance ours <-> PCL, relative to PCL's own run-to-run distance (PCL_REF_TIME = 3
    # seeds): ~1 if the samplers are equivalent.
    clouds, pcl, _ = runs
    ratios = _ratios(clouds, pcl)
    assert 0.85 < ratios.mean() < 1.15, ratios
    assert ratios.max() < 1.6, ratios


def test_statistical_check_can_fail(runs):
    # Negative control: 4x fewer samples is a different distribution; the check must see it.
    clouds, pcl, _ = runs
    sub = dict(list(clouds.items())[:5])
    assert _ratios(sub, pcl, n_samples=5000).mean() > 1.6


def test_seeded_and_invariant(runs):
    clouds, _, _ = runs
    pts = clouds["bun0"]
    a = compute_esf(pts, seed=5)
    np.testing.assert_array_equal(a, compute_esf(pts, seed=5))
    assert not np.array_equal(a, compute_esf(pts, seed=6))
    assert a.sum() == pytest.approx(1.0, abs=1e-5)
    # translation and scale invariant up to float32 rounding of the input (same random triples)
    b = compute_esf(pts * 2.0 + 0.5, seed=5)
    assert chi2(a, b) < 0.2 * chi2(a, compute_esf(pts, seed=6)) + 1e-3


def test_bad_input():
    with pytest.raises(DescriptorError, match="at least 3"):
        compute_esf(np.zeros((2, 3)))
    with pytest.raises(DescriptorError, match="points_xyz_m"):
        compute_esf(np.array([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]]))
    with pytest.raises(DescriptorError, match="identical"):
        compute_esf(np.ones((10, 3)))
    with pytest.raises(DescriptorError, match="collinear"):
        compute_esf(np.c_[np.linspace(0, 1, 50), np.zeros(50), np.zeros(50)], seed=0)
    with pytest.raises(InputError, match="sampler"):
        compute_esf(np.random.default_rng(0).random((10, 3)), sampler="mt")


def test_few_points_and_duplicates_work():
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    for pts in (tri, np.vstack([tri, tri, tri])):
        h = compute_esf(pts, seed=0, n_samples=500)
        assert np.isfinite(h).all() and h.sum() == pytest.approx(1.0, abs=1e-5)


def test_same_histogram_on_one_or_two_threads():
    """The triples are evaluated in parallel but accumulated in draw order: the thread count changes nothing."""
    import numba

    pts = np.random.default_rng(4).normal(size=(800, 3))
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = compute_esf(pts, seed=5)
        one_pcl = compute_esf(pts, seed=5, sampler="pcl")
    finally:
        numba.set_num_threads(before)
    np.testing.assert_array_equal(compute_esf(pts, seed=5), one)
    np.testing.assert_array_equal(compute_esf(pts, seed=5, sampler="pcl"), one_pcl)


def _esf_in_one_chunk(pts, seed, n_samples):
    """Reference: all of PCL's draws evaluated at once (no chunks), the first n_samples accepted in draw order
    counted by a plain Python loop."""
    from semslam.descriptors import _esf_kernels as K
    from semslam.descriptors.esf import glibc_rand

    local, vox, lut, _ = K.esf_prepare(np.ascontiguousarray(pts, dtype=np.float32))
    m = 50 * n_samples
    triples = (glibc_rand(seed, 3 * m) % len(pts)).reshape(m, 3)
    out_i = np.empty((m, 11), dtype=np.int64)
    out_f = np.empty((m, 8), dtype=np.float32)
    K.esf_evaluate(local, vox, lut, triples, out_i, out_f)
    accepted = np.flatnonzero(out_i[:, 0])
    return K.esf_histogram(out_i, out_f, int(accepted[n_samples - 1]) + 1)


@pytest.mark.parametrize("n_points", [3, 5, 9, 400])
def test_chunked_draws_equal_one_chunk(n_points):
    """Few points: most draws repeat an index, so compute_esf needs several chunks of draws; the histogram
    is the one of the first n_samples accepted triples whatever the chunking."""
    pts = np.random.default_rng(n_points).normal(size=(n_points, 3))
    for seed in (0, 7):
        np.testing.assert_array_equal(compute_esf(pts, seed=seed, sampler="pcl", n_samples=2000),
                                      _esf_in_one_chunk(pts, seed, 2000))


def _pcl_float32_histogram(out_i, out_f, end):
    """PCL 1.13's accumulation, transcribed independently of ``esf_histogram``: every accepted triple adds, in
    draw order and in float32, ``count / 32`` to its A3 bins and 1 to its D2, ratio and D3 bins (``np.add.at``
    is unbuffered and sequential, hence PCL's order); then D2-in and the ratio block are halved, the blocks
    weighted, and the histogram divided by its float32 running sum."""
    f32 = np.float32
    ok = out_i[:end, 0] != 0
    oi, of = out_i[:end][ok].astype(np.int64), out_f[:end][ok]
    n = len(oi)
    maxd2 = max(f32(0), of[:, 0:3].max())
    maxd3 = max(f32(0), of[:, 6].max())
    h = np.zeros(640, dtype=np.float32)
    cls = oi[:, 7]
    # A3: (th1, n3), (th2, n1), (th3, n2) per triple, interleaved in PCL's order
    a3_bins = np.stack([cls * 64 + oi[:, 1], cls * 64 + oi[:, 2], cls * 64 + oi[:, 3]], axis=1).ravel()
    a3_vals = (np.stack([oi[:, 10], oi[:, 8], oi[:, 9]], axis=1).astype(np.float32) / f32(32)).ravel()
    np.add.at(h, a3_bins, a3_vals)
    for j in range(3):
        line = oi[:, 4 + j]
        mixed = line == 2
        np.add.at(h, 9 * 64 + np.floor(of[mixed, 3 + j] * f32(63) + f32(0.5)).astype(np.int64), f32(1))
        np.add.at(h, (6 + line) * 64 + np.floor(of[:, j] / maxd2 * f32(63) + f32(0.5)).astype(np.int64), f32(1))
    idx = np.floor(of[:, 6] / maxd3 * f32(63) + f32(0.5)).astype(np.int64)
    w = of[:, 7]
    d3 = np.where(w >= f32(0.999), 0, np.where(w <= f32(0.001), 1, 2))
    keep = (idx >= 0) & (idx < 64)
    np.add.at(h, (3 + d3[keep]) * 64 + idx[keep], f32(1))
    h[6 * 64:7 * 64] *= f32(0.5)
    h[9 * 64:] *= f32(0.5)
    h *= np.repeat(np.array([0.5, 0.5, 0.5, 0.5, 0.5, 1.0, 1.0, 2.0, 2.0, 2.0], dtype=np.float32), 64)
    total = np.cumsum(h, dtype=np.float32)[-1]  # sequential float32 sum, as PCL's loop
    return h / total, n


@pytest.mark.parametrize("cloud,seed", [("bun0", 12345), ("milk", 3)])
def test_pcl_float32_accumulation_is_exact(test_data, cloud, seed):
    """The integer A3 / ratio / D2 / D3 counts of ``compute_esf`` equal PCL's float32 sums: PCL's own
    draw-order float32 accumulation (transcribed above, on the triples semslam evaluates) gives compute_esf's
    histogram bit for bit at the default 20,000 samples, every A3 bin's float32 sum times 32 is its exact
    integer count, and the largest stays below 2^24. Catches a broken ``esf_histogram`` (a wrong divisor or
    halving, an overflowing or float accumulator, a block out of place) that the golden files would only
    show for their few clouds."""
    from semslam.descriptors import _esf_kernels as K

    if cloud == "bun0":
        pts = np.load(test_data / "descriptors" / "bun0.npy")[:, :3]
    else:
        pts = np.load(test_data / "descriptors" / "milk.npz")["points"]
    n_samples = 20000
    local, vox, lut, _ = K.esf_prepare(np.ascontiguousarray(pts, dtype=np.float32))
    m = 2 * n_samples
    triples = (glibc_rand(seed, 3 * m) % len(pts)).reshape(m, 3)
    out_i = np.empty((m, 11), dtype=np.int64)
    out_f = np.empty((m, 8), dtype=np.float32)
    K.esf_evaluate(local, vox, lut, triples, out_i, out_f)
    accepted = np.flatnonzero(out_i[:, 0])
    assert len(accepted) >= n_samples
    end = int(accepted[n_samples - 1]) + 1
    ours = compute_esf(pts, seed=seed, sampler="pcl")
    ref, n = _pcl_float32_histogram(out_i, out_f, end)
    assert n == n_samples
    np.testing.assert_array_equal(ours, ref)
    # A3: float32 partial sums in draw order are exact multiples of 1/32 (checked against int64 counts)
    ok = out_i[:end, 0] != 0
    oi = out_i[:end][ok]
    cls = oi[:, 7]
    counts = np.zeros(192, dtype=np.int64)
    for th, cnt in ((1, 10), (2, 8), (3, 9)):
        np.add.at(counts, cls * 64 + oi[:, th], oi[:, cnt])
    f32sum = np.zeros(192, dtype=np.float32)
    bins = np.stack([cls * 64 + oi[:, 1], cls * 64 + oi[:, 2], cls * 64 + oi[:, 3]], axis=1).ravel()
    np.add.at(f32sum, bins, (np.stack([oi[:, 10], oi[:, 8], oi[:, 9]], axis=1).astype(np.float32) / 32).ravel())
    np.testing.assert_array_equal(f32sum.astype(np.float64) * 32, counts)
    assert 0 < counts.max() < 2**24 and counts.sum() > 2**15  # a real load, beyond int16


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
