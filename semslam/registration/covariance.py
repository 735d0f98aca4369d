"""Pose covariance from the ICP problem's information.

The point-to-plane ICP that aligns source points ``s_i`` onto a target with normals ``n_i`` minimises
``sum_i r_i^2`` with ``r_i = n_i . (T s_i - q_i)``. Perturbing the estimate on the left, in the TARGET
frame, ``T(delta) = Exp(delta) T`` with ``delta = (rho, phi)`` (translation, rotation vector), gives the
Jacobian row ``J_i = [n_i^T, (p_i x n_i)^T]`` with ``p_i = T s_i``. With the residual variance
``sigma^2 = sum r_i^2 / (N - 6)``, the Gauss-Newton covariance is ``C_delta = k sigma^2 (J^T J)^-1``, where
``k >= 1`` inflates it for the correlation of neighbouring residuals (calibrated on simulated scans, see
``PoseConfig.covariance_inflation``). Directions declared unobservable (rotation about a continuous
symmetry axis through the target origin) are removed from the inversion and given a fixed large variance.

:func:`xyz_rpy_covariance_of_inverse` then maps ``C_delta`` to the covariance of ``x y z roll pitch yaw``
of the INVERSE transform (``T_source_target``; for pose estimation ``T_scanner_object``) by its analytic
Jacobian (central differences near gimbal lock).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry import rpy_from_rotation, wrap_angle


def point_to_plane_information(points_target: np.ndarray, normals_target: np.ndarray,
                               residuals_m: np.ndarray) -> tuple[np.ndarray, float]:
    """``J^T J`` (6x6, order rho_xyz, phi_xyz) and the residual variance ``sigma^2`` (m^2).

    ``points_target`` (N, 3) are the aligned source points in the target frame, ``normals_target`` (N, 3)
    the unit normals of their correspondences, ``residuals_m`` (N,) the signed point-to-plane distances.
    """
    J = np.hstack([normals_target, np.cross(points_target, normals_target)])
    n = len(residuals_m)
    sigma2 = float(residuals_m @ residuals_m) / max(n - 6, 1)
    return J.T @ J, sigma2


def tangent_covariance(information: np.ndarray, sigma2_m2: float, *, inflation: float = 1.0,
                       unobservable_rotation_axes: np.ndarray | None = None,
                       unobservable_variance_rad2: float = 1e4) -> np.ndarray:
    """``C_delta`` (6x6, rho then phi) = ``inflation * sigma2 * information^-1`` on the observable subspace.

    Each axis ``a`` in ``unobservable_rotation_axes`` (K, 3) (target frame, through its origin) is the
    direction ``(0, 0, 0, a)``; it is projected out before inverting and gets ``unobservable_variance_rad2``.
    A remaining singular direction (degenerate geometry) gets a huge variance through the pseudo-inverse's
    regularisation instead of an error.
    """
    U = np.zeros((0, 6))
    if unobservable_rotation_axes is not None and len(unobservable_rotation_axes):
        ax = np.asarray(unobservable_rotation_axes, dtype=float).reshape(-1, 3)
        U = np.hstack([np.zeros_like(ax), ax / np.linalg.norm(ax, axis=1, keepdims=True)])
    # orthonormal basis Q of the observable complement
    full = np.linalg.svd(np.vstack([U, np.eye(6)]).T)[0] if len(U) else np.eye(6)
    Q = full[:, len(U):] if len(U) else np.eye(6)
    H = Q.T @ information @ Q
    w, V = np.linalg.eigh(0.5 * (H + H.T))
    floor = max(float(w.max()), 1e-30) * 1e-12  # regularise exactly singular directions
    Hinv = (V / np.maximum(w, floor)) @ V.T
    C = inflation * sigma2_m2 * (Q @ Hinv @ Q.T)
    if len(U):
        C = C + unobservable_variance_rad2 * (U.T @ U)
    return 0.5 * (C + C.T)


def xyz_rpy_covariance_of_inverse(T_target_source: np.ndarray, C_delta: np.ndarray, *, step: float = 1e-6,
                                  ) -> np.ndarray:
    """Covariance (6x6, x y z roll pitch yaw) of ``T_source_target = inv(T_target_source)``.

    ``C_delta`` is the covariance of a left perturbation ``Exp(delta) T_target_source`` (rho then phi).
    With ``A = R_target_source^T``, ``inv(Exp(delta) T) = [A R(phi)^T, -A R(phi)^T rho + t]``: the Jacobian is
    ``d xyz / d rho = -A``, ``d xyz / d phi = 0`` and ``d rpy / d phi = -E^-1`` with ``E`` the Z-Y-X body-rate
    matrix at the inverse's roll and pitch (analytic; equal to central differences to ~1e-9). Within 1e-3 rad
    of gimbal lock (pitch = +-90 degrees), central differences of step ``step`` are used instead.
    """
    T_target_source = np.asarray(T_target_source, dtype=np.float64)
    A = T_target_source[:3, :3].T
    roll, pitch, _ = rpy_from_rotation(A)
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    if abs(cp) < 1e-3:
        return _xyz_rpy_covariance_of_inverse_numeric(T_target_source, C_delta, step)
    # E^-1 of E = [[1, 0, -sp], [0, cr, sr cp], [0, -sr, cr cp]] (rpy rates -> body angular velocity)
    E_inv = np.array([[1.0, sr * sp / cp, cr * sp / cp],
                      [0.0, cr, -sr],
                      [0.0, sr / cp, cr / cp]])
    J = np.zeros((6, 6))
    J[:3, :3] = -A
    J[3:, 3:] = -E_inv
    C = J @ C_delta @ J.T
    return 0.5 * (C + C.T)


def _xyz_rpy_covariance_of_inverse_numeric(T_target_source: np.ndarray, C_delta: np.ndarray, step: float) -> np.ndarray:
    """:func:`xyz_rpy_covariance_of_inverse` by central differences (near gimbal lock)."""
    def f(delta: np.ndarray) -> np.ndarray:
        P = np.eye(4)
        P[:3, :3] = Rotation.from_rotvec(delta[3:]).as_matrix()
        P[:3, 3] = delta[:3]
        T = np.linalg.inv(P @ T_target_source)
        return np.concatenate([T[:3, 3], rpy_from_rotation(T[:3, :3])])

    J = np.empty((6, 6))
    for i in range(6):
        e = np.zeros(6)
        e[i] = step
        d = f(e) - f(-e)
        d[3:] = wrap_angle(d[3:])
        J[:, i] = d / (2 * step)
    C = J @ C_delta @ J.T
    return 0.5 * (C + C.T)
