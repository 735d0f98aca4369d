"""Point-cloud descriptors as PCL computes them: normals, FPFH (per point), ESF and VFH (global),
plus the measured point spacing that makes their settings scale-free.

See /work/shared/design/pcl-algorithms.md for the PCL behaviour reproduced here.

The FPFH (only the RANSAC registration uses it) is imported from :mod:`semslam.descriptors.fpfh`: recognising a
scan does not load its kernels.
"""

from .esf import ESF_SIZE, compute_esf, glibc_rand
from .neighbors import Neighborhoods, find_neighbors
from .normals import NormalsResult, estimate_normals
from .spacing import point_spacing_m
from .vfh import VFH_SIZE, VFH_VARIANTS, compute_vfh

__all__ = [
    "ESF_SIZE",
    "Neighborhoods",
    "NormalsResult",
    "VFH_SIZE",
    "VFH_VARIANTS",
    "compute_esf",
    "compute_vfh",
    "estimate_normals",
    "find_neighbors",
    "glibc_rand",
    "point_spacing_m",
]

