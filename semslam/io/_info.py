"""What ``semslam info`` reports about a point-cloud file (pure function; the CLI only prints it)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

_KIND = {"f": "F", "i": "I", "u": "U"}


def describe_file(path: str | os.PathLike) -> dict[str, Any]:
    """A JSON-ready description of a PCD, PLY or NPY file.

    Keys: ``path``, ``format``, ``encoding``, ``points``, ``valid_points``, ``nan_points`` (x, y or z not
    finite), ``width``, ``height``, ``organized``, ``fields`` (list of ``{name, size, type, count}`` as in a
    PCD header, padding included), ``viewpoint`` (``xyz_m``, ``quat_wxyz``), ``bounds`` (``min_xyz_m``,
    ``max_xyz_m`` of the valid points, None when there are none).
    """
    from . import _suffix, check_regular_file
    from .pcd import read_pcd

    suffix = _suffix(path)
    check_regular_file(Path(path))
    if suffix == ".pcd":
        data = read_pcd(path)
        fields = [
            {"name": f.name, "size": f.size, "type": f.type, "count": f.count}
            for f in data.pcd_fields
        ]
        valid = data.valid_mask
        has_xyz = all(c in data.fields and data.fields[c].ndim == 1 for c in "xyz")
        xyz = (
            np.stack([data.fields[c][valid].astype(np.float64) for c in "xyz"], 1)
            if has_xyz
            else None
        )
        return _payload(
            path,
            "pcd",
            data.encoding,
            data.n_points,
            data.n_nan,
            data.width,
            data.height,
            fields,
            data.viewpoint,
            xyz,
        )
    from . import read_point_cloud

    cloud = read_point_cloud(path, drop_nan=True)
    if suffix == ".ply":
        import plyfile

        ply = plyfile.PlyData.read(str(path))  # already read once without error by read_point_cloud
        encoding = (
            "ascii"
            if ply.text
            else {"<": "binary_little_endian", ">": "binary_big_endian"}.get(
                ply.byte_order, "binary_little_endian" if ply.byte_order == "=" else ply.byte_order
            )
        )
        vertex = ply["vertex"].data
        fields = [_field(name, vertex.dtype[name]) for name in vertex.dtype.names]
        total = len(vertex)
    else:
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
        encoding = f"npy {arr.dtype}"
        names = ["x", "y", "z", "nx", "ny", "nz"][: arr.shape[1]]
        fields = [_field(n, arr.dtype) for n in names]
        total = arr.shape[0]
    vp = np.concatenate([cloud.viewpoint_xyz_m, [1.0, 0.0, 0.0, 0.0]])
    return _payload(
        path,
        suffix[1:],
        encoding,
        total,
        total - cloud.n_points,
        total,
        1,
        fields,
        vp,
        cloud.points_xyz_m,
    )


def _field(name: str, dtype: np.dtype) -> dict[str, Any]:
    return {
        "name": name,
        "size": dtype.itemsize,
        "type": _KIND.get(dtype.kind, dtype.kind),
        "count": 1,
    }


def _payload(
    path, fmt, encoding, n, n_nan, width, height, fields, viewpoint, xyz
) -> dict[str, Any]:
    bounds = None
    if xyz is not None and len(xyz):
        bounds = {"min_xyz_m": xyz.min(axis=0).tolist(), "max_xyz_m": xyz.max(axis=0).tolist()}
    return {
        "path": str(path),
        "format": fmt,
        "encoding": encoding,
        "points": int(n),
        "valid_points": int(n - n_nan),
        "nan_points": int(n_nan),
        "width": int(width),
        "height": int(height),
        "organized": int(height) > 1,
        "fields": fields,
        "viewpoint": {
            "xyz_m": [float(v) for v in viewpoint[:3]],
            "quat_wxyz": [float(v) for v in viewpoint[3:]],
        },
        "bounds": bounds,
    }


def format_info(info: dict[str, Any]) -> str:
    """The human-readable text of :func:`describe_file`'s dictionary."""

    def num(v: float) -> str:
        return f"{v:.6g}"

    fields = ", ".join(
        f"{f['name']} {f['type']}{f['size']}" + (f"x{f['count']}" if f["count"] > 1 else "")
        for f in info["fields"]
    )
    vp = info["viewpoint"]
    lines = [
        f"file       {info['path']}",
        f"format     {info['format']} ({info['encoding']})",
        f"points     {info['points']} ({info['valid_points']} valid, {info['nan_points']} NaN)",
        f"size       {info['width']} x {info['height']}"
        + (" (organized)" if info["organized"] else ""),
        f"fields     {fields}",
        f"viewpoint  xyz_m ({', '.join(map(num, vp['xyz_m']))}), quat_wxyz ({', '.join(map(num, vp['quat_wxyz']))})",
    ]
    b = info["bounds"]
    if b is None:
        lines.append("bounds     none (no valid point)")
    else:
        axes = " ".join(
            f"{a} [{num(lo)}, {num(hi)}]"
            for a, lo, hi in zip("xyz", b["min_xyz_m"], b["max_xyz_m"])
        )
        lines.append(f"bounds     {axes} m")
    return "\n".join(lines)
