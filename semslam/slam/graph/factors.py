"""GTSAM factors of the graph backend, on the EKF's own parametrisation (so that both solve the same problem).

Variables: per keyframe the vehicle state ``X = [p (3), v (3), (DVL calibration (8)), (yaw bias)]`` (the layout of
:class:`~semslam.slam.ekf.SemanticEkf`, a GTSAM ``Vector``); per landmark ``L = [x y z roll pitch yaw]`` (world
NED, m, rad). The attitude is the AHRS input, as in the filter.

* :func:`segment_factor`: the pre-integrated prediction + DVL + depth rows between two keyframes
  (:mod:`~semslam.slam.graph.segment`), linear, whitened (native, :func:`linear_factor`);
* :func:`landmark_factor`: one detection of landmark ``j`` from keyframe ``k``, the filter's measurement model
  (:func:`~semslam.slam.association.innovation`: position rows, and the observed rotation rows with the rotation
  a symmetric class leaves unobservable projected out; the symmetry alignment is redone at every linearisation),
  relinearised by the optimiser, Huber-robust on request;
* :func:`landmark_init_factor`: the consensus initialisation ``L = g(X_k) + n`` of a new landmark;
* :func:`prior_factor`: a Gaussian prior on a vector variable (start state, surveyed landmarks).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from ...errors import SlamError
from .. import _ekf_kernels as kern
from ...geometry import rotation_from_rpy
from ..association import ObjectMeasurement, _observed_basis, align_rotation, innovation


def X(i: int) -> int:
    return gtsam.symbol("x", i)


def L(j: int) -> int:
    return gtsam.symbol("l", j)


def gaussian(cov: np.ndarray, what: str) -> gtsam.noiseModel.Base:
    """A full-covariance noise model, or SlamError naming ``what`` when ``cov`` is not a finite PSD matrix."""
    C = np.asarray(cov, dtype=float)
    if not np.isfinite(C).all() or C.shape[0] != C.shape[1]:
        raise SlamError(f"The covariance of {what} must be a finite square matrix. Got {C!r} instead.")
    C = 0.5 * (C + C.T)
    w = np.linalg.eigvalsh(C)
    if w.min() < -1e-9 * max(abs(w.max()), 1e-300):
        raise SlamError(f"The covariance of {what} must be positive semi-definite. Got smallest eigenvalue "
                        f"{w.min():.3g} instead.")
    if w.min() <= 1e-12 * max(w.max(), 1e-300):
        C = C + np.eye(len(C)) * 1e-12 * max(w.max(), 1e-300)
    try:
        return gtsam.noiseModel.Gaussian.Covariance(C)
    except RuntimeError as exc:  # pragma: no cover - guarded above
        raise SlamError(f"The covariance of {what} was refused by GTSAM: {exc}") from None


def linear_factor(keys, As, b: np.ndarray, W: np.ndarray | None = None):
    """``sum_i A_i X_i - b`` (rows whitened by ``W``, ``W^T W`` the information; None: already whitened) as a native
    GTSAM factor: a ``JacobianFactor`` held by a ``LinearContainerFactor`` at ``X = 0`` (exact for a linear model).

    Native, not a ``CustomFactor``: GTSAM's Python wrapper passes a copy of the whole ``Values`` to a Python error
    function, so every linearisation of a ``CustomFactor`` costs O(size of the graph) (it made iSAM2's update time
    grow linearly with the dive, and batch's iterations quadratically)."""
    b = np.asarray(b, dtype=float)
    As = [np.asarray(A, dtype=float) for A in As]
    if W is not None:
        As, b = [W @ A for A in As], W @ b
    args: list = []
    lin = gtsam.Values()
    for k, A in zip(keys, As):
        args += [k, np.ascontiguousarray(A)]
        lin.insert(k, np.zeros(A.shape[1]))
    jf = gtsam.JacobianFactor(*args, np.ascontiguousarray(b), gtsam.noiseModel.Unit.Create(len(b)))
    return gtsam.LinearContainerFactor(jf, lin)


def prior_factor(key: int, mean: np.ndarray, cov: np.ndarray, what: str, angles: slice | None = None):
    """``X - mean`` with covariance ``cov`` (linear: ``angles``, the rows that are angles, need no wrapping, since
    the variable starts at the mean and the graph never wraps a value)."""
    mean = np.asarray(mean, dtype=float).copy()
    return linear_factor([key], [np.eye(len(mean))], mean, gaussian(cov, what).R())


def segment_factor(k0: int, k1: int | None, A0: np.ndarray, A1: np.ndarray, b: np.ndarray):
    """``A0 X_k0 + A1 X_k1 - b`` (whitened rows: unit noise); unary on ``k0`` when ``k1`` is None."""
    if k1 is None:
        return linear_factor([k0], [A0], b)
    return linear_factor([k0, k1], [A0, A1], b)


@dataclass
class _Info:
    offset: int


class _Stub:
    """The part of the filter's interface that :func:`innovation` reads, over one ``[X; L]`` vector."""

    def __init__(self, n_v: int, yaw_bias: bool, i_yaw: int) -> None:
        self.n_v, self.yaw_bias, self.i_yaw = n_v, yaw_bias, i_yaw
        self.landmarks = [_Info(n_v)]
        self.x = np.zeros(n_v + 6)

    def mean(self, idx):
        return self.x[idx]

    def true_attitude(self, R):
        return kern.rot_z(-float(self.x[self.i_yaw])) @ R if self.yaw_bias else R

    def innovation_cov(self, idx, H, N):
        return N


def _jr_inv(phi: np.ndarray) -> np.ndarray:
    """Inverse right Jacobian of SO(3) at the rotation vector ``phi``."""
    th = float(np.linalg.norm(phi))
    K = kern.skew(phi)
    if th < 1e-6:
        return np.eye(3) + 0.5 * K + K @ K / 12.0
    c = 1.0 / th ** 2 - (1.0 + np.cos(th)) / (2.0 * th * np.sin(th))
    return np.eye(3) + 0.5 * K + c * (K @ K)


def landmark_factor(kx: int, kl: int, meas: ObjectMeasurement, R_ahrs: np.ndarray, which: str, noise_cov: np.ndarray,
                    *, n_v: int, yaw_bias: bool, i_yaw: int, orientation_innovation: str = "rotvec",
                    huber_k: float | None = None, what: str = "a detection", yaw_bias_lin: float = 0.0,
                    linearize_at: tuple | None = None):
    """The filter's object measurement (rows ``which``: ``pose`` or ``position``) as a factor on ``(X_k, L_j)``;
    ``noise_cov`` the rows' noise at the filter's decision (detection + AHRS parts), expressed, for a rotation with
    a free axis, in the basis of the observed directions at that decision (``yaw_bias_lin``: the filter's yaw bias
    then): the basis is kept fixed, as the noise model is (a basis of a plane recomputed at every evaluation may
    turn within it).

    Error ``h(X, L) - z``, the negated innovation of :func:`innovation` (the same model, rows and Jacobians; the
    ``rotvec`` form is evaluated here directly, the ``rpy`` form through :func:`innovation` itself).

    ``linearize_at``: ``(x_k, l_j)``: the factor linearised there (:func:`linearized`, native) instead of the
    ``CustomFactor`` (which the optimiser relinearises itself, but every linearisation of which costs O(size of the
    graph): GTSAM's wrapper copies the whole ``Values`` for the Python error function)."""
    noise = gaussian(noise_cov, what)
    if huber_k is not None:
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(float(huber_k)), noise)
    m = noise_cov.shape[0]
    rot_rows = which == "pose" and m > 3
    if orientation_innovation != "rotvec" and rot_rows:
        err = _rpy_form_error(kx, kl, meas, R_ahrs, which, n_v=n_v, yaw_bias=yaw_bias, i_yaw=i_yaw,
                              orientation_innovation=orientation_innovation)
    else:
        err = _rotvec_form_error(kx, kl, meas, R_ahrs, m, rot_rows, n_v=n_v, yaw_bias=yaw_bias, i_yaw=i_yaw,
                                 yaw_bias_lin=yaw_bias_lin)
    f = gtsam.CustomFactor(noise, [kx, kl], err)
    return f if linearize_at is None else linearized(f, linearize_at)


