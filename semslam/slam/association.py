"""Object measurements and their innovation against a landmark (the gates and the data association:
:mod:`semslam.slam.association_search`, re-exported here).

Measurement model (Himri et al. 2018, eq. 4-5), with two fixes:

* position rows ``z_p = R^T (l_p - p)`` (object position in the vehicle frame), ``H = [-R^T, 0, R^T]``;
* orientation rows: the paper measures the landmark's world roll-pitch-yaw with ``H = I``. Here the
  innovation is the world-frame rotation vector ``Log(R_meas R_l^T)`` with ``H = E(rpy_l)``
  (``w = E d_rpy``), which is wrapped by construction and has no singularity at pitch +-90 degrees
  (``orientation_innovation="rpy"`` keeps the paper's form, wrapped, with a guard near gimbal lock).

The AHRS attitude error enters the measurement noise (``[-R^T [d]x; I]`` applied to its world-frame
covariance). Rotations a symmetric object makes unobservable (the class's continuous axis, or any
direction the detection covariance gives a huge variance) are first aligned (the measured orientation is
turned about the axis to the closest equivalent) and then projected out of the innovation, so they never
move the landmark. A discrete symmetry picks the closest of the ``order`` equivalent orientations.

The mapper gates and updates with :func:`iterated_innovation`: the same model relinearised at the most likely state
where it is curved (in the AHRS yaw bias), so that a large heading error does not make a landmark's first sightings
fail a gate whose covariance is first-order (issue 17: duplicates of the surveyed landmark).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..detection import Detection
from ..errors import SlamError
from ..geometry import RigidTransform, rpy_from_rotation, rotation_from_rpy, wrap_angle
from ..symmetry import Symmetry
from . import _ekf_kernels as kern
from .association_search import GateThresholds, associate, associate_jcbb  # noqa: F401 - re-exported
from .ekf import SemanticEkf

_EZ = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True, eq=False)
class ObjectMeasurement:
    """One detection expressed in the vehicle frame.

    ``noise_cov`` (6, 6) is the covariance of ``[p_vehicle_object (m); rotation vector (rad)]``, the rotation
    perturbation on the left in the vehicle frame. ``unobservable_axes_vehicle`` (k, 3) are unit axes
    (vehicle frame) about which the orientation is not measured.
    """

    label: str
    stamp_s: float
    p_vehicle_object_m: np.ndarray
    R_vehicle_object: np.ndarray
    noise_cov: np.ndarray
    unobservable_axes_vehicle: np.ndarray
    symmetry: Symmetry = field(default_factory=Symmetry)
    index: int = -1


def measurement_from_detection(det: Detection, T_vehicle_scanner: RigidTransform, *, symmetry: Symmetry | None = None,
                               unobservable_var_rad2: float = 0.25, index: int = -1) -> ObjectMeasurement:
    """Turn a :class:`~semslam.detection.Detection` (scanner frame, rpy covariance) into an
    :class:`ObjectMeasurement` (vehicle frame, rotation-vector covariance)."""
    symmetry = symmetry or Symmetry()
    T_vo = T_vehicle_scanner @ det.T_sensor_object
    R_vs = T_vehicle_scanner.rotation
    E_s = kern.rpy_to_world_rate(det.T_sensor_object.as_rpy())
    J = np.zeros((6, 6))
    J[0:3, 0:3] = R_vs
    J[3:6, 3:6] = R_vs @ E_s
    C = J @ det.covariance_6x6 @ J.T
    C = 0.5 * (C + C.T)
    w, V = np.linalg.eigh(C[3:6, 3:6])
    axes = [V[:, k] for k in range(3) if w[k] > unobservable_var_rad2]
    if symmetry.kind == "continuous":
        axes.append(T_vo.rotation @ symmetry.axis_object)
    U = _orthonormal(axes)
    if len(U):  # clamp the huge variance: the direction is projected out of every update anyway
        Pu = np.eye(3) - U.T @ U
        C[3:6, 3:6] = Pu @ C[3:6, 3:6] @ Pu + U.T @ U * unobservable_var_rad2
        C[0:3, 3:6] = C[0:3, 3:6] @ Pu
        C[3:6, 0:3] = C[0:3, 3:6].T
    return ObjectMeasurement(det.label, float(det.stamp_s), T_vo.translation_m.copy(), T_vo.rotation.copy(), C, U,
                             symmetry, index)


def _orthonormal(vectors) -> np.ndarray:
    if not vectors:
        return np.zeros((0, 3))
    M = np.asarray(vectors, dtype=float).reshape(-1, 3)
    U, s, Vt = np.linalg.svd(M, full_matrices=False)
    return Vt[s > 0.3 * s[0]]


def align_rotation(R: np.ndarray, R_ref: np.ndarray, symmetry: Symmetry, axes_world: np.ndarray) -> np.ndarray:
    """The orientation equivalent to ``R`` (under ``symmetry`` and free rotations about ``axes_world``)
    closest to ``R_ref``: the joint optimum over the group elements and the free angle (each element is aligned
    about the free axis first, then the closest is kept)."""
    cands = [R @ S for S in symmetry.finite_rotations()]  # the discrete group, or a cylinder's end-for-end turn
    if len(axes_world) == 1:
        u = axes_world[0]
        cands = [kern.axis_rotation(u, kern.best_angle_about_axis(Rk @ R_ref.T, u)) @ Rk for Rk in cands]
    best, best_tr = cands[0], -np.inf
    for Rk in cands:
        tr = np.trace(Rk @ R_ref.T)
        if tr > best_tr:
            best, best_tr = Rk, tr
    return best


@dataclass(frozen=True, eq=False)
class Innovation:
    """Innovation of one measurement against one landmark (full rows; ``n_pos = 3`` first rows are position)."""

    idx: np.ndarray  #: global state indices with non-zero Jacobian columns
    H: np.ndarray  #: (m, len(idx))
    nu: np.ndarray  #: (m,)
    R: np.ndarray  #: (m, m) measurement noise
    S: np.ndarray  #: (m, m) innovation covariance
    d2_pose: float
    d2_position: float
    #: the position rows' own Jacobian and innovation when they were iterated apart from the pose rows
    #: (:func:`iterated_innovation`); None: the first three rows of ``H`` / ``nu``
    H_position: np.ndarray | None = None
    nu_position: np.ndarray | None = None

    @property
    def dof_pose(self) -> int:
        return len(self.nu)

    def rows(self, which: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if which == "pose":
            return self.H, self.nu, self.R
        if self.H_position is not None:
            return self.H_position, self.nu_position, self.R[:3, :3]
        return self.H[:3], self.nu[:3], self.R[:3, :3]


def innovation(ekf: SemanticEkf, landmark_id: int, meas: ObjectMeasurement, R_wv_ahrs: np.ndarray,
               attitude_cov_world: np.ndarray | None, *, orientation_innovation: str = "rotvec") -> Innovation:
    """Innovation, Jacobian, noise and squared Mahalanobis distances of ``meas`` against a landmark, linearised at
    the filter's estimate (see :func:`iterated_innovation` for the gate and update of the mapper)."""
    nv = ekf.n_v
    off = ekf.landmarks[landmark_id].offset
    idx = np.concatenate([np.arange(nv), off + np.arange(6)])
    x = ekf.mean(idx)
    R = ekf.true_attitude(R_wv_ahrs)
    B = _observed_basis(meas.unobservable_axes_vehicle @ R.T)
    H, nu, N = _model_at(ekf, x, meas, R_wv_ahrs, attitude_cov_world, B, orientation_innovation)
    S = ekf.innovation_cov(idx, H, N)
    d2 = kern.mahalanobis2(nu, S)
    d2p = kern.mahalanobis2(nu[:3], S[:3, :3])
    return Innovation(idx, H, nu, N, S, d2, d2p)


