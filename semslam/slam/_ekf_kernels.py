"""Small numeric kernels of the EKF (vectorised numpy / BLAS). Private: callers validate first.

Rotation conventions follow :mod:`semslam.geometry` (roll-pitch-yaw Z-Y-X). A *world-frame rotation
perturbation* ``w`` acts on the left: ``R' = Exp(w) R``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import blas

_EZ = np.array([0.0, 0.0, 1.0])


def rpy_to_world_rate(rpy: np.ndarray) -> np.ndarray:
    """Matrix ``E`` (3, 3) with ``w = E @ d_rpy``: the world-frame rotation of a small roll-pitch-yaw change.

    Columns: ``Rz Ry e_x`` (roll), ``Rz e_y`` (pitch), ``e_z`` (yaw). Defined everywhere; rank 2 at pitch
    +-90 degrees (gimbal lock), where it is never inverted by the filter.
    """
    _, p, y = rpy
    cp, sp, cy, sy = np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, -sy, 0.0], [sy * cp, cy, 0.0], [-sp, 0.0, 1.0]])


def world_rate_to_rpy(rpy: np.ndarray, min_cos_pitch: float = 1e-3) -> np.ndarray:
    """Inverse of :func:`rpy_to_world_rate`, with ``cos(pitch)`` clamped away from 0 (never NaN)."""
    _, p, y = rpy
    cp = np.cos(p)
    cp = np.copysign(max(abs(cp), min_cos_pitch), cp if cp != 0 else 1.0)
    tp, cy, sy = np.sin(p) / cp, np.cos(y), np.sin(y)
    return np.array([[cy / cp, sy / cp, 0.0], [-sy, cy, 0.0], [cy * tp, sy * tp, 1.0]])


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: rotation matrix of a rotation vector (3,) (plain floats: called per event)."""
    x, y, z = (float(c) for c in np.asarray(w, dtype=float).reshape(3))
    th2 = x * x + y * y + z * z
    th = math.sqrt(th2)
    if th < 1e-8:  # second-order series: I + K + K^2 / 2
        a, b = 1.0, 0.5
    else:
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / th2
    # I + a K + b K^2 with K^2 = w w^T - |w|^2 I
    return np.array([[1.0 + b * (x * x - th2), -a * z + b * x * y, a * y + b * x * z],
                     [a * z + b * x * y, 1.0 + b * (y * y - th2), -a * x + b * y * z],
                     [-a * y + b * x * z, a * x + b * y * z, 1.0 + b * (z * z - th2)]])


def rot_z(angle: float) -> np.ndarray:
    """Rotation by ``angle`` (rad) about the z axis."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) of a rotation matrix, angle in [0, pi]; robust near 0 and pi.

    The angle is ``atan2(|v| / 2, (trace - 1) / 2)`` (``v`` the skew part: ``2 sin(theta) u``), well conditioned
    everywhere; near pi the axis comes from the *symmetric* part ``(R + R^T) / 2 - cos(theta) I =
    (1 - cos(theta)) u u^T``, which the skew residue cannot contaminate (full precision up to pi)."""
    c = (np.trace(R) - 1.0) / 2.0
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    th = float(np.arctan2(0.5 * np.linalg.norm(v), c))
    if th < 1e-6:
        return 0.5 * v
    if np.pi - th > 1e-4:
        return th / (2.0 * np.sin(th)) * v
    # near pi: axis from the symmetric part, sign from v
    B = 0.5 * (R + R.T) - c * np.eye(3)
    k = int(np.argmax(np.diag(B)))
    axis = B[:, k] / np.sqrt(max(B[k, k], 1e-300))
    axis /= np.linalg.norm(axis)
    if axis @ v < 0:
        axis = -axis
    return th * axis


def axis_rotation(u: np.ndarray, angle: float) -> np.ndarray:
    """Rotation by ``angle`` about the unit axis ``u``."""
    return so3_exp(np.asarray(u, dtype=float) * angle)


def best_angle_about_axis(M: np.ndarray, u: np.ndarray) -> float:
    """``beta`` maximising ``trace(Rot(u, beta) @ M)``: the rotation about ``u`` that brings ``M`` closest to I."""
    tr = np.trace(M)
    uMu = u @ M @ u
    return float(np.arctan2(np.trace(skew(u) @ M), tr - uMu))


def mahalanobis2(nu: np.ndarray, S: np.ndarray) -> float:
    """Squared Mahalanobis distance ``nu^T S^-1 nu`` (a solve, no inverse); ``inf`` if ``S`` is not
    positive definite."""
    if len(nu) == 1:
        s = float(S[0, 0])
        return float(nu[0] * nu[0] / s) if s > 0 else float("inf")
    try:
        L = np.linalg.cholesky(0.5 * (S + S.T))
    except np.linalg.LinAlgError:
        return float("inf")
    y = np.linalg.solve(L, nu)
    return float(y @ y)


def subtract_outer_inplace(P: np.ndarray, W: np.ndarray) -> None:
    """``P -= W @ W.T`` in place for a C-contiguous symmetric ``P`` (BLAS dgemm on ``P.T``, no n x n temporary)."""
    if W.shape[1] == 0 or P.shape[0] == 0:
        return
    Wf = np.asfortranarray(W)
    out = blas.dgemm(-1.0, Wf, Wf, beta=1.0, c=P.T, trans_b=1, overwrite_c=1)
    if not np.shares_memory(out, P):  # pragma: no cover - BLAS wrapper copied: write back
        P[...] = out.T


