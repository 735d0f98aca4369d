"""VFH against PCL 1.13 (pcl_ref vfh_given / golden files) for every variant."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.descriptors import compute_vfh, estimate_normals
from semslam.errors import DescriptorError


def golden(test_data, name, file="pcl-1.13.txt"):
    for line in (test_data / "descriptors" / file).read_text().splitlines():
        if line.startswith(name + " "):
            return np.array(line.split()[1:], dtype=float)
    raise KeyError(name)


@pytest.fixture(scope="module")
def bun0(test_data):
    d = np.load(test_data / "descriptors" / "bun0.npy").astype(np.float64)
    return d[:, :3], d[:, 3:6]


def assert_bins_equal(ours, ref, rel=1e-4):
    assert ours.shape == (308,)
    np.testing.assert_allclose(ours, ref, rtol=rel, atol=rel * ref.max())


def assert_pcl_exact(ours, ref):
    """Bit for bit PCL 1.13's float32 output (features and histogram are computed in float32 as PCL's)."""
    assert ours.shape == (308,) and ours.dtype == np.float64
    np.testing.assert_array_equal(ours.astype(np.float32), np.asarray(ref, dtype=np.float32))


def test_pcl113_bun0_file_normals(test_data, bun0):
    ours = compute_vfh(*bun0)
    assert_pcl_exact(ours, golden(test_data, "VFH_bun0_filenormals_default"))
    np.testing.assert_array_equal(ours[135:180], 0.0)  # size component off by default
    used = np.nonzero(ours[180:])[0]
    assert used.min() >= 59 and used.max() <= 70  # the 4-vector view direction squeezes the bins


def test_pcl113_size_and_normalized_distances(test_data, bun0):
    ours = compute_vfh(*bun0, size_component=True, normalize_distances=True)
    assert_pcl_exact(ours, golden(test_data, "VFH_bun0_filenormals_size_normdist"))


def test_pcl18_legacy_binning(test_data, bun0):
    # this golden holds double-precision values (100/396 = 0.252525253), not PCL's float32 ones
    ref = golden(test_data, "VFH_bun0_filenormals_legacy_f23", "vfh-bun0-legacy-f23.txt")
    ours = compute_vfh(*bun0, variant="pcl-1.8")
    assert_bins_equal(ours, ref, rel=1e-6)
    np.testing.assert_array_equal(np.round(ours * 396 / 100), np.round(ref * 396 / 100))  # same counts per bin


def test_rusu2010_uses_a_3d_view_direction(bun0):
    ours = compute_vfh(*bun0, variant="rusu2010")
    legacy = compute_vfh(*bun0, variant="pcl-1.8")
    np.testing.assert_array_equal(ours[:180], legacy[:180])
    used = np.nonzero(ours[180:])[0]
    assert used.min() <= 30 and used.max() >= 120  # spread over the 128 bins (25-127 on bun0)
    c = bun0[0].mean(axis=0)
    d = -c / np.linalg.norm(c)
    alpha = np.floor((bun0[1] @ d + 1) / 2 * 128).clip(0, 127).astype(int)
    # float32 histogram (as PCL's): the float increments 100/N summed in float32
    np.testing.assert_allclose(ours[180:], np.bincount(alpha, minlength=128) * 100 / len(alpha), rtol=1e-6)


def test_pcl113_k10_normals(test_data, bun0):
    normals = estimate_normals(bun0[0], k=10).normals_xyz
    assert_pcl_exact(compute_vfh(bun0[0], normals), golden(test_data, "VFH_bun0_k10normals_default"))


@pytest.mark.parametrize("name", ["chef_sub", "bun4_k10", "cylinder"])
def test_pcl113_matches_pcl_ref_vfh_given(test_data, name):
    g = np.load(test_data / "descriptors" / "vfh_pcl.npz")
    cloud = g[f"{name}_cloud"].astype(np.float64)
    assert_pcl_exact(compute_vfh(cloud[:, :3], cloud[:, 3:6]), g[f"{name}_vfh"])


def test_with_our_normals_close_to_pcl_ref_vfh(test_data):
    # pcl_ref vfh (PCL's own radius normals): our normals differ in the last float32 digits, so a
    # few pairs change bin; the histograms total 400.
    g = np.load(test_data / "descriptors" / "vfh_pcl.npz")
    pts = g["milk3000_points"].astype(np.float64)
    normals = estimate_normals(pts, radius_m=0.01).normals_xyz
    diff = np.abs(compute_vfh(pts, normals) - g["milk3000_vfh_r0.01"])
    assert diff.sum() < 0.5


# Clouds of 3 points (x y z nx ny nz, float32) crafted so that one pair feature (f1, f2 or f3 of the centroid
# and mean normal against a point) or one viewpoint value lands on a bin edge: computed in float32, as PCL does,
# it falls in one bin, computed in float64 in the neighbouring one. Expected: PCL 1.13's output (pcl_ref
# vfh_given on these exact float32 values), as {bin: value}.
EDGE_CASES = {
    "f1": ([[-0.0257192254, 0.000814218074, 0.472439706, 0.099849388, 0.116172075, 0.989804983],
            [0.129406378, 0.100672439, 0.228883743, -0.471937597, -0.16025421, 0.866944909],
            [-0.188901335, -0.0174772106, 0.457780957, 0.61051017, 0.625954926, -0.485239923]],
           {4: 50.0, 16: 50.0, 24: 50.0, 67: 100.0, 71: 50.0, 105: 50.0, 118: 50.0, 119: 50.0,
            221: 33.3333321, 223: 33.3333321, 255: 33.3333321}),
    "f2": ([[-0.0258848071, 0.105574287, 0.274914563, -0.0882621557, 0.47929886, 0.873029232],
            [-0.0138655324, 0.00330001046, 0.357465088, 0.213840947, -0.489032567, -0.845647216],
            [0.0332813635, -0.0651281029, 0.586244464, 0.929179013, -0.0589775927, -0.36489445]],
           {22: 50.0, 29: 50.0, 43: 50.0, 65: 50.0, 67: 50.0, 68: 50.0, 106: 50.0, 113: 50.0, 115: 50.0,
            222: 33.3333321, 252: 33.3333321, 264: 33.3333321}),
    "f3": ([[0.0209167469, -0.059241008, 0.487402081, -0.395352811, -0.806994796, 0.438697577],
            [-0.00724985451, 0.0108737387, 0.496997207, 0.930467904, 0.348240972, 0.113831788],
            [0.0173965953, -0.167085007, 0.582962871, -0.296431988, 0.913115025, 0.297943801]],
           {16: 50.0, 21: 50.0, 34: 50.0, 67: 50.0, 68: 50.0, 69: 50.0, 111: 50.0, 117: 100.0,
            227: 33.3333321, 239: 33.3333321, 241: 33.3333321}),
    "viewpoint": ([[-0.113929465, -0.0779637918, 0.508697927, 0.021255713, -0.824419498, 0.57774353],
                   [-0.155473113, 0.0168630406, 0.45409286, 0.138959005, 0.453320742, -0.880449176],
                   [0.122627057, 0.0962154716, 0.228871465, 0.625032544, 0.690544069, -0.363982469]],
                  {19: 50.0, 27: 50.0, 38: 50.0, 67: 150.0, 106: 100.0, 116: 50.0, 231: 33.3333321,
                   253: 33.3333321, 264: 33.3333321}),
}


def float64_vfh_counts(pts, normals):
    """Hits per bin of PCL 1.13's VFH evaluated in float64 throughout (what semslam did before), (308,)."""
    c, m = pts.mean(axis=0), normals.mean(axis=0)
    counts = np.zeros(308, int)
    for p, n in zip(pts, normals):
        d = p - c
        f4 = np.linalg.norm(d)
        u, nn, a1, a2 = m, n, m @ d / f4, n @ d / f4
        if np.arccos(abs(a1)) > np.arccos(abs(a2)):
            u, nn, d, f3 = n, m, -d, -a2
        else:
            f3 = a1
        v = np.cross(d, u)
        v /= np.linalg.norm(v)
        w = np.cross(u, v)
        for block, f in enumerate((np.arctan2(w @ nn, u @ nn), v @ nn, f3)):
            counts[45 * block + int(np.clip(np.floor(45 * ((f + np.pi) * D_PI)), 0, 44))] += 1
    view = -c / np.sqrt(c @ c + 1.0)
    np.add.at(counts, 180 + np.clip(np.floor((normals @ view + 1) * 0.5 * 128), 0, 127).astype(int), 1)
    return counts


