"""Numba helpers of the laser pass (:func:`semslam.simulation._scanner_kernels.laser_pass`): where line k's
laser plane cuts the scene's large faces (angular windows) and its small-face bounding spheres (disks), and
a ray's first large-face hit. Conventions as in :mod:`semslam.simulation._scanner_kernels`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ._ray_kernels import inside_large

__all__ = ["face_window", "first_large_hit", "large_faces_cut", "line_plane", "mark_small_disk_rays", "wrap_angle"]

#: Angular margin (rad) of the per-line windows of large faces (covers rounding only).
_WINDOW_TOL_RAD = 1e-5
#: A vertex closer than this (m) to a laser plane counts as on it.
_PLANE_TOL_M = 1e-9


@njit(cache=True, nogil=True, error_model="numpy")
def wrap_angle(x):
    """``x`` (rad) shifted by one turn into [-pi, pi] when outside it (``x``: a difference of two angles in [-pi, pi])."""
    if x > np.pi:
        return x - 2.0 * np.pi
    if x < -np.pi:
        return x + 2.0 * np.pi
    return x


@njit(cache=True, nogil=True, error_model="numpy")
def face_window(f, lverts, ox, oy, oz, px, py, pz, sx, sy, sz, yx, yy, yz):
    """In-plane angular window (centre, half width) where the laser plane (origin o, normal p, axes s
    and y) cuts large face f; half < 0 when it does not cut it, half > pi when every ray must test it."""
    h = np.empty(3)
    for e in range(3):
        h[e] = (lverts[f, e, 0] - ox) * px + (lverts[f, e, 1] - oy) * py + (lverts[f, e, 2] - oz) * pz
    if (h[0] > _PLANE_TOL_M and h[1] > _PLANE_TOL_M and h[2] > _PLANE_TOL_M) or \
            (h[0] < -_PLANE_TOL_M and h[1] < -_PLANE_TOL_M and h[2] < -_PLANE_TOL_M):
        return 0.0, -1.0
    n_on = 0
    ang0 = 0.0
    lo = 0.0
    hi = 0.0
    n_pts = 0
    for e in range(3):
        b = (e + 1) % 3
        ha, hb = h[e], h[b]
        for case in range(2):
            if case == 0:
                if abs(ha) > _PLANE_TOL_M:
                    continue
                n_on += 1
                wx, wy, wz = lverts[f, e, 0] - ox, lverts[f, e, 1] - oy, lverts[f, e, 2] - oz
            else:
                if not ((ha > _PLANE_TOL_M and hb < -_PLANE_TOL_M) or (ha < -_PLANE_TOL_M and hb > _PLANE_TOL_M)):
                    continue
                u = ha / (ha - hb)
                wx = lverts[f, e, 0] + u * (lverts[f, b, 0] - lverts[f, e, 0]) - ox
                wy = lverts[f, e, 1] + u * (lverts[f, b, 1] - lverts[f, e, 1]) - oy
                wz = lverts[f, e, 2] + u * (lverts[f, b, 2] - lverts[f, e, 2]) - oz
            cs = wx * sx + wy * sy + wz * sz
            cy = wx * yx + wy * yy + wz * yz
            if cs * cs + cy * cy < 1e-18:  # the line's origin is on the face
                return 0.0, 10.0
            ang = np.arctan2(cy, cs)
            if n_pts == 0:
                ang0 = ang
            else:
                rel = wrap_angle(ang - ang0)
                lo = min(lo, rel)
                hi = max(hi, rel)
            n_pts += 1
    if n_on == 3 or hi - lo > np.pi - 0.01:  # face in the plane, or seen across the origin
        return 0.0, 10.0
    return ang0 + 0.5 * (lo + hi), 0.5 * (hi - lo) + _WINDOW_TOL_RAD


@njit(cache=True, nogil=True, error_model="numpy")
def line_plane(R, k, sin_a, cos_a):
    """Line k's laser plane (world): in-plane axes s (phi = 0) and y (phi = pi / 2), normal p."""
    sx = R[k, 0, 0] * sin_a[k] + R[k, 0, 2] * cos_a[k]  # in-plane axis (phi = 0)
    sy = R[k, 1, 0] * sin_a[k] + R[k, 1, 2] * cos_a[k]
    sz = R[k, 2, 0] * sin_a[k] + R[k, 2, 2] * cos_a[k]
    yx, yy, yz = R[k, 0, 1], R[k, 1, 1], R[k, 2, 1]  # in-plane axis (phi = pi / 2)
    px = R[k, 0, 0] * cos_a[k] - R[k, 0, 2] * sin_a[k]  # plane normal
    py = R[k, 1, 0] * cos_a[k] - R[k, 1, 2] * sin_a[k]
    pz = R[k, 2, 0] * cos_a[k] - R[k, 2, 2] * sin_a[k]
    return sx, sy, sz, yx, yy, yz, px, py, pz


