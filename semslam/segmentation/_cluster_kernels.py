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


@njit(cache=True, nogil=True)
def _find(parent, i):
    root = i
    while parent[root] != root:
        root = parent[root]
    while parent[i] != root:  # path compression
        nxt = parent[i]
        parent[i] = root
        i = nxt
    return root


@njit(cache=True, nogil=True)
def _union(parent, a, b):
    ra = _find(parent, a)
    rb = _find(parent, b)
    if ra == rb:
        return
    if ra < rb:
        parent[rb] = ra
    else:
        parent[ra] = rb


@njit(cache=True, nogil=True)
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


#: Neighbour rows (dy, dz) of a cell that can hold larger keys (see :func:`grid_components`).
_N_ROWS = 13


@njit(cache=True, nogil=True)
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
    Pairs already in one component (root of ``a`` kept up to date), or whose bounding boxes are
    >= tol apart, are skipped.
    """
    m = cell_keys.shape[0]
    tol2 = tol * tol
    parent = np.arange(m)
    boxes = _cell_boxes(points, order, cell_start)
    row_offset, row_dy, row_dz = _neighbour_rows(nx, ny)
    n_rows = _N_ROWS
    ptr = np.zeros(n_rows, np.int64)
    for a in range(m):
        key_a = cell_keys[a]
        root_a = _find(parent, a)
        for r in range(n_rows):
            row = key_a + row_offset[r]
            b = ptr[r]
            while b < m and cell_keys[b] < row - 2:
                b += 1
            ptr[r] = b
            while b < m and cell_keys[b] <= row + 2:
                if b > a:
                    root_b = _find(parent, b)
                    skip = root_b == root_a  # already one component: nothing to learn
                    if not skip:
                        dx = cell_keys[b] - row
                        skip = abs(dx) == 2 and abs(row_dy[r]) == 2 and row_dz[r] == 2
                    if not skip:
                        skip = _box_gap2(boxes, a, b) >= tol2
                    if not skip and _cells_touch(points, order, cell_start, a, b, tol2):
                        # link the roots: the smaller index becomes the root
                        if root_a < root_b:
                            parent[root_b] = root_a
                        else:
                            parent[root_a] = root_b
                            root_a = root_b
                b += 1
    roots = np.empty(m, np.int64)
    for c in range(m):
        roots[c] = _find(parent, c)
    return roots


@njit(cache=True, nogil=True)
def _neighbour_rows(nx, ny):
    """The 13 neighbour rows (dy, dz) of :func:`grid_components` that can hold larger keys (dz > 0, or
    dz == 0 and dy >= 0): key offsets ``nx * (dy + ny * dz)`` (13,) int64, dy (13,) and dz (13,)."""
    n_rows = _N_ROWS
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
    return row_offset, row_dy, row_dz


@njit(cache=True, inline="always")
def _box_gap2(boxes, a, b):
    """Squared distance between the bounding boxes (rows of :func:`_cell_boxes`) of cells ``a`` and ``b``."""
    gap2 = 0.0
    for ax in range(3):
        g = max(
            boxes[b, ax] - boxes[a, 3 + ax], boxes[a, ax] - boxes[b, 3 + ax]
        )
        if g > 0.0:
            gap2 += g * g
    return gap2


@njit(cache=True, inline="always")
def _cells_touch(points, order, cell_start, a, b, tol2):
    """True when some point of cell ``a`` and some point of cell ``b`` are closer than the tolerance
    (squared distance < ``tol2``); stops at the first such pair."""
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
                return True
    return False


@njit(cache=True, nogil=True)
def pair_components(n, pairs):
    """Component root of each of ``n`` nodes given an (E, 2) int64 edge list (union-find)."""
    parent = np.arange(n)
    for e in range(pairs.shape[0]):
        _union(parent, pairs[e, 0], pairs[e, 1])
    roots = np.empty(n, np.int64)
    for i in range(n):
        roots[i] = _find(parent, i)
    return roots


@njit(cache=True, nogil=True)
def _radix_argsort(keys, max_key):
    """Stable argsort (N,) int64 of non-negative int64 ``keys`` <= ``max_key`` (LSD radix sort on
    11-bit digits). A copy of ``_voxel_kernels.radix_argsort``: numba's on-disk cache does not
    notice edits to a jitted callee in another module, so kernels here call only this file."""
    n = keys.shape[0]
    order = np.arange(n)
    k_cur = keys.copy()
    order_tmp = np.empty(n, np.int64)
    k_tmp = np.empty(n, np.int64)
    count = np.empty(2049, np.int64)
    shift = 0
    while shift == 0 or (shift < 63 and (max_key >> shift) > 0):
        count[:] = 0
        for i in range(n):
            count[((k_cur[i] >> shift) & 0x7FF) + 1] += 1
        if count[1] != n:
            for d in range(2048):
                count[d + 1] += count[d]
            for i in range(n):
                d = (k_cur[i] >> shift) & 0x7FF
                r = count[d]
                count[d] = r + 1
                order_tmp[r] = order[i]
                k_tmp[r] = k_cur[i]
            order, order_tmp = order_tmp, order
            k_cur, k_tmp = k_tmp, k_cur
        shift += 11
    return order, k_cur


@njit(cache=True, nogil=True)
def grid_labels(points, cell, tol):
    """Connected-component labels (N,) int64 of the points under "distance < tol", numbered by the
    smallest point index of each component, by the grid union-find (:func:`grid_components`) with
    cubic cells of edge ``cell`` (< tol / sqrt(3)). N >= 1. Returns ``(True, labels)``, or
    ``(False, empty)`` when the padded grid needs keys of 2**62 or more (use the k-d tree)."""
    n = points.shape[0]
    lo = np.full(3, np.inf)
    for i in range(n):
        for a in range(3):
            lo[a] = min(lo[a], points[i, a])
    ijk = np.empty((n, 3), np.int64)
    hi = np.zeros(3)
    for i in range(n):
        for a in range(3):
            v = np.floor((points[i, a] - lo[a]) / cell)
            hi[a] = max(hi[a], v)
            ijk[i, a] = np.int64(v)  # exact: checked below that the grid is small
    extent = hi + 5.0  # +2 padding on each side, +1
    if extent[0] * extent[1] * extent[2] >= 2.0**62:
        return False, np.empty(0, np.int64)
    nx = np.int64(extent[0])
    ny = np.int64(extent[1])
    keys = np.empty(n, np.int64)
    for i in range(n):
        keys[i] = (ijk[i, 0] + 2) + nx * ((ijk[i, 1] + 2) + ny * (ijk[i, 2] + 2))
    order, sorted_keys = _radix_argsort(keys, np.int64(extent[0] * extent[1] * extent[2]) - 1)
    m = 1
    for r in range(1, n):
        if sorted_keys[r] != sorted_keys[r - 1]:
            m += 1
    cell_keys = np.empty(m, np.int64)
    cell_start = np.empty(m + 1, np.int64)
    point_cell = np.empty(n, np.int64)
    c = -1
    for r in range(n):
        if r == 0 or sorted_keys[r] != sorted_keys[r - 1]:
            c += 1
            cell_keys[c] = sorted_keys[r]
            cell_start[c] = r
        point_cell[order[r]] = c
    cell_start[m] = n
    roots = grid_components(points, order, cell_keys, cell_start, nx, ny, tol)
    return True, first_occurrence_labels(roots, point_cell)


@njit(cache=True, nogil=True)
def first_occurrence_labels(roots, point_node):
    """Label (N,) of each point: its node's root ``roots[point_node[i]]`` renumbered 0, 1, ... in
    order of first occurrence over the points (the component of point 0 is 0, ...)."""
    n = point_node.shape[0]
    label_of_root = np.full(roots.shape[0], -1, np.int64)
    labels = np.empty(n, np.int64)
    n_labels = 0
    for i in range(n):
        r = roots[point_node[i]]
        lab = label_of_root[r]
        if lab < 0:
            lab = n_labels
            label_of_root[r] = lab
            n_labels += 1
        labels[i] = lab
    return labels


@njit(cache=True, nogil=True)
def clusters_from_labels(labels, min_size, max_size):
    """Members of the clusters of size in [min_size, max_size] (max_size < 0: no limit), largest
    first (ties: smaller label first), indices ascending within each: flat members (K,) int64 and
    bounds (C + 1,) int64 (cluster c is ``members[bounds[c]:bounds[c + 1]]``)."""
    n = labels.shape[0]
    n_labels = 0
    for i in range(n):
        n_labels = max(n_labels, labels[i] + 1)
    sizes = np.zeros(n_labels, np.int64)
    for i in range(n):
        sizes[labels[i]] += 1
    n_kept = 0
    for lab in range(n_labels):
        if sizes[lab] >= min_size and (max_size < 0 or sizes[lab] <= max_size):
            n_kept += 1
    kept = np.empty(n_kept, np.int64)
    j = 0
    for lab in range(n_labels):
        if sizes[lab] >= min_size and (max_size < 0 or sizes[lab] <= max_size):
            kept[j] = lab
            j += 1
    # largest first, stable (ties by label): a radix sort of (largest size - size) rather than numba's mergesort
    # (~80 kB of code a cold process loads from the cache)
    largest = 0
    for c in range(n_kept):
        largest = max(largest, sizes[kept[c]])
    shortfall = np.empty(n_kept, np.int64)
    for c in range(n_kept):
        shortfall[c] = largest - sizes[kept[c]]
    by_size = _radix_argsort(shortfall, largest)[0]
    kept_by_label = kept
    kept = np.empty(n_kept, np.int64)
    for c in range(n_kept):
        kept[c] = kept_by_label[by_size[c]]
    start_of = np.full(n_labels, -1, np.int64)
    bounds = np.empty(n_kept + 1, np.int64)
    total = 0
    for c in range(n_kept):
        bounds[c] = total
        start_of[kept[c]] = total
        total += sizes[kept[c]]
    bounds[n_kept] = total
    members = np.empty(total, np.int64)
    for i in range(n):
        s = start_of[labels[i]]
        if s >= 0:
            members[s] = i
            start_of[labels[i]] = s + 1
    return members, bounds
