"""Numba kernels of Euclidean cluster extraction. Private: call
:func:`semslam.segmentation.extract_euclidean_clusters`, which validates its input.

Grid method (default). Points are binned in cubic cells of edge ``s = tol / sqrt(3) * (1 - 1e-9)``:
any two points of one cell are closer than ``tol``, so each occupied cell is connected and the
union-find runs over cells, not points. Two cells are joined as soon as ONE pair of their points is
closer than ``tol`` (strict, ``d**2 < tol**2`` in float64). Cells that can hold such a pair are at
most 2 cells apart per axis and not 2 apart on all three axes (116 neighbours, 58 visited per
cell), and are skipped when their points' bounding boxes are >= tol apart. The connected
components are exactly those of the graph "distance < tol" over points, i.e. PCL's flood fill.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _find(parent, i):
    root = i
    while parent[root] != root:
        root = parent[root]
    while parent[i] != root:  # path compression
        nxt = parent[i]
        parent[i] = root
        i = nxt
    return root


@njit(cache=True)
def _union(parent, a, b):
    ra = _find(parent, a)
    rb = _find(parent, b)
    if ra == rb:
        return
    if ra < rb:
        parent[rb] = ra
    else:
        parent[ra] = rb


@njit(cache=True)
def _cell_boxes(points, order, cell_start):
    """Axis-aligned bounding box (M, 6) = (min xyz, max xyz) of the points of each cell."""
    m = cell_start.shape[0] - 1
    boxes = np.empty((m, 6))
    for c in range(m):
        for a in range(3):
            boxes[c, a] = np.inf
            boxes[c, 3 + a] = -np.inf
        for r in range(cell_start[c], cell_start[c + 1]):
            p = order[r]
            for a in range(3):
                v = points[p, a]
                boxes[c, a] = min(boxes[c, a], v)
                boxes[c, 3 + a] = max(boxes[c, 3 + a], v)
    return boxes


@njit(cache=True)
def grid_components(points, order, cell_keys, cell_start, nx, ny, tol):
    """Component label (the smallest cell index of the component) of each cell.

    Parameters
    ----------
    points : (N, 3) float64, the points
    order : (N,) int64, point indices sorted by cell key
    cell_keys : (M,) int64, sorted unique keys ``x + nx*(y + ny*z)`` of the occupied cells, with
        cell coordinates offset by +2 so that neighbours never wrap to another row
    cell_start : (M + 1,) int64, cell c holds ``order[cell_start[c]:cell_start[c+1]]``
    nx, ny : int, padded grid extents along x and y
    tol : float, cluster tolerance

    Returns
    -------
    (M,) int64 component root of each cell.

    Each cell pair is visited once, from the cell with the smaller key: only the 13 rows (dy, dz)
    with dz > 0, or dz == 0 and dy >= 0, can hold larger keys. Because the cells are visited in key
    order, the start of each neighbour row only moves forward (one pointer per row, no search).
    Pairs whose bounding boxes are >= tol apart, or already in one component, are skipped.
    """
    m = cell_keys.shape[0]
    tol2 = tol * tol
    parent = np.arange(m)
    boxes = _cell_boxes(points, order, cell_start)
    n_rows = 13
    row_offset = np.empty(n_rows, np.int64)
    row_dy = np.empty(n_rows, np.int64)
    row_dz = np.empty(n_rows, np.int64)
    r = 0
    for dz in range(3):
        for dy in range(-2, 3):
            if dz == 0 and dy < 0:
                continue
            row_offset[r] = nx * (dy + ny * dz)
            row_dy[r] = dy
            row_dz[r] = dz
            r += 1
    ptr = np.zeros(n_rows, np.int64)
    for a in range(m):
        key_a = cell_keys[a]
        for r in range(n_rows):
            row = key_a + row_offset[r]
            b = ptr[r]
            while b < m and cell_keys[b] < row - 2:
                b += 1
            ptr[r] = b
            while b < m and cell_keys[b] <= row + 2:
                if b > a:
                    dx = cell_keys[b] - row
                    skip = abs(dx) == 2 and abs(row_dy[r]) == 2 and row_dz[r] == 2
                    if not skip:
                        gap2 = 0.0
                        for ax in range(3):
                            g = max(
                                boxes[b, ax] - boxes[a, 3 + ax], boxes[a, ax] - boxes[b, 3 + ax]
                            )
                            if g > 0.0:
                                gap2 += g * g
                        skip = gap2 >= tol2
                    if not skip and _find(parent, a) != _find(parent, b):
                        joined = False
                        for ia in range(cell_start[a], cell_start[a + 1]):
                            pa = order[ia]
                            xa = points[pa, 0]
                            ya = points[pa, 1]
                            za = points[pa, 2]
                            for ib in range(cell_start[b], cell_start[b + 1]):
                                pb = order[ib]
                                ddx = points[pb, 0] - xa
                                ddy = points[pb, 1] - ya
                                ddz = points[pb, 2] - za
                                if ddx * ddx + ddy * ddy + ddz * ddz < tol2:
                                    joined = True
                                    break
                            if joined:
                                break
                        if joined:
                            _union(parent, a, b)
                b += 1
    roots = np.empty(m, np.int64)
    for c in range(m):
        roots[c] = _find(parent, c)
    return roots


@njit(cache=True)
def pair_components(n, pairs):
    """Component root of each of ``n`` nodes given an (E, 2) int64 edge list (union-find)."""
    parent = np.arange(n)
    for e in range(pairs.shape[0]):
        _union(parent, pairs[e, 0], pairs[e, 1])
    roots = np.empty(n, np.int64)
    for i in range(n):
        roots[i] = _find(parent, i)
    return roots