# ---------------------------------------------------------------------- numba kernels (hot loop)
from numba import njit  # noqa: E402


@njit(cache=True, nogil=True)
def joseph_update(P, x, loc, Hc, nu, Rn):
    """In-place Joseph-form update of ``(x, P)`` for ``z = H x + n`` with ``H`` non-zero on columns ``loc``.

    ``P <- (I - K H) P (I - K H)^T + K R K^T`` with ``K = P H^T S^-1`` (a solve); returns ``(K, S)``.
    """
    n = P.shape[0]
    m, k = Hc.shape
    PHt = np.zeros((n, m))
    for i in range(n):
        for a in range(m):
            s = 0.0
            for b in range(k):
                s += P[i, loc[b]] * Hc[a, b]
            PHt[i, a] = s
    S = np.empty((m, m))
    for a in range(m):
        for c in range(m):
            s = 0.0
            for b in range(k):
                s += Hc[a, b] * PHt[loc[b], c]
            S[a, c] = s + Rn[a, c]
    S = 0.5 * (S + S.T)
    K = np.linalg.solve(S, np.ascontiguousarray(PHt.T)).T.copy()
    x += K @ nu
    X = P - K @ np.ascontiguousarray(PHt.T)          # (I - K H) P   (H P = (P H^T)^T, P symmetric)
    XHt = np.zeros((n, m))
    for i in range(n):
        for a in range(m):
            s = 0.0
            for b in range(k):
                s += X[i, loc[b]] * Hc[a, b]
            XHt[i, a] = s
    Pn = X - XHt @ np.ascontiguousarray(K.T) + K @ (Rn @ np.ascontiguousarray(K.T))
    for i in range(n):
        for j in range(i, n):
            v = 0.5 * (Pn[i, j] + Pn[j, i])
            P[i, j] = v
            P[j, i] = v
    return K, S


@njit(cache=True, nogil=True)
def predict_vehicle(P, x, R, dt, q, att_cov, nv, bias_rw, i_yaw, i_dvl, dvl_a, dvl_q, slope_a, slope_q):
    """In-place constant-velocity prediction of the vehicle rows of ``(x, P)``; returns ``F`` (nv, nv).

    ``q`` (3,): spectral densities (m^2/s^3) of the white body-frame acceleration (surge, sway, heave).

    ``i_yaw`` / ``i_dvl``: index of the yaw-bias state / first DVL-calibration state (-1 when absent); the
    DVL bias decays by ``dvl_a = exp(-dt / tau)`` and gains ``dvl_q = sigma^2 (1 - a^2)`` per axis, the DVL
    slope bias (the next three states) likewise with ``slope_a`` / ``slope_q``.
    """
    v = x[3:6].copy()
    d = R @ v * dt
    F = np.eye(nv)
    for i in range(3):
        for j in range(3):
            F[i, 3 + j] = R[i, j] * dt
    if i_yaw >= 0:  # d p / d b = -[e_z]x d
        F[0, i_yaw] = d[1]
        F[1, i_yaw] = -d[0]
        F[2, i_yaw] = 0.0
    if i_dvl >= 0:
        for i in range(3):
            F[i_dvl + i, i_dvl + i] = dvl_a
            x[i_dvl + i] *= dvl_a
            F[i_dvl + 3 + i, i_dvl + 3 + i] = slope_a
            x[i_dvl + 3 + i] *= slope_a
    for i in range(3):
        x[i] += d[i]
    n = P.shape[0]
    top = F @ np.ascontiguousarray(P[:nv, :])
    P[:nv, :] = top
    left = np.ascontiguousarray(P[:, :nv]) @ F.T
    P[:, :nv] = left
    Q = np.zeros((nv, nv))
    # white body-frame acceleration of spectral densities q[0..2] (surge, sway, heave), rotated by R
    for i in range(3):
        Q[3 + i, 3 + i] = q[i] * dt
        for j in range(3):
            Q[i, 3 + j] = q[j] * dt ** 2 / 2.0 * R[i, j]
            Q[3 + j, i] = Q[i, 3 + j]
            s = 0.0
            for k in range(3):
                s += R[i, k] * q[k] * R[j, k]
            Q[i, j] = s * dt ** 3 / 3.0
    Dx = np.array([[0.0, -d[2], d[1]], [d[2], 0.0, -d[0]], [-d[1], d[0], 0.0]])
    Qa = Dx @ att_cov @ Dx.T
    for i in range(3):
        for j in range(3):
            Q[i, j] += Qa[i, j]
    if i_yaw >= 0:
        Q[i_yaw, i_yaw] = bias_rw * bias_rw * dt
    if i_dvl >= 0:
        for i in range(3):
            Q[i_dvl + i, i_dvl + i] = dvl_q
            Q[i_dvl + 3 + i, i_dvl + 3 + i] = slope_q
    for i in range(nv):
        for j in range(nv):
            P[i, j] += Q[i, j]
    return F
