"""Numba kernels of the laser scanner: one fused pass per stage instead of many numpy temporaries.

Conventions as in :mod:`semslam.simulation.scanner`: ``dirs_local`` (N, 3) unit laser rays in the
scanner frame, ray i belongs to line ``i // points_per_line`` whose pose is ``R[l], t[l]`` (world).
Embree coordinates are world minus ``offset``, float32.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def laser_rays(dirs_local, R, t, points_per_line, offset):
    """World ray origins (shifted, float32), directions (float32) and directions (float64)."""
    n = dirs_local.shape[0]
    o32 = np.empty((n, 3), np.float32)
    d32 = np.empty((n, 3), np.float32)
    d64 = np.empty((n, 3))
    for i in range(n):
        line = i // points_per_line
        for a in range(3):
            v = R[line, a, 0] * dirs_local[i, 0] + R[line, a, 1] * dirs_local[i, 1] + R[line, a, 2] * dirs_local[i, 2]
            d64[i, a] = v
            d32[i, a] = v
            o32[i, a] = t[line, a] - offset[a]
    return o32, d32, d64


@njit(cache=True)
def camera_rays(dirs_local, d64, tri, R, t, points_per_line, v0, normals, cam_local, axis_local,
                cos_half_fov, min_range, max_range, offset):
    """Laser hits within range that lie in the camera's field of view and range.

    Returns the ray indices (K,), the laser range (K,), the camera range (K,), the camera rays for the
    occlusion test: origins (K, 3) float32 shifted, unit directions (K, 3) float32 (world), and the laser
    range of every ray (N,) (inf where it hits nothing).
    """
    n = dirs_local.shape[0]
    laser = np.full(n, np.inf)
    idx = np.empty(n, np.int64)
    dist = np.empty(n)
    rcam = np.empty(n)
    co = np.empty((n, 3), np.float32)
    cd = np.empty((n, 3), np.float32)
    k = 0
    for i in range(n):
        f = tri[i]
        if f < 0:
            continue
        line = i // points_per_line
        num = 0.0
        den = 0.0
        for a in range(3):
            num += (v0[f, a] - t[line, a]) * normals[f, a]
            den += d64[i, a] * normals[f, a]
        if den == 0.0:
            continue
        s = num / den
        laser[i] = s
        if s < min_range or s > max_range:
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
        dist[k] = s
        rcam[k] = r
        for a in range(3):
            co[k, a] = t[line, a] + R[line, a, 0] * cam_local[0] + R[line, a, 1] * cam_local[1] + R[line, a, 2] * cam_local[2] - offset[a]
            cd[k, a] = (R[line, a, 0] * vx + R[line, a, 1] * vy + R[line, a, 2] * vz) / r
        k += 1
    return idx[:k], dist[:k], rcam[:k], co[:k], cd[:k], laser


@njit(cache=True)
def measure(idx, dist, rcam, dirs_local, d64, tri, normals, cam_local, gauss, noise_floor, noise_r2, attenuation):
    """Noisy points in the scanner frame of their line (noise along the camera ray, sigma = a + b r^2)
    and intensities ``|cos incidence| exp(-attenuation (laser range + camera range))``."""
    k = idx.shape[0]
    pts = np.empty((k, 3))
    inten = np.empty(k)
    for j in range(k):
        i = idx[j]
        s = dist[j]
        r = rcam[j]
        e = gauss[i] * (noise_floor + noise_r2 * r * r)
        c = 0.0
        for a in range(3):
            p = dirs_local[i, a] * s
            pts[j, a] = p + (p - cam_local[a]) / r * e
            c += normals[tri[i], a] * d64[i, a]
        inten[j] = abs(c) * np.exp(-attenuation * (s + r))
    return pts, inten
