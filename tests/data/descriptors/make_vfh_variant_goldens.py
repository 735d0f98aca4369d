"""Regenerate ``vfh_variants_pcl.npz``: PCL's VFH for every variant and option branch of ``compute_vfh``.

    PCL_REF_VARIANTS=/tmp/pcl_oracle_build/build/pcl_ref \\
        .venv/bin/python tests/data/descriptors/make_vfh_variant_goldens.py

``PCL_REF_VARIANTS`` is a build of ``../shared/pcl_oracle`` whose ``pcl_ref.cpp`` has the extra command
``vfh_opts`` (README-vfh-variants.md says exactly what was added and how to build it). For each cloud and
each configuration it runs::

    pcl_ref vfh_opts CLOUD.pcd CODE CENTROID NORMALIZE_BINS NORMALIZE_DISTANCES SIZE_COMPONENT VPX VPY VPZ

with (CODE, CENTROID) = (pcl, 4d) for variant "pcl-1.13" (PCL 1.13's own ``pcl::VFHEstimation``),
(legacy, 4d) for "pcl-1.8" and (legacy, 3d) for "rusu2010" (PCL <= 1.10.0's ``vfh.hpp`` transcribed on
PCL 1.13's pair features; 3d = ``setUseGivenCentroid`` + ``setCentroidToUse`` with PCL's own centroid, so
the view direction is a 3-D unit vector). Before writing, it checks the transcription: ``transcribed113``
must equal ``pcl`` bit for bit in every configuration and both centroid modes.

Inputs are float32 clouds with normals (stored in the npz exactly as written for PCL):
- ``bun0``: PCL's bun0.pcd with the file's normals (397 points, ``bun0.npy`` here);
- ``milk``: 2000 points of PCL's milk.pcd (seed 31) with semslam's radius-0.01 m normals of the full scan;
- ``globe_valve``: the real RealSense view valves/globe_valve/pitch000_yaw000_30cm/1/RANSAC.pcd with
  semslam's radius-0.01 m normals (points without a finite normal dropped).
"""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from make_goldens import write_pcd  # noqa: E402  (the sibling generator's PCD writer)

ROOT = HERE.parents[2]
SHARED = Path(os.environ.get("SEMSLAM_SHARED", ROOT.parent / "shared"))
REAL = SHARED / "data" / "real"
PCL_REF = os.environ.get("PCL_REF_VARIANTS", "/tmp/pcl_oracle_build/build/pcl_ref")
TMP = Path(tempfile.mkdtemp(prefix="semslam_vfh_variants_"))

# variant of compute_vfh -> (CODE, CENTROID) of pcl_ref vfh_opts
ORACLE = {"pcl-1.13": ("pcl", "4d"), "pcl-1.8": ("legacy", "4d"), "rusu2010": ("legacy", "3d")}
# size branch -> (normalize_distances, size_component)
SIZE_BRANCHES = {"nosize": (False, False), "nosize_normdist": (True, False), "size": (False, True),
                 "size_normdist": (True, True)}
VIEWPOINTS = {"origin": (0.0, 0.0, 0.0), "custom": (0.25, -0.4, 1.5)}


def configs() -> list[str]:
    """Every configuration, as 'variant/nb0|nb1/size branch/viewpoint' (the key the test parses)."""
    return [f"{v}/nb{int(nb)}/{s}/{vp}" for v, nb, s, vp in
            itertools.product(ORACLE, (True, False), SIZE_BRANCHES, VIEWPOINTS)]


def parse(config: str) -> dict:
    """compute_vfh keyword arguments of a configuration key."""
    variant, nb, size, vp = config.split("/")
    normalize_distances, size_component = SIZE_BRANCHES[size]
    return {"variant": variant, "normalize_bins": nb == "nb1", "normalize_distances": normalize_distances,
            "size_component": size_component, "viewpoint_xyz_m": VIEWPOINTS[vp]}


def run_oracle(path: Path, code: str, centroid: str, kw: dict) -> np.ndarray:
    args = [PCL_REF, "vfh_opts", str(path), code, centroid, str(int(kw["normalize_bins"])),
            str(int(kw["normalize_distances"])), str(int(kw["size_component"])),
            *(f"{x:.9g}" for x in kw["viewpoint_xyz_m"])]
    out = subprocess.run(args, check=True, capture_output=True, text=True).stdout
    return np.array(json.loads(out.splitlines()[0])["bins"], dtype=np.float32)


def clouds() -> dict[str, np.ndarray]:
    sys.path.insert(0, str(ROOT))
    from semslam.descriptors import estimate_normals
    from semslam.io import read_point_cloud

    def with_normals(pts: np.ndarray) -> np.ndarray:
        pts = pts[np.isfinite(pts).all(axis=1) & (np.abs(pts).sum(axis=1) > 0)].astype(np.float64)
        normals = estimate_normals(pts, radius_m=0.01).normals_xyz
        ok = np.isfinite(normals).all(axis=1)
        return np.c_[pts[ok], normals[ok]].astype(np.float32)

    milk = with_normals(read_point_cloud(REAL / "milk.pcd").points_xyz_m)
    rng = np.random.default_rng(31)
    valve = REAL / "valves/globe_valve/pitch000_yaw000_30cm/1/RANSAC.pcd"
    return {
        "bun0": np.load(HERE / "bun0.npy")[:, :6].astype(np.float32),
        "milk": milk[np.sort(rng.choice(len(milk), 2000, replace=False))],
        "globe_valve": with_normals(read_point_cloud(valve).points_xyz_m),
    }


def main() -> None:
    keys = configs()
    kws = [parse(key) for key in keys]
    # the compute_vfh keyword arguments of each configuration, so that the test needs nothing from here
    out: dict[str, np.ndarray] = {
        "configs": np.array(keys),
        "variant": np.array([kw["variant"] for kw in kws]),
        "normalize_bins": np.array([kw["normalize_bins"] for kw in kws]),
        "normalize_distances": np.array([kw["normalize_distances"] for kw in kws]),
        "size_component": np.array([kw["size_component"] for kw in kws]),
        "viewpoint_xyz_m": np.array([kw["viewpoint_xyz_m"] for kw in kws], dtype=np.float64),
    }
    for name, cols in clouds().items():
        path = write_pcd(TMP / f"{name}.pcd", cols, "x y z normal_x normal_y normal_z")
        hists = []
        for key, kw in zip(keys, kws):
            code, centroid = ORACLE[kw["variant"]]
            hists.append(run_oracle(path, code, centroid, kw))
            if kw["variant"] != "pcl-1.8":  # check the transcription against PCL's class, both centroid modes
                a, b = run_oracle(path, "transcribed113", centroid, kw), run_oracle(path, "pcl", centroid, kw)
                assert np.array_equal(a, b), f"transcription differs from PCL 1.13: {name} {key} {centroid}"
        out[f"{name}_cloud"] = cols
        out[f"{name}_vfh"] = np.array(hists, dtype=np.float32)
        print(name, len(cols), "points,", len(keys), "configurations")
    np.savez_compressed(HERE / "vfh_variants_pcl.npz", **out)


if __name__ == "__main__":
    main()