@njit(cache=True, nogil=True, error_model="numpy")
def large_faces_cut(lverts, lv0, ln, ox, oy, oz, plane, faces, centre, half, num):
    """The large faces the laser plane (origin o) cuts, in the first n entries of ``faces``, with the
    angular window of the cut (``centre``, ``half``) and the offset ``num`` of the face's plane; returns n."""
    sx, sy, sz, yx, yy, yz, px, py, pz = plane
    n_large = lv0.shape[0]
    n_rel = 0
    for f in range(n_large):
        cw, hw = face_window(f, lverts, ox, oy, oz, px, py, pz, sx, sy, sz, yx, yy, yz)
        if hw < 0.0:
            continue
        faces[n_rel] = f
        centre[n_rel] = cw
        half[n_rel] = hw
        num[n_rel] = (lv0[f, 0] - ox) * ln[f, 0] + (lv0[f, 1] - oy) * ln[f, 1] + (lv0[f, 2] - oz) * ln[f, 2]
        n_rel += 1
    return n_rel


@njit(cache=True, nogil=True, error_model="numpy")
def mark_small_disk_rays(mark, m, phi, phi_tol, sc, sr, ox, oy, oz, plane):
    """Small-face spheres cut by the laser plane (origin o) are disks: ``mark[j]`` for the rays that reach one."""
    sx, sy, sz, yx, yy, yz, px, py, pz = plane
    mark[:] = False
    for g in range(sc.shape[0]):
        vx, vy, vz = sc[g, 0] - ox, sc[g, 1] - oy, sc[g, 2] - oz
        h = vx * px + vy * py + vz * pz
        if abs(h) > sr[g]:
            continue
        rp2 = sr[g] * sr[g] - h * h
        u = vx * sx + vy * sy + vz * sz
        w = vx * yx + vy * yy + vz * yz
        l2 = u * u + w * w
        if l2 <= rp2:  # the line's origin is inside the disk
            mark[:] = True
            return
        pc = np.arctan2(w, u)
        hw = np.arcsin(min(1.0, np.sqrt(rp2 / l2))) + phi_tol
        for j in range(m):
            if abs(wrap_angle(phi[j] - pc)) <= hw:
                mark[j] = True


@njit(cache=True, nogil=True, error_model="numpy")
def first_large_hit(phi_j, ox, oy, oz, dx, dy, dz, n_rel, faces, centre, half, num, ln, len_, lec):
    """Distance (inf none) and large face (-1 none) of the first hit of the ray from o along d, at in-plane
    angle ``phi_j``, among the first ``n_rel`` faces cut by its laser plane (:func:`large_faces_cut`)."""
    best = np.inf
    bf = -1
    for r in range(n_rel):
        if abs(wrap_angle(phi_j - centre[r])) > half[r]:
            continue
        f = faces[r]
        den = dx * ln[f, 0] + dy * ln[f, 1] + dz * ln[f, 2]
        if den == 0.0:
            continue
        s = num[r] / den
        if s <= 0.0 or s >= best:
            continue
        if inside_large(f, ox + s * dx, oy + s * dy, oz + s * dz, len_, lec):
            best = s
            bf = f
    return best, bf
