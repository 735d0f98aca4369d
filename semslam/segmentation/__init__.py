"""Segmentation of a scan into object clusters (Rusu et al. 2009, as in the seed papers).

* :func:`voxel_downsample` / :func:`voxel_grid`: PCL ``VoxelGrid`` (centroid per occupied voxel);
* :func:`fit_plane_rmsac` / :func:`remove_dominant_planes`: RMSAC plane(s) (PCL's ``SAC_RMSAC`` with
  the max-iterations cap always honoured and PCL 1.15's 1-point pre-test);
* :func:`extract_euclidean_clusters`: PCL ``EuclideanClusterExtraction`` (strict distance < tolerance);
* :func:`segment_scene`: the three stages with a :class:`SegmentationConfig`.
"""

from .clusters import euclidean_labels, extract_euclidean_clusters
from .plane import PlaneModel, PlaneRemovalResult, fit_plane_rmsac, remove_dominant_planes
from .scene import SegmentationConfig, SegmentationResult, segment_scene
from .voxel import VoxelGridResult, voxel_downsample, voxel_grid

__all__ = [
    "PlaneModel",
    "PlaneRemovalResult",
    "SegmentationConfig",
    "SegmentationResult",
    "VoxelGridResult",
    "euclidean_labels",
    "extract_euclidean_clusters",
    "fit_plane_rmsac",
    "remove_dominant_planes",
    "segment_scene",
    "voxel_downsample",
    "voxel_grid",
]
