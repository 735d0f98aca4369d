"""The point cloud every stage passes around."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from ._validation import as_float_array
from .errors import InputError


#: names of a per-point time field, in order of preference: seconds from the scan's start in a dataset directory,
#: the field names drivers use in a PointCloud2 (decoded to seconds by :mod:`semslam.io.ros.pointcloud2`)
POINT_TIME_FIELDS = ("t", "time", "timestamp", "time_offset", "offset_time", "time_offset_s")


@dataclass(frozen=True, eq=False)
class PointCloud:
    """An unorganised 3-D point cloud, validated on construction.

    Parameters
    ----------
    points_xyz_m : array-like of shape (N, 3)
        Point coordinates in metres, in frame ``frame_id``. Stored as float64; must be finite.
    normals_xyz : array-like of shape (N, 3), optional
        Unit surface normals. Rows may be NaN where a normal could not be estimated (as PCL does);
        stages that need normals skip or reject such rows and say so.
    intensity : array-like of shape (N,), optional
        Return intensity (sensor units).
    viewpoint_xyz_m : array-like of shape (3,)
        Sensor origin in the same frame (PCD ``VIEWPOINT``); normals are flipped towards it.
    frame_id : str
        Name of the frame the coordinates are expressed in (``"scanner"``, ``"object"``, ``"world"``...).
    fields : mapping of str to array of shape (N,) or (N, K)
        Any other per-point fields read from a file (``rgba``, ``curvature``, ``label`` ...). Kept so
        that nothing read is lost; copied and checked for length.
    """

    points_xyz_m: np.ndarray
    normals_xyz: np.ndarray | None = None
    intensity: np.ndarray | None = None
    viewpoint_xyz_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    frame_id: str = "sensor"
    fields: Mapping[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        pts = as_float_array("points_xyz_m", self.points_xyz_m, (None, 3), caller="PointCloud")
        n = len(pts)
        object.__setattr__(self, "points_xyz_m", _frozen(pts))
        if self.normals_xyz is not None:
            nrm = as_float_array("normals_xyz", self.normals_xyz, (n, 3), caller="PointCloud", finite=False)
            if np.isinf(nrm).any():
                raise InputError("The 'normals_xyz' argument of PointCloud must not contain infinite values.")
            object.__setattr__(self, "normals_xyz", _frozen(nrm))
        if self.intensity is not None:
            inten = as_float_array("intensity", self.intensity, (n,), caller="PointCloud", finite=False)
            object.__setattr__(self, "intensity", _frozen(inten))
        vp = as_float_array("viewpoint_xyz_m", self.viewpoint_xyz_m, (3,), caller="PointCloud")
        object.__setattr__(self, "viewpoint_xyz_m", _frozen(vp))
        if not isinstance(self.frame_id, str) or not self.frame_id:
            raise InputError(
                f"The 'frame_id' argument of PointCloud must be a non-empty string. Got {self.frame_id!r} instead."
            )
        checked: dict[str, np.ndarray] = {}
        for name, values in dict(self.fields).items():
            arr = np.asarray(values)
            if arr.ndim not in (1, 2) or len(arr) != n:
                raise InputError(
                    f"The field {name!r} of PointCloud must have {n} rows (one per point). Got shape {arr.shape} "
                    f"instead."
                )
            checked[str(name)] = _frozen(np.array(arr, copy=True))
        object.__setattr__(self, "fields", checked)

    def __len__(self) -> int:
        return len(self.points_xyz_m)

    @property
    def n_points(self) -> int:
        return len(self.points_xyz_m)

    @property
    def has_normals(self) -> bool:
        return self.normals_xyz is not None

    def select(self, indices: Any) -> "PointCloud":
        """A new cloud with the points at ``indices`` (int array or boolean mask), every field kept."""
        idx = np.asarray(indices)
        if idx.dtype == bool:
            if idx.shape != (self.n_points,):
                raise InputError(
                    f"The 'indices' mask of PointCloud.select must have shape ({self.n_points},). Got {idx.shape} "
                    f"instead."
                )
        elif idx.size and (idx.min() < -self.n_points or idx.max() >= self.n_points):
            raise InputError(
                f"The 'indices' argument of PointCloud.select must be in [0, {self.n_points}). "
                f"Got values from {idx.min()} to {idx.max()} instead."
            )
        return PointCloud(
            self.points_xyz_m[idx],
            None if self.normals_xyz is None else self.normals_xyz[idx],
            None if self.intensity is None else self.intensity[idx],
            self.viewpoint_xyz_m,
            self.frame_id,
            {k: v[idx] for k, v in self.fields.items()},
        )

    def with_normals(self, normals_xyz: Any) -> "PointCloud":
        """The same cloud with ``normals_xyz`` replaced."""
        return PointCloud(
            self.points_xyz_m, normals_xyz, self.intensity, self.viewpoint_xyz_m, self.frame_id, self.fields
        )

    def transformed(self, T_new_old: Any, frame_id: str | None = None) -> "PointCloud":
        """The cloud expressed in another frame: points, normals and viewpoint mapped by ``T_new_old``."""
        from .geometry import RigidTransform

        if not isinstance(T_new_old, RigidTransform):
            T_new_old = RigidTransform(T_new_old)
        normals = None if self.normals_xyz is None else self.normals_xyz @ T_new_old.rotation.T
        return PointCloud(
            T_new_old.apply(self.points_xyz_m),
            normals,
            self.intensity,
            T_new_old.apply(self.viewpoint_xyz_m[None])[0],
            frame_id or self.frame_id,
            self.fields,
        )

    def __repr__(self) -> str:
        extras = ["normals"] if self.normals_xyz is not None else []
        extras += ["intensity"] if self.intensity is not None else []
        extras += list(self.fields)
        return f"PointCloud(n_points={self.n_points}, frame_id={self.frame_id!r}, fields={extras})"


def _frozen(arr: np.ndarray) -> np.ndarray:
    arr = np.ascontiguousarray(arr)
    if arr.flags.writeable and arr.base is not None:
        arr = arr.copy()
    arr.setflags(write=False)
    return arr
