"""Regenerate ``pcl_golden.json``: PCL 1.13 (``pcl_ref``) reference outputs for the segmentation tests.

Run from the repository root (needs ../shared and the pcl_ref oracle)::

    .venv/bin/python tests/data/segmentation/make_golden.py

For each real scene at a 5 mm voxel grid it records:

* PCL's voxel count, plane (RANSAC, T = 0.01, 1000 iterations) and cluster sizes
  (``pcl_ref segment SCENE 0.01 0.02 50 25000 0 0.005``);
* the partition of IDENTICAL points by PCL's EuclideanClusterExtraction: our voxel grid
  (``pcl_rounding=True``) minus the points within 1 cm of PCL's plane, rounded to float32, are written
  to a PCD together with a far synthetic plane (z = -10 m, more points than the scene) that PCL's
  plane step removes exactly; PCL then clusters exactly our points (ExtractIndices keeps their
  order). Sizes of all clusters of >= 10 points (pcl_ref runs ESF on each cluster, which can loop
  forever on tiny ones) and of those of 50..25000 points are stored.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
sys.path.insert(0, str(ROOT))

from semslam.io import read_point_cloud
from semslam.segmentation import voxel_downsample

SHARED = Path(os.environ.get("SEMSLAM_SHARED", ROOT.parent / "shared"))
PCL_REF = os.environ.get("PCL_REF", str(Path.home() / ".cache/pcl_oracle/pcl_ref"))
SCENES = ("table_scene_mug_stereo_textured", "milk_cartoon_all_small_clorox")
LEAF, DIST, TOL = 0.005, 0.01, 0.02


def pcl_segment(path: Path, *args) -> dict:
    out = subprocess.run(
        [PCL_REF, "segment", str(path), *map(str, args)], check=True, capture_output=True, text=True
    ).stdout
    return json.loads(out.strip().splitlines()[-1])


def write_ascii_pcd(path: Path, pts: np.ndarray) -> None:
    body = "\n".join(" ".join(f"{v:.9g}" for v in row) for row in pts.astype(np.float32))
    n = len(pts)
    path.write_text(
        f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA ascii\n{body}\n"
    )


def remaining_after_plane(points: np.ndarray, plane: list[float]) -> np.ndarray:
    """Points at distance >= DIST from ``plane`` (PCL keeps d < T as inliers), rounded to float32."""
    coeff = np.asarray(plane, float)
    coeff /= np.linalg.norm(coeff[:3])
    rest = points[np.abs(points @ coeff[:3] + coeff[3]) >= DIST]
    return rest.astype(np.float32).astype(np.float64)


def main() -> None:
    golden = {
        "pcl_version": "1.13 (pcl_ref)",
        "leaf_m": LEAF,
        "distance_threshold_m": DIST,
        "cluster_tolerance_m": TOL,
        "scenes": {},
    }
    for scene in SCENES:
        path = SHARED / "data" / "real" / f"{scene}.pcd"
        ref = pcl_segment(path, DIST, TOL, 50, 25000, 0, LEAF)
        vox = voxel_downsample(read_point_cloud(path).points_xyz_m, LEAF, pcl_rounding=True)
        assert len(vox) == ref["points"], (len(vox), ref["points"])
        rest = remaining_after_plane(vox, ref["plane"])
        side = int(np.ceil(np.sqrt(len(rest) + 1000)))
        gx, gy = np.meshgrid(np.arange(side) * 0.05, np.arange(side) * 0.05)
        synthetic = np.c_[gx.ravel(), gy.ravel(), np.full(side * side, -10.0)]
        with tempfile.TemporaryDirectory() as tmp:
            pcd = Path(tmp) / "rest.pcd"
            write_ascii_pcd(pcd, np.r_[rest, synthetic])
            all_ = pcl_segment(pcd, 1e-5, TOL, 10, 10**9, 0, 0)  # ESF can loop on tiny clusters
            kept = pcl_segment(pcd, 1e-5, TOL, 50, 25000, 0, 0)
        assert all_["plane_inliers"] == len(synthetic) == kept["plane_inliers"], all_
        golden["scenes"][scene] = {
            "pcl_pipeline": {
                k: ref[k] for k in ("points", "plane_inliers", "plane", "clusters", "sizes")
            },
            "n_remaining": len(rest),
            "pcl_sizes_min10": all_["sizes"],
            "pcl_sizes_50_25000": kept["sizes"],
        }
        print(scene, len(vox), len(rest), len(all_["sizes"]), kept["sizes"])
    (HERE / "pcl_golden.json").write_text(json.dumps(golden, indent=1) + "\n")


if __name__ == "__main__":
    main()
