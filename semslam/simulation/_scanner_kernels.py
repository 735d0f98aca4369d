"""Numba kernels of the laser scanner: one fused pass per stage instead of many numpy temporaries.

Conventions as in :mod:`semslam.simulation.scanner`: ``dirs_local`` (N, 3) unit laser rays in the
scanner frame, ray ``i = k * m + j`` is point j (in-plane angle ``phi[j]``) of line k (``m`` points per
line), line k's pose is ``R[k], t[k]`` (world). Embree coordinates are world minus ``offset``, float32.
The scene arrives split (:class:`semslam.simulation._ray_kernels.SplitScene`): large faces (vertices
``lverts``, first vertex ``lv0``, unit normal ``ln``, edge planes ``len_, lec``, scene ids ``lid``) are
intersected here in float64; small faces are culled with bounding spheres (``sc, sr``) and the
surviving rays go to Embree.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ._laser_plane_kernels import first_large_hit, large_faces_cut, line_plane, mark_small_disk_rays
from ._ray_kernels import inside_large


@njit(cache=True, nogil=True, error_model="numpy")
def _direction(R, k, dirs_local, i):
    """World direction of ray i of line k (the one expression every kernel uses: identical bits)."""
    lx, ly, lz = dirs_local[i, 0], dirs_local[i, 1], dirs_local[i, 2]
    return (R[k, 0, 0] * lx + R[k, 0, 1] * ly + R[k, 0, 2] * lz,
            R[k, 1, 0] * lx + R[k, 1, 1] * ly + R[k, 1, 2] * lz,
            R[k, 2, 0] * lx + R[k, 2, 1] * ly + R[k, 2, 2] * lz)


@njit(cache=True, nogil=True, error_model="numpy")
def laser_pass(dirs_local, R, t, m, sin_a, cos_a, phi, phi_tol, lid, lverts, lv0, ln, len_, lec, sc, sr, offset):
    """First hit of every laser ray among the large faces, and the rays that may hit a small face.

    Returns ``tri`` (N,) scene face of the first large-face hit (-1 none), ``t_hit`` (N,) its distance
    (inf none), and for the candidate rays (whose in-plane angle is within ``phi_tol`` of the disk a
    small-face sphere cuts from their laser plane): indices (C,), shifted float32 origins (C, 3),
    float32 directions (C, 3) and float32 ``tfar`` (C,) just beyond ``t_hit``.
    """
    n_lines = R.shape[0]
    n = n_lines * m
    n_large = lv0.shape[0]
    tri = np.full(n, -1, np.int64)
    t_hit = np.full(n, np.inf)
    mark = np.zeros(m, np.bool_)
    cand = np.empty(n, np.int64)
    o32 = np.empty((n, 3), np.float32)
    d32 = np.empty((n, 3), np.float32)
    tf32 = np.empty(n, np.float32)
    c = 0
    num = np.empty(n_large)
    faces = np.empty(n_large, np.int64)
    centre = np.empty(n_large)
    half = np.empty(n_large)
    for k in range(n_lines):
        ox, oy, oz = t[k, 0], t[k, 1], t[k, 2]
        plane = line_plane(R, k, sin_a, cos_a)
        n_rel = large_faces_cut(lverts, lv0, ln, ox, oy, oz, plane, faces, centre, half, num)
        mark_small_disk_rays(mark, m, phi, phi_tol, sc, sr, ox, oy, oz, plane)
        for j in range(m):
            i = k * m + j
            dx, dy, dz = _direction(R, k, dirs_local, i)
            best, bf = first_large_hit(phi[j], ox, oy, oz, dx, dy, dz, n_rel, faces, centre, half, num, ln, len_, lec)
            if bf >= 0:
                tri[i] = lid[bf]
                t_hit[i] = best
            if mark[j]:
                cand[c] = i
                o32[c, 0], o32[c, 1], o32[c, 2] = ox - offset[0], oy - offset[1], oz - offset[2]
                d32[c, 0], d32[c, 1], d32[c, 2] = dx, dy, dz
                tf32[c] = best * (1.0 + 1e-5) + 1e-4
                c += 1
    return tri, t_hit, cand[:c].copy(), o32[:c].copy(), d32[:c].copy(), tf32[:c].copy()


@njit(cache=True, nogil=True, error_model="numpy")
def merge_small_hits(tri, t_hit, cand, small_tri, dirs_local, R, t, m, v0, normals):
    """Replace the large-face hit of a candidate ray by its small-face hit when nearer (float64)."""
    for q in range(cand.shape[0]):
        f = small_tri[q]
        if f < 0:
            continue
        i = cand[q]
        k = i // m
        dx, dy, dz = _direction(R, k, dirs_local, i)
        num = (
            (v0[f, 0] - t[k, 0]) * normals[f, 0]
            + (v0[f, 1] - t[k, 1]) * normals[f, 1]
            + (v0[f, 2] - t[k, 2]) * normals[f, 2]
        )
        den = dx * normals[f, 0] + dy * normals[f, 1] + dz * normals[f, 2]
        if den != 0.0 and num / den < t_hit[i]:
            tri[i] = f
            t_hit[i] = num / den


@njit(cache=True, nogil=True, error_model="numpy")
def _camera_centre(R, t, line, cam_local):
    """World position of the camera during line ``line``."""
    cx = t[line, 0] + R[line, 0, 0] * cam_local[0] + R[line, 0, 1] * cam_local[1] + R[line, 0, 2] * cam_local[2]
    cy = t[line, 1] + R[line, 1, 0] * cam_local[0] + R[line, 1, 1] * cam_local[1] + R[line, 1, 2] * cam_local[2]
    cz = t[line, 2] + R[line, 2, 0] * cam_local[0] + R[line, 2, 1] * cam_local[1] + R[line, 2, 2] * cam_local[2]
    return cx, cy, cz


@njit(cache=True, nogil=True, error_model="numpy")
def _camera_view_hits(line, m, k, dirs_local, t_hit, R, cam_local, axis_local, cos_half_fov, min_range, max_range,
                      end_gap, cx, cy, cz, idx, rcam, cd):
    """Append the line's laser hits in range and in the camera's view to ``idx, rcam`` from entry ``k``
    (their world unit camera directions to ``cd`` from row 0); returns the new ``k`` and the box (lo x, y,
    z, hi x, y, z) of the camera centre c and the segment ends."""
    k0 = k
    lo_x, lo_y, lo_z, hi_x, hi_y, hi_z = cx, cy, cz, cx, cy, cz
    for i in range(line * m, line * m + m):
        s = t_hit[i]
        if s < min_range or s > max_range:  # also no hit (inf)
            continue
        vx = dirs_local[i, 0] * s - cam_local[0]
        vy = dirs_local[i, 1] * s - cam_local[1]
        vz = dirs_local[i, 2] * s - cam_local[2]
        r = np.sqrt(vx * vx + vy * vy + vz * vz)
        if r < min_range or r > max_range or r == 0.0:
            continue
        if (vx * axis_local[0] + vy * axis_local[1] + vz * axis_local[2]) / r < cos_half_fov:
            continue
        idx[k] = i
        rcam[k] = r
        q = k - k0
        for a in range(3):
            cd[q, a] = (R[line, a, 0] * vx + R[line, a, 1] * vy + R[line, a, 2] * vz) / r
        length = r - end_gap
        ex, ey, ez = cx + length * cd[q, 0], cy + length * cd[q, 1], cz + length * cd[q, 2]
        lo_x, lo_y, lo_z = min(lo_x, ex), min(lo_y, ey), min(lo_z, ez)
        hi_x, hi_y, hi_z = max(hi_x, ex), max(hi_y, ey), max(hi_z, ez)
        k += 1
    return k, (lo_x, lo_y, lo_z, hi_x, hi_y, hi_z)


@njit(cache=True, nogil=True, error_model="numpy")
def _large_faces_in_box(box, cx, cy, cz, lv0, ln, faces, s_cam):
    """Large faces whose plane crosses ``box``, in the first n entries of ``faces``, with the signed
    distance ``s_cam`` of the camera centre c from the face's plane; returns n."""
    lo_x, lo_y, lo_z, hi_x, hi_y, hi_z = box
    n_large = lv0.shape[0]
    bx, by, bz = 0.5 * (lo_x + hi_x), 0.5 * (lo_y + hi_y), 0.5 * (lo_z + hi_z)
    ex, ey, ez = 0.5 * (hi_x - lo_x), 0.5 * (hi_y - lo_y), 0.5 * (hi_z - lo_z)
    n_rel = 0
    for f in range(n_large):
        sb = (bx - lv0[f, 0]) * ln[f, 0] + (by - lv0[f, 1]) * ln[f, 1] + (bz - lv0[f, 2]) * ln[f, 2]
        if abs(sb) > ex * abs(ln[f, 0]) + ey * abs(ln[f, 1]) + ez * abs(ln[f, 2]):
            continue
        faces[n_rel] = f
        s_cam[n_rel] = (cx - lv0[f, 0]) * ln[f, 0] + (cy - lv0[f, 1]) * ln[f, 1] + (cz - lv0[f, 2]) * ln[f, 2]
        n_rel += 1
    return n_rel