D_PI = float(np.float32(1) / (np.float32(2) * np.float32(np.pi)))


@pytest.mark.parametrize("feature", sorted(EDGE_CASES))
def test_bin_edges_fall_as_in_pcl_float32(feature):
    cloud, expected = EDGE_CASES[feature]
    cloud = np.array(cloud, dtype=np.float32).astype(np.float64)
    ref = np.zeros(308, np.float32)
    ref[list(expected)] = list(expected.values())
    assert_pcl_exact(compute_vfh(cloud[:, :3], cloud[:, 3:]), ref)
    # the case is a real edge: in float64 the value falls in the neighbouring bin
    pcl_counts = np.round(ref / np.r_[np.full(180, 50.0), np.full(128, 100 / 3)]).astype(int)
    moved = np.flatnonzero(float64_vfh_counts(cloud[:, :3], cloud[:, 3:]) != pcl_counts)
    assert len(moved) == 2 and moved[1] - moved[0] == 1  # one hit, one bin over
    block = {"f1": (0, 45), "f2": (45, 90), "f3": (90, 135), "viewpoint": (180, 308)}[feature]
    assert block[0] <= moved[0] and moved[1] < block[1]


def test_nan_normals_are_skipped(bun0):
    pts, normals = bun0
    normals = normals.copy()
    normals[::7] = np.nan
    ours = compute_vfh(pts, normals)
    assert np.isfinite(ours).all()
    keep = np.isfinite(normals[:, 0])
    # same as removing those normals, except that the centroid still uses every point
    ref = compute_vfh(pts[keep], normals[keep])
    np.testing.assert_allclose(ours[180:], ref[180:], atol=2.0)
    np.testing.assert_allclose(ours[:180].reshape(4, 45)[:3].sum(axis=1), 100 * keep.sum() / (keep.sum() - 1), rtol=0.02)


