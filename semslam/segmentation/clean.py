"""Cleaning a recorded view before it enters a database or the recogniser.

Real captures carry points that are not surface returns:

* **invalid depth at the sensor origin**: depth cameras (RealSense, Kinect through many drivers) store a
  pixel without depth as the point ``(0, 0, 0)`` of the camera frame instead of NaN. No real return lies
  exactly at the sensor origin, so such points are dropped (the test is exact: ``x == y == z == 0``, and
  the sensor origin is the cloud's ``viewpoint_xyz_m``).
* **drawn overlays**: tools that save what they displayed append axes or normal arrows as lines of
  evenly spaced points (the shared RealSense valve views carry 405 such points each). A sensor never
  returns a run of points that are collinear to float precision: any neighbourhood of real points has
  noise across the line. A point is part of a drawn line when its ``k`` nearest neighbours are collinear
  (second principal variance below ``1e-6`` of the first, and below ``(1e-3 * spacing)^2``) and at
  least ``min_line_points`` such points touch each other.

:func:`clean_view` applies both and says what it removed (:class:`CleanReport`); the database builder
and ``semslam db build --clean`` (on by default for view folders) use it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..cloud import PointCloud
from ..errors import InputError

__all__ = ["CleanReport", "clean_view", "drawn_line_mask", "origin_mask"]

#: Neighbours (the point included) whose spread decides whether a point lies on a drawn line.
LINE_NEIGHBOURS = 6
#: Second principal variance over the first below which a neighbourhood is collinear to float precision.
COLLINEAR_RATIO = 1e-6


@dataclass(frozen=True)
class CleanReport:
    """What :func:`clean_view` removed: ``n_in`` points read, ``n_origin`` at the sensor origin,
    ``n_drawn`` on drawn lines (in ``n_lines`` lines), ``n_out`` kept."""

    n_in: int
    n_origin: int
    n_drawn: int
    n_lines: int
    n_out: int

    def to_dict(self) -> dict:
        return {"n_in": self.n_in, "n_origin": self.n_origin, "n_drawn": self.n_drawn, "n_lines": self.n_lines,
                "n_out": self.n_out}


def origin_mask(points_xyz_m: np.ndarray, viewpoint_xyz_m: np.ndarray) -> np.ndarray:
    """True for the points exactly at the sensor origin (invalid depth stored as a point)."""
    return np.all(points_xyz_m == np.asarray(viewpoint_xyz_m, dtype=float)[None, :], axis=1)


def drawn_line_mask(points_xyz_m: np.ndarray, *, min_line_points: int = 10) -> tuple[np.ndarray, int]:
    """True for the points of drawn straight lines (see the module docstring), and the number of lines."""
    pts = np.asarray(points_xyz_m, dtype=float)
    n = len(pts)
    if n < max(LINE_NEIGHBOURS, min_line_points):
        return np.zeros(n, dtype=bool), 0
    tree = cKDTree(pts)
    dist, idx = tree.query(pts, LINE_NEIGHBOURS)
    spacing = float(np.median(dist[:, 1])) if np.isfinite(dist[:, 1]).any() else 0.0
    nb = pts[idx] - pts[idx].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", nb, nb) / LINE_NEIGHBOURS
    ev = np.linalg.eigvalsh(cov)  # ascending
    first, second = ev[:, 2], ev[:, 1]
    collinear = (first > 0) & (second <= COLLINEAR_RATIO * first) & (second <= (1e-3 * spacing) ** 2)
    cand = np.flatnonzero(collinear)
    if len(cand) < min_line_points:
        return np.zeros(n, dtype=bool), 0
    # touching collinear points form one line; short runs are left alone
    rows = np.repeat(np.arange(len(cand)), LINE_NEIGHBOURS)
    pos = np.full(n, -1)
    pos[cand] = np.arange(len(cand))
    cols = pos[idx[cand].ravel()]
    keep = cols >= 0
    graph = coo_matrix((np.ones(int(keep.sum())), (rows[keep], cols[keep])), shape=(len(cand), len(cand)))
    n_comp, lab = connected_components(graph, directed=False)
    sizes = np.bincount(lab, minlength=n_comp)
    big = sizes >= min_line_points
    mask = np.zeros(n, dtype=bool)
    mask[cand[big[lab]]] = True
    return mask, int(big.sum())


def clean_view(cloud: PointCloud, *, drop_origin: bool = True, drop_drawn_lines: bool = True,
               min_line_points: int = 10, name: str = "cloud") -> tuple[PointCloud, CleanReport]:
    """``cloud`` without invalid-origin points and drawn lines, and a :class:`CleanReport`.

    Raises :class:`~semslam.errors.InputError` naming ``name`` when no point is left.
    """
    if not isinstance(cloud, PointCloud):
        raise InputError(
            f"The 'cloud' argument of clean_view must be a PointCloud. Got {type(cloud).__name__} instead."
        )
    pts = cloud.points_xyz_m
    bad = origin_mask(pts, cloud.viewpoint_xyz_m) if drop_origin else np.zeros(len(pts), dtype=bool)
    n_origin = int(bad.sum())
    n_drawn = n_lines = 0
    if drop_drawn_lines:
        line, n_lines = drawn_line_mask(pts[~bad], min_line_points=min_line_points)
        n_drawn = int(line.sum())
        bad[np.flatnonzero(~bad)[line]] = True
    report = CleanReport(len(pts), n_origin, n_drawn, n_lines, int((~bad).sum()))
    if report.n_out == 0:
        raise InputError(f"The view {name} has no points left after cleaning: {report.n_in} read, "
                         f"{n_origin} at the sensor origin (invalid depth), {n_drawn} on drawn lines.")
    return (cloud if not bad.any() else cloud.select(np.flatnonzero(~bad))), report