@njit(cache=True, nogil=True, error_model="numpy")
def _block_by_large_faces(k0, k, rcam, end_gap, cd, cx, cy, cz, n_rel, faces, s_cam, ln, len_, lec, blocked):
    """``blocked[k0 + q]`` for the segments ``c + s cd[q]`` (0 < s < camera range - end_gap) that cross one of
    the first ``n_rel`` large faces (:func:`_large_faces_in_box`)."""
    for q in range(k - k0):
        length = rcam[k0 + q] - end_gap
        ux, uy, uz = cd[q, 0], cd[q, 1], cd[q, 2]
        for r in range(n_rel):
            f = faces[r]
            un = ux * ln[f, 0] + uy * ln[f, 1] + uz * ln[f, 2]
            s_end = s_cam[r] + length * un
            if (s_cam[r] > 0.0 and s_end > 0.0) or (s_cam[r] < 0.0 and s_end < 0.0) or un == 0.0:
                continue  # both ends on the same side of the plane
            s = -s_cam[r] / un
            if s <= 0.0 or s >= length:
                continue
            if inside_large(f, cx + s * ux, cy + s * uy, cz + s * uz, len_, lec):
                blocked[k0 + q] = True
                break


@njit(cache=True, nogil=True, error_model="numpy")
def _mark_small_sphere_segments(mark, k0, k, blocked, rcam, end_gap, cd, cx, cy, cz, box, sc, sr):
    """Small-face spheres that touch ``box``: ``mark[q]`` for the open segments (not ``blocked``) that
    pass through one (candidates for Embree)."""
    lo_x, lo_y, lo_z, hi_x, hi_y, hi_z = box
    mark[:] = False
    for g in range(sc.shape[0]):
        rg = sr[g]
        if (sc[g, 0] + rg < lo_x or sc[g, 0] - rg > hi_x or sc[g, 1] + rg < lo_y or sc[g, 1] - rg > hi_y
                or sc[g, 2] + rg < lo_z or sc[g, 2] - rg > hi_z):
            continue
        vx, vy, vz = sc[g, 0] - cx, sc[g, 1] - cy, sc[g, 2] - cz
        for q in range(k - k0):
            if blocked[k0 + q] or mark[q]:
                continue
            length = rcam[k0 + q] - end_gap
            s = min(max(vx * cd[q, 0] + vy * cd[q, 1] + vz * cd[q, 2], 0.0), length)
            wx, wy, wz = vx - s * cd[q, 0], vy - s * cd[q, 1], vz - s * cd[q, 2]
            if wx * wx + wy * wy + wz * wz <= rg * rg:
                mark[q] = True


