"""PLY (via plyfile: ascii, binary little/big endian) and ``.npy`` point clouds.

PLY: the ``vertex`` element gives x y z, normals (``nx ny nz`` or ``normal_x normal_y normal_z``), ``intensity``
and any other scalar property (kept in ``PointCloud.fields`` at its dtype); other elements (faces of a mesh)
are ignored. NPY: a float array (N, 3) = x y z or (N, 6) = x y z nx ny nz.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np
import plyfile

from .._atomic import atomic_open
from ..cloud import PointCloud
from ..errors import InputError, PcdError

__all__ = ["read_npy", "read_ply", "write_npy", "write_ply"]

PLY_ENCODINGS = ("ascii", "binary_little_endian", "binary_big_endian")
_NORMALS = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))
_PLY_DTYPES = ("i1", "u1", "i2", "u2", "i4", "u4", "f4", "f8")


def _check_file(path: Path) -> None:
    from . import check_regular_file

    check_regular_file(path)
    if path.stat().st_size == 0:
        raise PcdError(f"Cannot read point-cloud file '{path}': the file is empty.")


def _make_cloud(
    path: Path, pts: np.ndarray, normals, intensity, fields: dict, drop_nan: bool, frame_id: str
) -> PointCloud:
    valid = np.isfinite(pts).all(axis=1)
    if not valid.all():
        if not drop_nan:
            raise PcdError(
                f"Point-cloud file '{path}' has {np.count_nonzero(~valid)} point(s) with NaN or infinite "
                "coordinates; pass drop_nan=True to remove them."
            )
        pts = pts[valid]
        normals = None if normals is None else normals[valid]
        intensity = None if intensity is None else intensity[valid]
        fields = {k: v[valid] for k, v in fields.items()}
    try:
        return PointCloud(pts, normals, intensity, np.zeros(3), frame_id, fields)
    except InputError as exc:
        raise PcdError(
            f"Point-cloud file '{path}' cannot be turned into a PointCloud: {exc}"
        ) from None


def read_ply(
    path: str | os.PathLike, *, drop_nan: bool = True, frame_id: str = "sensor"
) -> PointCloud:
    """Read the vertices of a PLY file (ascii or binary) into a :class:`PointCloud` (see module doc)."""
    path = Path(path)
    _check_file(path)
    try:
        ply = plyfile.PlyData.read(str(path))
        vertex = ply["vertex"].data
    except KeyError:
        raise PcdError(f"Cannot read PLY file '{path}': it has no 'vertex' element.") from None
    except (
        plyfile.PlyParseError,
        ValueError,
        EOFError,
        UnicodeDecodeError,
        IndexError,
        struct.error,
        TypeError,
        MemoryError,
    ) as exc:
        raise PcdError(f"Cannot read PLY file '{path}': {exc}.") from None
    except OSError as exc:
        raise PcdError(f"Cannot read PLY file '{path}': {exc.strerror or exc}.") from None
    names = list(vertex.dtype.names or ())
    missing = [c for c in "xyz" if c not in names]
    if missing:
        raise PcdError(
            f"Cannot read PLY file '{path}': the vertex element has no {', '.join(missing)} property "
            f"(properties: {', '.join(names)})."
        )
    pts = np.stack([vertex[c].astype(np.float64) for c in "xyz"], axis=1)
    used = {"x", "y", "z"}
    normals = None
    for trio in _NORMALS:
        if all(c in names for c in trio):
            normals = np.stack([vertex[c].astype(np.float64) for c in trio], axis=1)
            used.update(trio)
            break
    intensity = None
    if "intensity" in names:
        intensity = vertex["intensity"].astype(np.float64)
        used.add("intensity")
    fields = {}
    for name in names:
        if name in used:
            continue
        col = vertex[name]
        if col.dtype == object:
            lengths = {len(v) for v in col}
            if len(lengths) > 1:
                raise PcdError(
                    f"Cannot read PLY file '{path}': the list property {name!r} has rows of different "
                    "lengths; a point field needs one length."
                )
            col = np.stack(col) if len(col) else np.empty((0, 0))
        fields[name] = np.ascontiguousarray(col, dtype=col.dtype.newbyteorder("="))
    return _make_cloud(path, pts, normals, intensity, fields, drop_nan, frame_id)


def write_ply(
    path: str | os.PathLike,
    cloud: PointCloud,
    *,
    encoding: str = "binary_little_endian",
    coords_dtype: str = "float32",
) -> None:
    """Write ``cloud`` as the vertex element of a PLY file, atomically.

    ``encoding``: ``binary_little_endian`` (also for ``binary``/``binary_compressed``), ``binary_big_endian``
    or ``ascii``. Normals are written as ``nx ny nz``. Fields must be (N,) of a PLY type (int/uint 8-32,
    float32/64); others raise :class:`PcdError`.
    """
    where = str(path)
    enc = {"binary": "binary_little_endian", "binary_compressed": "binary_little_endian"}.get(
        encoding, encoding
    )
    if enc not in PLY_ENCODINGS:
        raise PcdError(
            f"Cannot write PLY file '{where}': encoding must be one of {', '.join(PLY_ENCODINGS)}, "
            f"got {encoding!r}."
        )
    if coords_dtype not in ("float32", "float64"):
        raise PcdError(
            f"The 'coords_dtype' argument must be 'float32' or 'float64'. Got {coords_dtype!r} instead."
        )
    cols: dict[str, np.ndarray] = {}
    for i, c in enumerate("xyz"):
        cols[c] = cloud.points_xyz_m[:, i].astype(coords_dtype)
    if cloud.normals_xyz is not None:
        for i, c in enumerate(("nx", "ny", "nz")):
            cols[c] = cloud.normals_xyz[:, i].astype(coords_dtype)
    if cloud.intensity is not None:
        cols["intensity"] = cloud.intensity.astype(coords_dtype)
    for name, arr in cloud.fields.items():
        if name in cols:
            raise PcdError(
                f"Cannot write PLY file '{where}': field {name!r} clashes with a standard property."
            )
        code = arr.dtype.newbyteorder("=").str[1:]
        if arr.ndim != 1 or code not in _PLY_DTYPES:
            raise PcdError(
                f"Cannot write PLY file '{where}': field {name!r} of shape {arr.shape} and dtype "
                f"{arr.dtype} has no PLY scalar type (use .pcd for multi-value or 64-bit int fields)."
            )
        cols[name] = arr
    if coords_dtype == "float32" and any(np.isinf(cols[c]).any() for c in "xyz"):
        raise PcdError(
            f"Cannot write PLY file '{where}': a coordinate exceeds the float32 range "
            "(use coords_dtype='float64')."
        )
    order = ">" if enc == "binary_big_endian" else "<"
    table = np.empty(
        cloud.n_points, dtype=[(k, v.dtype.newbyteorder(order)) for k, v in cols.items()]
    )
    for k, v in cols.items():
        table[k] = v
    ply = plyfile.PlyData(
        [plyfile.PlyElement.describe(table, "vertex")], text=enc == "ascii", byte_order=order
    )
    if Path(path).is_dir():
        raise PcdError(f"Cannot write PLY file '{where}': it is a directory.")
    try:
        with atomic_open(path, "wb") as fh:
            ply.write(fh)
    except OSError as exc:
        raise PcdError(f"Cannot write PLY file '{where}': {exc.strerror or exc}.") from None


def read_npy(
    path: str | os.PathLike, *, drop_nan: bool = True, frame_id: str = "sensor"
) -> PointCloud:
    """Read a ``.npy`` array of shape (N, 3) (x y z) or (N, 6) (x y z nx ny nz) into a PointCloud."""
    path = Path(path)
    _check_file(path)
    try:
        arr = np.load(path, allow_pickle=False)
    except (
        ValueError,
        EOFError,
        OSError,
        UnicodeDecodeError,
        SyntaxError,
        TypeError,
        MemoryError,
    ) as exc:
        raise PcdError(f"Cannot read NPY file '{path}': {exc}.") from None
    if (
        not isinstance(arr, np.ndarray)
        or arr.ndim != 2
        or arr.shape[1] not in (3, 6)
        or arr.dtype.kind not in "fiu"
    ):
        shape = getattr(arr, "shape", None)
        raise PcdError(
            f"Cannot read NPY file '{path}': expected a numeric array of shape (N, 3) or (N, 6), got "
            f"shape {shape} and dtype {getattr(arr, 'dtype', type(arr).__name__)}."
        )
    arr = arr.astype(np.float64)
    normals = arr[:, 3:6] if arr.shape[1] == 6 else None
    return _make_cloud(path, arr[:, :3], normals, None, {}, drop_nan, frame_id)


def write_npy(path: str | os.PathLike, cloud: PointCloud) -> None:
    """Write ``cloud`` as a float64 ``.npy`` array (N, 3), or (N, 6) with normals, atomically.

    An NPY file holds coordinates and normals only: a cloud with intensity or other fields raises
    :class:`PcdError` (write .pcd instead) rather than losing them.
    """
    where = str(path)
    extra = (["intensity"] if cloud.intensity is not None else []) + list(cloud.fields)
    if extra:
        raise PcdError(
            f"Cannot write NPY file '{where}': it holds x y z [nx ny nz] only, and the cloud has "
            f"{', '.join(extra)} (write a .pcd file to keep them)."
        )
    arr = (
        cloud.points_xyz_m
        if cloud.normals_xyz is None
        else np.hstack([cloud.points_xyz_m, cloud.normals_xyz])
    )
    if Path(path).is_dir():
        raise PcdError(f"Cannot write NPY file '{where}': it is a directory.")
    try:
        with atomic_open(path, "wb") as fh:
            np.save(fh, np.ascontiguousarray(arr, dtype=np.float64))
    except OSError as exc:
        raise PcdError(f"Cannot write NPY file '{where}': {exc.strerror or exc}.") from None
