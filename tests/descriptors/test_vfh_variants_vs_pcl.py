"""Every VFH variant and option branch of ``compute_vfh`` against PCL's output, bin by bin.

Goldens: ``data/descriptors/vfh_variants_pcl.npz`` (``make_vfh_variant_goldens.py`` there; how the oracle was
built and what it runs: ``README-vfh-variants.md``). For each of 3 real float32 clouds with normals (PCL's
bun0 with its file normals, 2000 points of PCL's milk scan, a real globe-valve view) and each of the 48
configurations {pcl-1.13, pcl-1.8, rusu2010} x normalize_bins {on, off} x {no size component, no size
component + normalize_distances, size component, size component + normalize_distances} x viewpoint {origin,
(0.25, -0.4, 1.5) m}, the npz holds PCL's 308 float32 bins (pcl-1.13: PCL 1.13's ``pcl::VFHEstimation``;
pcl-1.8: PCL <= 1.10.0's binning; rusu2010: the same with the centroid given to PCL, so a 3-D view direction).

Tolerance: none. ``compute_vfh`` runs PCL's float32 arithmetic step for step (as the default variant in
test_vfh.py, ``assert_pcl_exact``), so every bin must equal PCL's float32 value exactly; a single point moved
to a neighbouring bin changes two bins by 100/(N-1) (or 100/N, or 1 without normalize_bins), which exact
equality always catches (test_comparison_fails_when_a_bin_shifts checks that for every configuration).
"""

from __future__ import annotations

import functools
import inspect

import numpy as np
import pytest

from semslam.descriptors import compute_vfh
from semslam.descriptors.vfh import VFH_VARIANTS

GOLDEN = "vfh_variants_pcl.npz"
CLOUDS = ("bun0", "milk", "globe_valve")
N_CONFIGS = 48  # 3 variants x 2 normalize_bins x 4 size branches x 2 viewpoints
BLOCKS = {"f1": (0, 45), "f2": (45, 90), "f3": (90, 135), "f4": (135, 180), "viewpoint": (180, 308)}


@functools.cache
def goldens(test_data) -> dict[str, np.ndarray]:
    with np.load(test_data / "descriptors" / GOLDEN) as g:
        return {k: g[k] for k in g.files}


def config_kwargs(g: dict, i: int) -> dict:
    """The compute_vfh keyword arguments of configuration i, as stored with the goldens."""
    return {"variant": str(g["variant"][i]), "normalize_bins": bool(g["normalize_bins"][i]),
            "normalize_distances": bool(g["normalize_distances"][i]),
            "size_component": bool(g["size_component"][i]), "viewpoint_xyz_m": g["viewpoint_xyz_m"][i]}


@functools.cache
def ours(test_data, cloud: str, i: int) -> np.ndarray:
    g = goldens(test_data)
    cols = g[f"{cloud}_cloud"].astype(np.float64)
    return compute_vfh(cols[:, :3], cols[:, 3:], **config_kwargs(g, i))


def same_bins_as_pcl(ours_vfh: np.ndarray, pcl_vfh: np.ndarray) -> bool:
    """Every one of the 308 bins equal to PCL's float32 value (no tolerance: see the module docstring)."""
    return ours_vfh.shape == (308,) and np.array_equal(ours_vfh.astype(np.float32),
                                                       np.asarray(pcl_vfh, dtype=np.float32))


def assert_same_bins_as_pcl(ours_vfh: np.ndarray, pcl_vfh: np.ndarray) -> None:
    assert ours_vfh.shape == (308,) and ours_vfh.dtype == np.float64
    if not same_bins_as_pcl(ours_vfh, pcl_vfh):
        bins = np.flatnonzero(ours_vfh.astype(np.float32) != pcl_vfh)
        raise AssertionError(f"bins {bins.tolist()} differ from PCL: ours {ours_vfh[bins].tolist()}, "
                             f"PCL {pcl_vfh[bins].tolist()}")