@njit(cache=True, nogil=True, error_model="numpy")
def camera_pass(dirs_local, t_hit, R, t, m, cam_local, axis_local, cos_half_fov, min_range, max_range, end_gap,
                lv0, ln, len_, lec, sc, sr, offset):
    """Laser hits within range and inside the camera's field of view and range, and whether the
    camera sees them: the segment ``cam + s u``, ``0 < s < camera range - end_gap`` is tested here
    against the large faces; segments that pass through a small-face sphere are candidates for Embree.

    Returns ray indices (K,) (increasing), camera range (K,), ``blocked`` (K,) by a large face, and for
    the candidates: indices into K (C,), shifted float32 origins (C, 3), float32 unit directions
    (C, 3), float32 lengths (C,).
    """
    n_lines = R.shape[0]
    n = n_lines * m
    n_large = lv0.shape[0]
    idx = np.empty(n, np.int64)
    rcam = np.empty(n)
    blocked = np.zeros(n, np.bool_)
    cand = np.empty(n, np.int64)
    o32 = np.empty((n, 3), np.float32)
    d32 = np.empty((n, 3), np.float32)
    len32 = np.empty(n, np.float32)
    cd = np.empty((m, 3))  # camera directions of the current line
    mark = np.zeros(m, np.bool_)
    s_cam = np.empty(n_large)
    faces = np.empty(n_large, np.int64)
    k = 0
    c = 0
    for line in range(n_lines):
        k0 = k
        cx, cy, cz = _camera_centre(R, t, line, cam_local)
        k, box = _camera_view_hits(line, m, k, dirs_local, t_hit, R, cam_local, axis_local, cos_half_fov, min_range,
                                   max_range, end_gap, cx, cy, cz, idx, rcam, cd)
        if k == k0:
            continue
        n_rel = _large_faces_in_box(box, cx, cy, cz, lv0, ln, faces, s_cam)
        _block_by_large_faces(k0, k, rcam, end_gap, cd, cx, cy, cz, n_rel, faces, s_cam, ln, len_, lec, blocked)
        _mark_small_sphere_segments(mark, k0, k, blocked, rcam, end_gap, cd, cx, cy, cz, box, sc, sr)
        for q in range(k - k0):
            if mark[q]:
                cand[c] = k0 + q
                o32[c, 0], o32[c, 1], o32[c, 2] = cx - offset[0], cy - offset[1], cz - offset[2]
                d32[c, 0], d32[c, 1], d32[c, 2] = cd[q, 0], cd[q, 1], cd[q, 2]
                len32[c] = rcam[k0 + q] - end_gap
                c += 1
    return (idx[:k].copy(), rcam[:k].copy(), blocked[:k].copy(), cand[:c].copy(), o32[:c].copy(), d32[:c].copy(),
            len32[:c].copy())