def _rpy_form_error(kx: int, kl: int, meas: ObjectMeasurement, R_ahrs: np.ndarray, which: str, *, n_v: int,
                    yaw_bias: bool, i_yaw: int, orientation_innovation: str):
    """The error function of :func:`landmark_factor` in a form other than ``rotvec``: through :func:`innovation`."""
    stub = _Stub(n_v, yaw_bias, i_yaw)

    def err_generic(this, values, H):
        stub.x[:n_v] = values.atVector(kx)
        stub.x[n_v:] = values.atVector(kl)
        inn = innovation(stub, 0, meas, R_ahrs, None, orientation_innovation=orientation_innovation)
        Hc, nu, _ = inn.rows(which)
        if H is not None:
            H[0] = np.ascontiguousarray(Hc[:, :n_v])
            H[1] = np.ascontiguousarray(Hc[:, n_v:])
        return -nu

    return err_generic


def _rotvec_form_error(kx: int, kl: int, meas: ObjectMeasurement, R_ahrs: np.ndarray, m: int, rot_rows: bool, *,
                       n_v: int, yaw_bias: bool, i_yaw: int, yaw_bias_lin: float):
    """The error function of :func:`landmark_factor` in the ``rotvec`` form (``m`` rows; the rotation rows with
    ``rot_rows``), evaluated here directly, in the observed basis at the filter's yaw bias ``yaw_bias_lin``."""
    z_p, R_vo, U = meas.p_vehicle_object_m, meas.R_vehicle_object, meas.unobservable_axes_vehicle
    ez = np.array([0.0, 0.0, 1.0])

    B = _observed_basis(U @ (kern.rot_z(-yaw_bias_lin) @ R_ahrs if yaw_bias else R_ahrs).T)

    def rot_rows_at(x, lm):
        R = kern.rot_z(-float(x[i_yaw])) @ R_ahrs if yaw_bias else R_ahrs
        R_l = rotation_from_rpy(*lm[3:6])
        axes_w = U @ R.T
        phi = kern.so3_log(align_rotation(R @ R_vo, R_l, meas.symmetry, axes_w) @ R_l.T)
        return -(B.T @ phi), B, phi

    def err(this, values, H):
        x, lm = values.atVector(kx), values.atVector(kl)
        R = kern.rot_z(-float(x[i_yaw])) @ R_ahrs if yaw_bias else R_ahrs
        Rt = R.T
        d = lm[0:3] - x[0:3]
        e = np.empty(m)
        e[0:3] = Rt @ d - z_p
        Hx, Hl = np.zeros((m, n_v)), np.zeros((m, 6))
        Hx[0:3, 0:3], Hl[0:3, 0:3] = -Rt, Rt
        if yaw_bias:
            Hx[0:3, i_yaw] = Rt @ kern.skew(ez) @ d
        if rot_rows:
            e[3:], _, phi = rot_rows_at(x, lm)
            if H is not None and len(U):
                # a free axis: the alignment about it follows the landmark, so differentiate through it
                h, e0 = 1e-7, e[3:]
                for c in range(3):
                    dl = np.zeros(6)
                    dl[3 + c] = h
                    Hl[3:, 3 + c] = (rot_rows_at(x, lm + dl)[0] - e0) / h
                if yaw_bias:
                    dx = np.zeros(n_v)
                    dx[i_yaw] = h
                    Hx[3:, i_yaw] = (rot_rows_at(x + dx, lm)[0] - e0) / h
            elif H is not None:
                # exact derivative (the filter takes Jr^-1 = I, right at a zero residual): Gauss-Newton converges
                Hl[3:, 3:6] = B.T @ _jr_inv(phi) @ kern.rpy_to_world_rate(lm[3:6])
                if yaw_bias:  # the bias turns the measured rotation on the left: Jl^-1(phi) = Jr^-1(-phi)
                    Hx[3:, i_yaw] = B.T @ _jr_inv(-phi) @ ez
        if H is not None:
            H[0], H[1] = Hx, Hl
        return e

    return err


def landmark_init_factor(kx: int, kl: int, pose0: np.ndarray, G: np.ndarray, x_lin: np.ndarray, cov: np.ndarray,
                         what: str = "a new landmark"):
    """``L - pose0 - G (X_k - x_lin)`` with covariance ``cov`` (the filter's state augmentation; linear, as
    :func:`prior_factor`: the landmark starts at ``pose0``, so its angles need no wrapping)."""
    pose0, G, x_lin = (np.asarray(a, dtype=float).copy() for a in (pose0, G, x_lin))
    return linear_factor([kx, kl], [-G, np.eye(6)], pose0 - G @ x_lin, gaussian(cov, what).R())



def linearized(factor, at) -> gtsam.LinearContainerFactor:
    """The nonlinear ``factor`` linearised by GTSAM at ``at`` (one vector per key of the factor: whitening and a
    robust kernel's weight as GTSAM's own linearisation gives them there), held as a native factor."""
    vals = gtsam.Values()
    for k, x in zip(factor.keys(), at):
        vals.insert(k, np.asarray(x, dtype=float))
    return gtsam.LinearContainerFactor(factor.linearize(vals), vals)