def config_ids() -> list[str]:
    # the keys are fixed by the generator; listed here so that the ids exist without loading the npz
    ids = []
    for variant in ("pcl-1.13", "pcl-1.8", "rusu2010"):
        for nb in ("nb1", "nb0"):
            for size in ("nosize", "nosize_normdist", "size", "size_normdist"):
                ids += [f"{variant}/{nb}/{size}/{vp}" for vp in ("origin", "custom")]
    return ids


CONFIGS = config_ids()


def test_golden_file_holds_every_configuration(test_data):
    g = goldens(test_data)
    assert list(g["configs"]) == CONFIGS and len(CONFIGS) == N_CONFIGS
    # every variant and every option compute_vfh offers is covered: a new one needs new goldens
    assert set(g["variant"]) == set(VFH_VARIANTS)
    options = [p.name for p in inspect.signature(compute_vfh).parameters.values() if p.kind is p.KEYWORD_ONLY]
    assert sorted(options) == sorted(config_kwargs(g, 0))
    for cloud in CLOUDS:
        assert g[f"{cloud}_vfh"].shape == (N_CONFIGS, 308) and g[f"{cloud}_vfh"].dtype == np.float32
        assert g[f"{cloud}_cloud"].dtype == np.float32 and len(g[f"{cloud}_cloud"]) >= 397


@pytest.mark.parametrize("config", CONFIGS)
@pytest.mark.parametrize("cloud", CLOUDS)
def test_variant_matches_pcl_bin_for_bin(test_data, cloud, config):
    i = CONFIGS.index(config)
    assert_same_bins_as_pcl(ours(test_data, cloud, i), goldens(test_data)[f"{cloud}_vfh"][i])


def shifted_goldens(ref: np.ndarray):
    """(what, mutated golden) for each non-empty block: the block rolled by one bin, and one hit of its first
    non-empty bin moved to the neighbouring bin (the histogram's total unchanged)."""
    for block, (lo, hi) in BLOCKS.items():
        part = ref[lo:hi]
        nonzero = np.flatnonzero(part)
        if len(nonzero) == 0:
            continue
        rolled = ref.copy()
        rolled[lo:hi] = np.roll(part, 1)
        yield f"{block} rolled by one bin", rolled
        k = lo + int(nonzero[0])
        hit = np.float32(part[nonzero].min())  # the smallest non-empty bin holds at least one increment
        neighbour = k + 1 if k + 1 < hi else k - 1
        moved = ref.copy()
        moved[k] -= hit
        moved[neighbour] += hit
        yield f"{block}: one hit of bin {k} moved to bin {neighbour}", moved


@pytest.mark.parametrize("config", CONFIGS)
def test_comparison_fails_when_a_bin_shifts(test_data, config):
    i = CONFIGS.index(config)
    for cloud in CLOUDS:
        ref = goldens(test_data)[f"{cloud}_vfh"][i]
        checked = set()
        for what, mutated in shifted_goldens(ref):
            assert not same_bins_as_pcl(ours(test_data, cloud, i), mutated), (cloud, what)
            checked.add(what.split()[0].rstrip(":"))
        size = config.split("/")[2].startswith("size")
        assert checked == set(BLOCKS) - (set() if size else {"f4"}), (cloud, config, checked)


def block(v: np.ndarray, name: str) -> np.ndarray:
    lo, hi = BLOCKS[name]
    return v[lo:hi]