def iterated_innovation(ekf: SemanticEkf, landmark_id: int, meas: ObjectMeasurement, R_wv_ahrs: np.ndarray,
                        attitude_cov_world: np.ndarray | None, *, orientation_innovation: str = "rotvec",
                        rows: tuple = ("position", "pose"), max_iterations: int = 10, tol: float = 1e-7,
                        keep_within: dict | None = None, linear_tol: float = 0.2) -> Innovation:
    """:func:`innovation` relinearised at the most likely state given the detection (Gauss-Newton: the iterated
    EKF of Bell & Cathey 1993), separately for the position rows and the pose rows (``rows``).

    The statistic is then the minimum over the state of ``|x - x_hat|^2_P + |z - h(x)|^2_N``, the gate of the
    exact model, instead of the first-order ``nu^T S^-1 nu``. They differ when the state is uncertain in a direction
    the model is curved in: a yaw-bias error ``b`` moves a landmark seen at range ``r`` by ``2 r sin(b/2)`` along
    a chord, whose radial part ``r (1 - cos b)`` (9 cm at 20 degrees and 1.5 m) the linearised ``S`` gives no
    variance, so a first sighting of a surveyed landmark under a large yaw bias fails the linear gate.

    The returned ``H`` / ``nu`` (and ``H_position`` / ``nu_position``) are the Jacobian at the final iterate and the
    innovation referred to the estimate, ``nu_i + H_i (x_i - x_hat)``: ``ekf.update(idx, H, nu, R)`` with them is
    the iterated-EKF update. The landmark's orientation enters linearly, at the estimate, as in :func:`innovation`:
    its errors are small, and a symmetric landmark's free angle (a huge variance, unobserved) would otherwise swing
    the relinearisation through the roll-pitch-yaw parameterisation's curvature. The model is therefore curved in
    the yaw bias only: without a yaw-bias state (or while the heading is observability-constrained) this is exactly
    :func:`innovation`. The noise ``R`` stays the one at the estimate (the graph's factors use it as the filter
    decided).

    ``keep_within``: ``{dof: chi-square threshold}``, the mapper's rule: rows whose linearised statistic is inside
    their gate *and* whose linearisation is adequate keep the linearised innovation (the EKF's update, unchanged);
    the others are iterated. Adequate: one Gauss-Newton step away, the model departs from its linearisation by less
    than ``linear_tol`` noise standard deviations (``|nu(x_1) + H (x_1 - x_hat) - nu|_R``; the same idea as the
    graph's relinearisation threshold). So the iteration corrects the linear gate's false rejections and the
    updates of large heading errors, and leaves the rest as it was. None: iterate every row asked for.
    """
    _check_iteration_arguments(rows, max_iterations, tol, linear_tol)
    nv = ekf.n_v
    off = ekf.landmarks[landmark_id].offset
    idx = np.concatenate([np.arange(nv), off + np.arange(6)])
    x0 = ekf.mean(idx)
    B = _observed_basis(meas.unobservable_axes_vehicle @ ekf.true_attitude(R_wv_ahrs).T)
    H0, nu0, N = _model_at(ekf, x0, meas, R_wv_ahrs, attitude_cov_world, B, orientation_innovation)
    m_pose = len(nu0)
    if not ekf.yaw_bias or getattr(ekf, "heading_constrained", False):  # linear in the state: one step
        S = ekf.innovation_cov(idx, H0, N)
        return Innovation(idx, H0, nu0, N, S, kern.mahalanobis2(nu0, S), kern.mahalanobis2(nu0[:3], S[:3, :3]))
    P = ekf.cov(idx)
    curved = np.arange(nv + 3)  # the vehicle (the yaw bias) and the landmark position; not its orientation

    def solve(m: int):
        def model(x):
            H, nu, _ = _model_at(ekf, x, meas, R_wv_ahrs, attitude_cov_world, B, orientation_innovation)
            return H[:m], nu[:m]
        return _gauss_newton(model, x0, P, H0[:m], nu0[:m], N[:m, :m], curved, max_iterations, tol)

    H, nu, S = H0, nu0, ekf.innovation_cov(idx, H0, N)
    S0 = S
    d2, d2p = kern.mahalanobis2(nu, S), kern.mahalanobis2(nu[:3], S[:3, :3])

    def kept(d2_lin: float, dof: int) -> bool:
        if keep_within is None or d2_lin > keep_within[dof]:
            return False
        m = 3 if dof == 3 else m_pose
        return _linearisation_adequate(lambda x: _model_at(ekf, x, meas, R_wv_ahrs, attitude_cov_world, B,
                                                           orientation_innovation)[1],
                                       x0, P, H0[:m], nu0[:m], N[:m, :m], S0[:m, :m], curved, linear_tol)

    Hp, nup, Sp = H[:3], nu[:3], S[:3, :3]
    if "position" in rows and not kept(d2p, 3):
        Hp, nup, Sp = solve(3)
        d2p = kern.mahalanobis2(nup, Sp)
    if "pose" in rows and m_pose > 3 and not kept(d2, m_pose):
        H, nu, S = solve(m_pose)
        d2 = kern.mahalanobis2(nu, S)
    return Innovation(idx, H, nu, N, S, d2, d2p, Hp, nup)