def test_bad_input(bun0):
    pts, normals = bun0
    with pytest.raises(DescriptorError, match="at least 2 points"):
        compute_vfh(pts[:1], normals[:1])
    with pytest.raises(DescriptorError, match="normals_xyz"):
        compute_vfh(pts, normals[:-1])
    with pytest.raises(DescriptorError, match="finite normals"):
        compute_vfh(pts[:3], np.full((3, 3), np.nan))
    with pytest.raises(DescriptorError, match="viewpoint"):
        # the centroid as computed (PCL's float32 sequential sum / N), so the direction is exactly zero
        centroid = np.cumsum(pts.astype(np.float32), axis=0)[-1] / np.float32(len(pts))
        compute_vfh(pts, normals, viewpoint_xyz_m=centroid, variant="rusu2010")
    with pytest.raises(Exception, match="variant"):
        compute_vfh(pts, normals, variant="pcl-2")


def _write_pcd_with_normals(path, cols):
    header = ("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z normal_x normal_y normal_z\nSIZE 4 4 4 4 4 4\n"
              f"TYPE F F F F F F\nCOUNT 1 1 1 1 1 1\nWIDTH {len(cols)}\nHEIGHT 1\n"
              f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(cols)}\nDATA ascii\n")
    path.write_text(header + "\n".join(" ".join(f"{v:.9g}" for v in row) for row in cols) + "\n")


def test_real_views_bit_for_bit_with_pcl(real_data, pcl_ref, tmp_path):
    # real scans (the valve views of ../shared and PCL's bun0, bun4, chef): our normals, rounded to float32,
    # given to both; before the float32 fix two valve views differed from PCL in a pair of bins
    import json
    import subprocess

    from semslam.io import read_point_cloud

    files = sorted(real_data.glob("valves/*/*/*/RANSAC.pcd"))
    files += [real_data / f"{name}.pcd" for name in ("bun0", "bun4", "chef")]
    assert len(files) >= 13
    for path in files:
        pts = read_point_cloud(path).points_xyz_m
        pts = pts[np.isfinite(pts).all(axis=1) & (np.abs(pts).sum(axis=1) > 0)]
        normals = estimate_normals(pts, radius_m=0.01).normals_xyz
        ok = np.isfinite(normals).all(axis=1)
        cols = np.c_[pts[ok], normals[ok]].astype(np.float32)
        _write_pcd_with_normals(tmp_path / "view.pcd", cols)
        out = subprocess.run([pcl_ref, "vfh_given", str(tmp_path / "view.pcd")], capture_output=True, text=True,
                             check=True).stdout
        ref = np.array(json.loads(out.splitlines()[0])["bins"], dtype=np.float32)
        assert_pcl_exact(compute_vfh(cols[:, :3].astype(float), cols[:, 3:].astype(float)), ref)
