"""Regenerate segment_scene_golden.json: bit-level fingerprints of segment_scene and voxel_grid on
the tank_scene of tests/_support/scenes.py.

The committed file was written by the implementation before the latency pass (commit c184769:
sort-based voxel grid, NumPy cluster glue); the current implementation reproduces it byte for
byte (tests/cli/test_segment_cli.py::test_matches_golden_of_previous_implementation).

    .venv/bin/python tests/data/segmentation/make_scene_golden.py
"""

import hashlib
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[2])]

from tests._support.scenes import tank_scene

from semslam import segmentation as seg

CONFIGS = [
    {"voxel_leaf_m": 0.01, "min_cluster_size": 30},
    {
        "voxel_leaf_m": 0.004,
        "max_planes": 3,
        "min_plane_inliers": 50,
        "min_cluster_size": 5,
        "max_cluster_size": None,
    },
    {"voxel_leaf_m": None, "min_cluster_size": 100, "max_cluster_size": None},
]


def sha(a) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def main() -> None:
    out = {
        "generator": "semslam.segmentation before the latency pass (commit c184769), "
        "tank_scene() of tests/test_segment_cli.py",
        "cases": [],
    }
    for seed in (0, 1):
        cloud, _ = tank_scene(seed)
        for cfg in CONFIGS:
            r = seg.segment_scene(cloud, seg.SegmentationConfig(**cfg), seed=seed)
            pv = None if r.point_voxel is None else sha(r.point_voxel.astype(np.int64))
            planes = [
                {
                    "coefficients": p.coefficients.tolist(),
                    "n_inliers": p.n_inliers,
                    "rmse_m": p.rmse_m,
                    "n_iterations": p.n_iterations,
                    "n_scored": p.n_scored,
                }
                for p in r.planes
            ]
            out["cases"].append(
                {
                    "scene_seed": seed,
                    "config": cfg,
                    "seed": seed,
                    "n_segmented": r.segmented_cloud.n_points,
                    "centroids_sha": sha(r.segmented_cloud.points_xyz_m),
                    "intensity_sha": sha(r.segmented_cloud.intensity),
                    "point_voxel_sha": pv,
                    "planes": planes,
                    "n_after_planes": r.n_after_planes,
                    "cluster_sizes": r.cluster_sizes,
                    "clusters_sha": [sha(c.astype(np.int64)) for c in r.cluster_indices],
                    "input_indices_sha": [sha(r.input_indices(k)) for k in range(r.n_clusters)],
                }
            )
        for pcl_rounding in (False, True):
            g = seg.voxel_grid(cloud.points_xyz_m, 0.003, pcl_rounding=pcl_rounding)
            out["cases"].append(
                {
                    "scene_seed": seed,
                    "voxel_leaf_m": 0.003,
                    "pcl_rounding": pcl_rounding,
                    "n_voxels": g.n_voxels,
                    "centroids_sha": sha(g.points_xyz_m),
                    "point_voxel_sha": sha(g.point_voxel),
                    "counts_sha": sha(g.counts),
                }
            )
    with open(HERE / "segment_scene_golden.json", "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