def _check_iteration_arguments(rows: Any, max_iterations: Any, tol: Any, linear_tol: Any) -> None:
    """:class:`SlamError` naming the argument of :func:`iterated_innovation` that is not what it must be."""
    if isinstance(rows, str) or not set(rows) <= {"position", "pose"}:
        raise SlamError(f"The 'rows' argument of iterated_innovation must be a sequence of 'position' and/or 'pose'. "
                        f"Got {rows!r} instead.")
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, int) or max_iterations < 1:
        raise SlamError(f"The 'max_iterations' argument of iterated_innovation must be an integer >= 1. "
                        f"Got {max_iterations!r} instead.")
    if not tol > 0:
        raise SlamError(f"The 'tol' argument of iterated_innovation must be > 0. Got {tol!r} instead.")
    if not linear_tol >= 0:
        raise SlamError(f"The 'linear_tol' argument of iterated_innovation must be >= 0. Got {linear_tol!r} instead.")


def _linearisation_adequate(innovation_at, x0: np.ndarray, P: np.ndarray, Hm: np.ndarray, num: np.ndarray,
                            Nm: np.ndarray, Sm: np.ndarray, curved: np.ndarray, linear_tol: float) -> bool:
    """Whether the rows ``(Hm, num)`` (noise ``Nm``, innovation covariance ``Sm``) linearised at ``x0`` stay within
    ``linear_tol`` noise standard deviations of the model (``innovation_at(x) -> nu``, the rows first) one
    Gauss-Newton step away: the linearisation's own error, in noise units."""
    m = len(num)
    x1 = x0.copy()
    try:
        x1[curved] += (P @ Hm.T @ np.linalg.solve(Sm, num))[curved]
    except np.linalg.LinAlgError:
        return False
    nu1 = innovation_at(x1)
    delta = nu1[:m] + Hm @ (x1 - x0) - num
    return kern.mahalanobis2(delta, Nm) <= linear_tol ** 2