@pytest.mark.parametrize("cloud", CLOUDS)
def test_goldens_differ_where_the_branches_differ(test_data, cloud):
    """PCL's outputs tell the branches apart, so each branch's comparison above checks that branch."""
    g = goldens(test_data)
    h = dict(zip(CONFIGS, g[f"{cloud}_vfh"].astype(np.float64)))
    n = len(g[f"{cloud}_cloud"])
    for key, v in h.items():
        variant, nb, size, vp = key.split("/")
        pair_sum = 100.0 * n / (n - 1) if nb == "nb1" else float(n)
        for name in ("f1", "f2", "f3"):  # every point gives one pair feature (no point is the centroid)
            assert block(v, name).sum() == pytest.approx(pair_sum, rel=1e-4), (key, name)
        assert block(v, "viewpoint").sum() == pytest.approx(100.0 if nb == "nb1" else n, rel=1e-4), key
        if size.startswith("size"):
            assert block(v, "f4").sum() == pytest.approx(pair_sum, rel=1e-4), key
        else:
            assert not block(v, "f4").any(), key
        if nb == "nb0":  # counts, which are the normalised histogram over its increment
            normalised = h[key.replace("nb0", "nb1")]
            np.testing.assert_array_equal(v[:180], np.round(normalised[:180] * (n - 1) / 100.0))
            np.testing.assert_array_equal(v[180:], np.round(normalised[180:] * n / 100.0))
    for nb in ("nb1", "nb0"):
        for vp in ("origin", "custom"):
            for variant in ("pcl-1.13", "pcl-1.8", "rusu2010"):
                base = f"{variant}/{nb}/nosize/{vp}"
                np.testing.assert_array_equal(h[base], h[f"{variant}/{nb}/nosize_normdist/{vp}"])
                assert not np.array_equal(block(h[f"{variant}/{nb}/size/{vp}"], "f4"),
                                          block(h[f"{variant}/{nb}/size_normdist/{vp}"], "f4"))
                assert not np.array_equal(block(h[f"{variant}/{nb}/nosize/origin"], "viewpoint"),
                                          block(h[f"{variant}/{nb}/nosize/custom"], "viewpoint"))
            new, legacy, rusu = (h[f"{v}/{nb}/size_normdist/{vp}"] for v in ("pcl-1.13", "pcl-1.8", "rusu2010"))
            np.testing.assert_array_equal(block(new, "f1"), block(legacy, "f1"))
            for name in ("f2", "f3"):  # PCL >= 1.10.1 bins the cosines f2, f3 as angles
                assert not np.array_equal(block(new, name), block(legacy, name))
                np.testing.assert_array_equal(block(legacy, name), block(rusu, name))
            # rusu2010: a 3-D view direction and a 3-D largest distance instead of PCL's 4-vectors
            assert not np.array_equal(block(legacy, "viewpoint"), block(rusu, "viewpoint"))
            assert not np.array_equal(block(legacy, "f4"), block(rusu, "f4"))


def test_goldens_agree_with_the_older_pcl_goldens(test_data):
    """The oracle's default and size/normalised-distance bun0 outputs are pcl-1.13.txt's PCL 1.13 vectors, and
    its pre-1.10.1 binning gives the counts of vfh-bun0-legacy-f23.txt (a float64 reference)."""
    g = goldens(test_data)
    h = dict(zip(CONFIGS, g["bun0_vfh"]))

    def line(name, file):
        for text in (test_data / "descriptors" / file).read_text().splitlines():
            if text.startswith(name + " "):
                return np.array(text.split()[1:], dtype=np.float64)
        raise KeyError(name)

    for key, name in [("pcl-1.13/nb1/nosize/origin", "VFH_bun0_filenormals_default"),
                      ("pcl-1.13/nb1/size_normdist/origin", "VFH_bun0_filenormals_size_normdist")]:
        np.testing.assert_array_equal(h[key], line(name, "pcl-1.13.txt").astype(np.float32))
    legacy = line("VFH_bun0_filenormals_legacy_f23", "vfh-bun0-legacy-f23.txt")
    n = len(g["bun0_cloud"])
    np.testing.assert_array_equal(np.round(h["pcl-1.8/nb1/nosize/origin"] * (n - 1) / 100),
                                  np.round(legacy * (n - 1) / 100))