@njit(cache=True, nogil=True, error_model="numpy")
def assemble(idx, rcam, seen, keep, scatter, scatter_u, gauss, dirs_local, R, tri, t_hit, normals, face_instance,
             cam_local, m, noise_floor, noise_r2, attenuation, min_range, max_range, backscatter_id):
    """The scan's points in ray order (line by line; a ray's surface point before its backscatter).

    Surface points (seen by the camera and not dropped) get noise along the camera ray (sigma = a + b
    r^2, r = camera range) and the intensity ``|cos incidence| exp(-attenuation (laser + camera
    range))``; backscatter points lie on the laser ray between ``min_range`` and the surface (or
    ``max_range``), intensity ``0.05 exp(-2 attenuation range)``. Returns points (P, 3) in the scanner
    frame of their line, intensities (P,), line (P,) int32, instance (P,) int32 (``face_instance``
    empty: -1 for every surface point).
    """
    n = dirs_local.shape[0]
    count = 0
    for q in range(idx.shape[0]):
        if seen[q] and keep[idx[q]]:
            count += 1
    for i in range(n):
        if scatter[i]:
            count += 1
    pts = np.empty((count, 3))
    inten = np.empty(count)
    line = np.empty(count, np.int32)
    inst = np.empty(count, np.int32)
    p = 0
    q = 0
    kk = idx.shape[0]
    for i in range(n):
        while q < kk and idx[q] < i:
            q += 1
        if q < kk and idx[q] == i and seen[q] and keep[i]:
            s = t_hit[i]
            r = rcam[q]
            e = gauss[i] * (noise_floor + noise_r2 * r * r)
            f = tri[i]
            dx, dy, dz = _direction(R, i // m, dirs_local, i)
            for a in range(3):
                x = dirs_local[i, a] * s
                pts[p, a] = x + (x - cam_local[a]) / r * e
            c = normals[f, 0] * dx + normals[f, 1] * dy + normals[f, 2] * dz
            inten[p] = abs(c) * np.exp(-attenuation * (s + r))
            line[p] = i // m
            inst[p] = face_instance[f] if face_instance.shape[0] > 0 else -1
            p += 1
        if scatter[i]:
            r_bs = min_range + scatter_u[i] * max(min(t_hit[i], max_range) - min_range, 0.0)
            for a in range(3):
                pts[p, a] = dirs_local[i, a] * r_bs
            inten[p] = 0.05 * np.exp(-attenuation * 2 * r_bs)
            line[p] = i // m
            inst[p] = backscatter_id
            p += 1
    return pts, inten, line, inst