def _gauss_newton(model, x0: np.ndarray, P: np.ndarray, H: np.ndarray, nu: np.ndarray, N: np.ndarray,
                  curved: np.ndarray, max_iterations: int, tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Iterated-EKF relinearisation: ``(H_i, nu_i + H_i (x_i - x0), S_i)`` at the fixed point ``x_i`` of
    ``x <- x0 + P H^T S^-1 (nu(x) + H(x) (x - x0))`` (``model(x) -> (H, nu)``), the components not in ``curved``
    held at ``x0`` (the model is linear in them); the first linearisation if an iterate is not finite or ``S`` is
    singular."""
    first = None
    x = x0.copy()
    for it in range(max(1, max_iterations)):
        nut = nu + H @ (x - x0)
        S = H @ P @ H.T + N
        S = 0.5 * (S + S.T)
        if first is None:
            first = (H, nut, S)
        if it == max_iterations - 1:
            break
        try:
            step = P @ H.T @ np.linalg.solve(S, nut)
        except np.linalg.LinAlgError:
            return first
        x_next = x0.copy()
        x_next[curved] += step[curved]
        if not np.all(np.isfinite(x_next)):
            return first
        if np.max(np.abs(x_next - x)) <= tol:
            break
        x = x_next
        H, nu = model(x)
    if not (np.all(np.isfinite(nut)) and np.all(np.isfinite(S))):
        return first
    return H, nut, S


def _observed_basis(axes_w: np.ndarray) -> np.ndarray:
    """Basis (3, k) of the observed rotation directions (world frame), given the unobservable axes."""
    if len(axes_w) == 0:
        return np.eye(3)
    if len(axes_w) == 1:
        return np.linalg.svd(np.eye(3) - np.outer(axes_w[0], axes_w[0]))[0][:, :2]
    return np.zeros((3, 0))


def _model_at(ekf, x: np.ndarray, meas: ObjectMeasurement, R_wv_ahrs: np.ndarray,
              attitude_cov_world: np.ndarray | None, B: np.ndarray, orientation_innovation: str):
    """``(H, nu, N)`` of ``meas`` linearised at the sub-state ``x = [vehicle (n_v); landmark (6)]`` (the yaw bias,
    when estimated, read from ``x``), the orientation rows in the observed basis ``B``."""
    nv = ekf.n_v
    p, l_p, l_rpy = x[0:3], x[nv:nv + 3], x[nv + 3:nv + 6]
    R = kern.rot_z(-float(x[ekf.i_yaw])) @ R_wv_ahrs if ekf.yaw_bias else R_wv_ahrs
    d = l_p - p
    R_l = rotation_from_rpy(*l_rpy)
    axes_w = meas.unobservable_axes_vehicle @ R.T
    R_meas = align_rotation(R @ meas.R_vehicle_object, R_l, meas.symmetry, axes_w)
    k = B.shape[1]
    m = 3 + k
    H = np.zeros((m, len(x)))
    Rt = R.T
    H[0:3, 0:3] = -Rt
    H[0:3, nv:nv + 3] = Rt
    if ekf.yaw_bias:
        H[0:3, ekf.i_yaw] = Rt @ kern.skew(_EZ) @ d
    # noise: detection part (pos in vehicle frame, rotation rotated to world) + AHRS part
    J = np.zeros((6, 6))
    J[0:3, 0:3] = np.eye(3)
    J[3:6, 3:6] = R
    N6 = J @ meas.noise_cov @ J.T
    if attitude_cov_world is not None:
        Je = np.vstack([-Rt @ kern.skew(d), np.eye(3)])
        N6 = N6 + Je @ attitude_cov_world @ Je.T
    nu = np.empty(m)
    nu[0:3] = meas.p_vehicle_object_m - Rt @ d
    rpy_mode = (orientation_innovation == "rpy" and k == 3 and abs(l_rpy[1]) < np.radians(80.0))
    if rpy_mode:
        Einv = kern.world_rate_to_rpy(l_rpy)
        T = np.zeros((6, 6))
        T[0:3, 0:3] = np.eye(3)
        T[3:6, 3:6] = Einv
        N = T @ N6 @ T.T
        nu[3:6] = wrap_angle(rpy_from_rotation(R_meas) - l_rpy)
        H[3:6, nv + 3:nv + 6] = np.eye(3)
        if ekf.yaw_bias:
            H[5, ekf.i_yaw] = 1.0
    else:
        T = np.zeros((m, 6))
        T[0:3, 0:3] = np.eye(3)
        T[3:, 3:6] = B.T
        N = T @ N6 @ T.T
        if k:
            nu[3:] = B.T @ kern.so3_log(R_meas @ R_l.T)
            H[3:, nv + 3:nv + 6] = B.T @ kern.rpy_to_world_rate(l_rpy)
            if ekf.yaw_bias:
                H[3:, ekf.i_yaw] = B.T @ _EZ
    return H, nu, 0.5 * (N + N.T)
