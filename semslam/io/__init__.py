"""Point-cloud files: PCD (PCL, any encoding), PLY and ``.npy``, chosen by the file suffix.

>>> cloud = read_point_cloud("scan.pcd")            # doctest: +SKIP
>>> write_point_cloud("scan.ply", cloud)            # doctest: +SKIP

Lower level: :func:`semslam.io.pcd.read_pcd` / :func:`~semslam.io.pcd.write_pcd` keep every PCD field at its
exact dtype, the organisation (WIDTH x HEIGHT) and the NaN points (``valid_mask``).
"""

from __future__ import annotations

import os
from pathlib import Path

from ..cloud import PointCloud
from ..errors import PcdError
from .pcd import PcdData, PcdField, read_pcd, write_pcd

__all__ = [
    "SUFFIXES",
    "PcdData",
    "PcdField",
    "read_pcd",
    "read_point_cloud",
    "write_pcd",
    "write_point_cloud",
]

SUFFIXES = (".pcd", ".ply", ".npy")


def _suffix(path: str | os.PathLike) -> str:
    suffix = Path(path).suffix.lower()
    if suffix not in SUFFIXES:
        raise PcdError(
            f"Point-cloud file '{path}' has suffix {suffix or '(none)'!r}; expected one of "
            f"{', '.join(SUFFIXES)}."
        )
    return suffix


def check_regular_file(path: Path) -> None:
    """A point-cloud path must be a regular file (after symlinks): a FIFO, a device such as /dev/urandom or
    /dev/zero, or a socket would block or never end. Raises :class:`PcdError` naming the file."""
    import stat

    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise PcdError(f"Cannot read point-cloud file '{path}': no such file.") from None
    except OSError as exc:
        raise PcdError(f"Cannot read point-cloud file '{path}': {exc.strerror or exc}.") from None
    if stat.S_ISDIR(mode):
        raise PcdError(f"Cannot read point-cloud file '{path}': it is a directory.")
    if not stat.S_ISREG(mode):
        raise PcdError(f"Cannot read point-cloud file '{path}': it is not a regular file (a FIFO, device or socket).")


def read_point_cloud(
    path: str | os.PathLike, *, drop_nan: bool = True, frame_id: str = "sensor"
) -> PointCloud:
    """Read a PCD, PLY or NPY file into a :class:`~semslam.cloud.PointCloud` (dispatch on the suffix).

    Parameters
    ----------
    path : path-like
        ``.pcd`` (ascii, binary, binary_compressed), ``.ply`` (ascii, binary little/big endian) or ``.npy``
        (float array of shape (N, 3) = x y z, or (N, 6) = x y z nx ny nz).
    drop_nan : bool
        Remove points whose x, y or z is NaN or infinite (organised scans). With False such points raise
        :class:`PcdError` (use :func:`read_pcd` and ``valid_mask`` to keep the organisation).
    frame_id : str
        Frame of the returned cloud.

    Returns
    -------
    PointCloud
        ``points_xyz_m`` float64 (N, 3); ``normals_xyz`` from normal_x/y/z (PCD) or nx/ny/nz (PLY);
        ``intensity``; every other field in ``fields``; ``viewpoint_xyz_m`` from the PCD VIEWPOINT.

    Raises
    ------
    PcdError
        Unknown suffix, missing/unreadable/corrupted file; the message names the file.
    """
    suffix = _suffix(path)
    check_regular_file(Path(path))
    if suffix == ".pcd":
        return read_pcd(path).to_point_cloud(drop_nan=drop_nan, frame_id=frame_id)
    from . import ply

    if suffix == ".ply":
        return ply.read_ply(path, drop_nan=drop_nan, frame_id=frame_id)
    return ply.read_npy(path, drop_nan=drop_nan, frame_id=frame_id)


def write_point_cloud(
    path: str | os.PathLike,
    cloud: PointCloud,
    *,
    encoding: str = "binary_compressed",
    coords_dtype: str = "float32",
) -> None:
    """Write ``cloud`` atomically (temporary file then rename); the format follows the suffix.

    Parameters
    ----------
    encoding : str
        PCD: ``binary_compressed`` (default), ``binary`` or ``ascii``. PLY: ``binary_little_endian``
        (also chosen for the PCD names ``binary``/``binary_compressed``), ``binary_big_endian`` or ``ascii``.
        Ignored for ``.npy``.
    coords_dtype : {"float32", "float64"}
        Storage of coordinates, normals and intensity in PCD/PLY (float32 is what PCL expects). ``.npy``
        always stores float64.

    Every field of ``cloud.fields`` is written (PCD: any (N,) or (N, K) numeric field; PLY: (N,) fields);
    a field the format cannot hold raises :class:`PcdError` rather than being dropped.
    """
    suffix = _suffix(path)
    if suffix == ".pcd":
        write_pcd(path, cloud, encoding=encoding, coords_dtype=coords_dtype)
        return
    from . import ply

    if suffix == ".ply":
        ply.write_ply(path, cloud, encoding=encoding, coords_dtype=coords_dtype)
    else:
        ply.write_npy(path, cloud)
