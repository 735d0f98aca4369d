"""The semantic EKF of Himri et al. (2018), with an exact *compressed* update for large maps.

State ``x = [p (3), v (3), (b_dvl (3), s_dvl (3), k_dvl, delta_dvl), (b_yaw), l_1 (6), ..., l_N (6)]``: vehicle
position in the world NED frame (m), body-frame velocity (m/s), optionally the DVL calibration (body-frame
Gauss-Markov biases b_dvl and s_dvl (m/s; s_dvl is driven only while the beams are on a slope), scale factor k
and yaw misalignment delta (rad): DVL = ``(1 + k) Rz(delta) v + b_dvl + s_dvl``),
optionally the AHRS yaw bias (rad; AHRS yaw = true yaw + b), and per landmark its world pose
``[x y z roll pitch yaw]`` (m, rad). ``i_dvl`` / ``i_yaw`` give the first index of the optional blocks (-1 when
absent).

Cost that scales. Predictions and updates act on an *active* set ``A`` (the vehicle and the landmarks near
it); the rest ``B`` of the map is kept in compressed form (Guivant & Nebot 2001, "compressed EKF"): three
small accumulators ``phi, psi, theta`` (``|A| x |A|``, ``|A| x |A|``, ``|A|``) give at any time

    P_AB = phi P_AB(0),   P_BB = P_BB(0) - P_AB(0)^T psi P_AB(0),   x_B = x_B(0) + P_AB(0)^T theta,

so that one update costs ``O(|A|^2)`` whatever the size of the map and the filter stays *exactly* the full
EKF. The ``O(n^2)`` "flush" happens only when the active set changes. With every landmark active (the
default for small maps) this is the ordinary EKF.

Numerics: Joseph-form covariance update on the active block, Cholesky solves (no inverse), symmetrised
covariance, wrapped landmark angles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SlamError
from . import _ekf_kernels as kern
from .compressed import CompressedState

_EZ = np.array([0.0, 0.0, 1.0])


@dataclass
class LandmarkInfo:
    """Book-keeping of one landmark (the state lives in the filter)."""

    label: str
    offset: int  #: index of its x in the state vector
    first_seen_s: float
    last_seen_s: float
    n_updates: int = 0
    name: str = ""


class SemanticEkf(CompressedState):
    """Vehicle + landmark EKF. See the module docstring for the state and the compressed update.

    Parameters
    ----------
    position_ned_m, velocity_body_mps : array-like of shape (3,)
        Initial mean.
    P0_vehicle : array of shape (n_v, n_v)
        Initial vehicle covariance, ``n_v = 6 + 8 * dvl_calibration + yaw_bias``.
    yaw_bias : bool
        Add the AHRS yaw-bias state.
    dvl_calibration : bool
        Add the DVL calibration states (bias (3), slope bias (3), scale factor, yaw misalignment); the biases
        are first-order Gauss-Markov processes (``dvl_bias_*``, ``dvl_slope_bias_*``: std, correlation time).
    """

    def __init__(self, position_ned_m, velocity_body_mps, P0_vehicle, *, yaw_bias: bool = False,
                 dvl_calibration: bool = False, dvl_bias_sigma_mps: float = 0.0, dvl_bias_tau_s: float = 1e9,
                 dvl_slope_bias_sigma_mps: float = 0.0, dvl_slope_bias_tau_s: float = 1e9) -> None:
        self.i_dvl = 6 if dvl_calibration else -1
        self.i_yaw = 6 + 8 * dvl_calibration if yaw_bias else -1
        self.n_v = 6 + 8 * dvl_calibration + yaw_bias
        self.dvl_slope_bias_sigma_mps = float(dvl_slope_bias_sigma_mps)
        self.dvl_slope_bias_tau_s = float(dvl_slope_bias_tau_s)
        self.yaw_bias = yaw_bias
        self.dvl_calibration = dvl_calibration
        self.dvl_bias_sigma_mps = float(dvl_bias_sigma_mps)
        self.dvl_bias_tau_s = float(dvl_bias_tau_s)
        P0 = np.asarray(P0_vehicle, dtype=float)
        if P0.shape != (self.n_v, self.n_v):
            raise SlamError(
                f"The 'P0_vehicle' argument of SemanticEkf must have shape ({self.n_v}, {self.n_v}). Got {P0.shape} "
                f"instead."
            )
        self.x = np.zeros(self.n_v)
        self.x[0:3] = position_ned_m
        self.x[3:6] = velocity_body_mps
        self.P = np.ascontiguousarray(0.5 * (P0 + P0.T))
        self.landmarks: list[LandmarkInfo] = []
        self._N: np.ndarray | None = None
        self._q_cache: dict = {}
        #: optional :class:`~semslam.slam.smoother.RtsRecorder`, told of every transition and update
        self.recorder = None
        self._set_active(np.arange(self.n_v))

    # ------------------------------------------------------------------ observability constraint
    def constrain_heading_nullspace(self, enable: bool = True) -> None:
        """Observability-constrained EKF (Huang, Mourikis & Roumeliotis 2010) for the yaw bias.

        With a yaw-bias state and only relative observations, a common rotation about the vertical of the
        trajectory and the map together with an opposite change of the bias changes no measurement: the
        direction ``N`` (``dp = e_z x (p - p_0)``, ``db = -1``, per landmark ``dl = e_z x (l - p_0)``,
        ``dyaw = +1``) is unobservable. The EKF evaluates its Jacobians at estimates that move between steps and
        so gains spurious information along ``N`` (its bias variance shrinks, its bias estimate wanders and the
        map rotates with it). Enabled, ``N`` is propagated with the filter's own ``F`` and ``G`` and every
        measurement Jacobian is replaced by the closest ``H'`` with ``H' N = 0``. Surveyed landmarks make the
        direction observable: :meth:`add_prior_landmarks` switches the constraint off.
        """
        if not enable or not self.yaw_bias:
            self._N = None
            return
        self.flush()
        N = np.zeros(self.n)
        N[self.i_yaw] = -1.0
        p = self.x[0:3]
        for lm in self.landmarks:
            N[lm.offset:lm.offset + 3] = np.cross(_EZ, self.x[lm.offset:lm.offset + 3] - p)
            N[lm.offset + 5] = 1.0
        self._N = N

    @property
    def heading_constrained(self) -> bool:
        """Whether the observability constraint of :meth:`constrain_heading_nullspace` is on."""
        return self._N is not None

    # ------------------------------------------------------------------ named state blocks
    def indices(self, block: str) -> np.ndarray:
        """Global state indices of a named block of the vehicle state: ``position`` (3, world NED, m),
        ``velocity`` (3, body, m/s), ``dvl_calibration`` (8: bias (3), degraded-bottom bias (3) (m/s), scale
        factor, misalignment (rad)) and ``yaw_bias`` (1, rad); the optional blocks raise when absent."""
        if block == "position":
            return np.arange(0, 3)
        if block == "velocity":
            return np.arange(3, 6)
        if block == "dvl_calibration" and self.dvl_calibration:
            return np.arange(self.i_dvl, self.i_dvl + 8)
        if block == "yaw_bias" and self.yaw_bias:
            return np.array([self.i_yaw])
        raise SlamError(
            f"The 'block' argument of SemanticEkf.indices must be one of position, velocity"
            f"{', dvl_calibration' if self.dvl_calibration else ''}{', yaw_bias' if self.yaw_bias else ''}. "
            f"Got {block!r} instead."
        )

    @property
    def position_ned_m(self) -> np.ndarray:
        """Vehicle position (world NED, m): a view of the state (the vehicle is always active)."""
        return self.xa[0:3]

    @property
    def position_cov_m2(self) -> np.ndarray:
        return self.Paa[0:3, 0:3]

    @property
    def velocity_body_mps(self) -> np.ndarray:
        return self.xa[3:6]

    @property
    def velocity_cov(self) -> np.ndarray:
        return self.Paa[3:6, 3:6]

    def yaw_bias_var_rad2(self) -> float:
        return float(self.Paa[self.i_yaw, self.i_yaw]) if self.yaw_bias else 0.0

    def landmark_positions(self) -> np.ndarray:
        """(N, 3) current world positions of every landmark (exact for passive ones after the last flush)."""
        offs = np.array([lm.offset for lm in self.landmarks], dtype=np.intp)
        if len(offs) == 0:
            return np.zeros((0, 3))
        pos = self.x[offs[:, None] + np.arange(3)]
        loc = self._loc[offs]
        a = loc >= 0
        pos[a] = self.xa[loc[a][:, None] + np.arange(3)]
        return pos

    def set_active_landmarks(self, landmark_ids) -> None:
        """Flush, then make the vehicle and ``landmark_ids`` the active set."""
        self.flush()
        idx = [np.arange(self.n_v)] + [self.landmarks[i].offset + np.arange(6) for i in sorted(set(landmark_ids))]
        self._set_active(np.concatenate(idx))

    def is_active(self, landmark_id: int) -> bool:
        return self.is_active_index(self.landmarks[landmark_id].offset)

    def vehicle_position(self) -> np.ndarray:
        return self.xa[0:3].copy()

    def vehicle_position_cov(self) -> np.ndarray:
        return self.Paa[0:3, 0:3].copy()

    def landmark_pose(self, i: int) -> np.ndarray:
        return self.mean(self.landmarks[i].offset + np.arange(6))

    def landmark_cov(self, i: int) -> np.ndarray:
        return self.cov(self.landmarks[i].offset + np.arange(6))

    def yaw_bias_rad(self) -> float:
        return float(self.xa[self.i_yaw]) if self.yaw_bias else 0.0

    def dvl_calibration_state(self) -> np.ndarray:
        """``[b (3), s (3) (m/s), k, delta (rad)]`` (zeros without the DVL calibration states)."""
        return self.xa[self.i_dvl:self.i_dvl + 8].copy() if self.dvl_calibration else np.zeros(8)

    def true_attitude(self, R_wv_ahrs: np.ndarray) -> np.ndarray:
        """Vehicle rotation corrected by the estimated yaw bias: ``Rz(-b) R_ahrs``."""
        if not self.yaw_bias:
            return R_wv_ahrs
        return kern.rot_z(-float(self.xa[self.i_yaw])) @ R_wv_ahrs

    # ------------------------------------------------------------------ prediction
    def predict(
        self,
        dt_s: float,
        R_wv_ahrs: np.ndarray,
        *,
        velocity_rw,
        attitude_cov_world: np.ndarray | None = None,
        yaw_bias_rw: float = 0.0,
        dvl_on_slope: bool = False,
    ) -> None:
        """Constant-velocity prediction over ``dt_s`` with the AHRS attitude as input.

        ``p += R v dt``, ``v`` constant, landmarks static. Process noise: white acceleration of spectral
        density ``velocity_rw**2`` (m^2/s^3) in the body frame (``velocity_rw`` a number, or three numbers
        for surge, sway and heave), the AHRS attitude error (world-frame
        rotation covariance ``attitude_cov_world``, rad^2) mapped through ``[R v dt]x``, and a yaw-bias
        random walk ``yaw_bias_rw`` (rad/sqrt(s)).
        """
        if dt_s <= 0.0:
            return
        R = self.true_attitude(R_wv_ahrs)
        if self.recorder is not None:
            self.recorder.before_transition(self)
        att = np.zeros((3, 3)) if attitude_cov_world is None else attitude_cov_world
        a = float(np.exp(-dt_s / self.dvl_bias_tau_s))
        a2 = float(np.exp(-dt_s / self.dvl_slope_bias_tau_s))
        q2 = self.dvl_slope_bias_sigma_mps**2 * (1.0 - a2 * a2) if dvl_on_slope else 0.0
        q = self._q_cache.get(velocity_rw) if isinstance(velocity_rw, (float, int, tuple)) else None
        if q is None:
            q = np.ascontiguousarray(np.broadcast_to(np.asarray(velocity_rw, dtype=float), (3,)) ** 2)
            if isinstance(velocity_rw, (float, int, tuple)):
                self._q_cache[velocity_rw] = q
        F = kern.predict_vehicle(self.Paa, self.xa, np.ascontiguousarray(R), float(dt_s), q,
                                 np.ascontiguousarray(att, dtype=float), self.n_v, float(yaw_bias_rw), self.i_yaw,
                                 self.i_dvl, a, self.dvl_bias_sigma_mps**2 * (1.0 - a * a), a2, q2)
        if self.compressed:
            nv = self.n_v
            self._phi[:nv, :] = F @ self._phi[:nv, :]
            self._dirty = True
        if self._N is not None:
            self._N[:self.n_v] = F @ self._N[:self.n_v]
        if self.recorder is not None:
            self.recorder.compose(F, rows=self.n_v)

    def inflate(self, idx, Q: np.ndarray) -> None:
        """Add ``Q`` to the covariance block of the active global indices ``idx`` (an extra process noise)."""
        if self.recorder is not None:
            self.recorder.before_transition(self)
        loc = self._loc[np.asarray(idx, dtype=np.intp)]
        if (loc < 0).any():
            raise SlamError("SemanticEkf.inflate touches a passive state; call set_active_landmarks first.")
        self.Paa[np.ix_(loc, loc)] += Q

    # ------------------------------------------------------------------ updates
    def innovation_cov(self, idx, Hc: np.ndarray, Rn: np.ndarray) -> np.ndarray:
        """``S = H P H^T + R`` for a measurement whose Jacobian has non-zero columns ``idx`` (global)."""
        S = Hc @ self.cov(idx) @ Hc.T + Rn
        return 0.5 * (S + S.T)

    def update(self, idx, Hc: np.ndarray, nu: np.ndarray, Rn: np.ndarray) -> None:
        """Linear(ised) update ``z = H x + n`` with innovation ``nu``; ``H`` non-zero only on ``idx``.

        Every index must be active (see :meth:`set_active_landmarks`). Joseph form on the active block;
        the passive block is updated exactly through the compression accumulators.
        """
        loc = self._loc[np.asarray(idx, dtype=np.intp)]
        if (loc < 0).any():
            raise SlamError("SemanticEkf.update touches a passive state; call set_active_landmarks first.")
        if self.recorder is not None:
            self.recorder.before_update(self)
        if self._N is not None:
            u = self._N[np.asarray(idx, dtype=np.intp)]
            uu = float(u @ u)
            if uu > 0.0:
                Hc = np.asarray(Hc, dtype=float)
                Hc = Hc - np.outer(Hc @ u, u) / uu
        K, S = kern.joseph_update(self.Paa, self.xa, loc, np.ascontiguousarray(Hc, dtype=float),
                                  np.ascontiguousarray(nu, dtype=float), np.ascontiguousarray(Rn, dtype=float))
        if self.compressed:
            HPhi = Hc @ self._phi[loc, :]
            SinvHPhi = np.linalg.solve(S, np.column_stack([HPhi, nu]))
            self._theta += HPhi.T @ SinvHPhi[:, -1]
            psi = self._psi + HPhi.T @ SinvHPhi[:, :-1]
            self._psi = 0.5 * (psi + psi.T)
            self._phi -= K @ HPhi
            self._dirty = True
        # angles are wrapped after updates that touch the landmark block (a vehicle-only update moves them by
        # far less than a turn; the next landmark update wraps them)
        if len(self._A) > self.n_v and loc.max() >= self.n_v:
            self._normalize_angles()
        elif self.yaw_bias and abs(self.xa[self.i_yaw]) > np.pi:
            self.xa[self.i_yaw] = kern_wrap(self.xa[self.i_yaw])

    def _normalize_angles(self) -> None:
        nv = self.n_v
        if self.yaw_bias:
            self.xa[self.i_yaw] = kern_wrap(self.xa[self.i_yaw])
        nl = (len(self._A) - nv) // 6
        if nl == 0:
            return
        ang = self.xa[nv:].reshape(nl, 6)[:, 3:6]
        if np.abs(ang).max() <= np.pi / 2 or (np.abs(ang[:, 1]).max() <= np.pi / 2 and np.abs(ang).max() < np.pi):
            return
        over = np.abs(ang[:, 1]) > np.pi / 2
        if self.recorder is not None and over.any():
            self.recorder.before_transition(self)
            J = np.ones(self.n)
            J[self._A[nv + 6 * np.flatnonzero(over) + 4]] = -1.0
            self.recorder.compose(np.diag(J))
        for j in np.flatnonzero(over):  # pitch beyond +-90 deg: same rotation, pitch mirrored
            ang[j] = [ang[j, 0] + np.pi, np.pi - ang[j, 1], ang[j, 2] + np.pi]
            r = nv + 6 * j + 4
            self.Paa[r, :] *= -1.0
            self.Paa[:, r] *= -1.0
            if self.compressed:
                self._phi[r, :] *= -1.0
        ang[:] = kern_wrap(ang)

    # ------------------------------------------------------------------ map management
    def add_landmark(self, pose_xyzrpy: np.ndarray, G_vehicle: np.ndarray, noise_cov: np.ndarray, *,
                     label: str, stamp_s: float, name: str = "") -> int:
        """Augment the state with a landmark ``l = g(x_v, z)``.

        ``G_vehicle`` (6, n_v) is ``dg/dx_v`` and ``noise_cov`` (6, 6) the covariance of ``g``'s
        measurement part; the new landmark gets the full cross-covariance ``G P_v,:`` with the vehicle and
        every landmark. Returns the landmark id.
        """
        if self.recorder is not None:
            self.recorder.before_transition(self)
        self.flush()
        n, nv = self.n, self.n_v
        G = np.asarray(G_vehicle, dtype=float)
        cross = G @ self.P[:nv, :]                           # (6, n)
        Pll = G @ self.P[:nv, :nv] @ G.T + noise_cov
        P = np.empty((n + 6, n + 6))
        P[:n, :n] = self.P
        P[n:, :n] = cross
        P[:n, n:] = cross.T
        P[n:, n:] = 0.5 * (Pll + Pll.T)
        self.P = P
        self.x = np.concatenate([self.x, pose_xyzrpy])
        if self._N is not None:
            self._N = np.concatenate([self._N, G @ self._N[:nv]])
        self.landmarks.append(LandmarkInfo(label, n, stamp_s, stamp_s, 0, name))
        self._set_active(np.concatenate([self._A, n + np.arange(6)]))
        if self.recorder is not None:
            F = np.zeros((n + 6, n))
            F[:n] = np.eye(n)
            F[n:, :nv] = G
            self.recorder.compose(F)
        return len(self.landmarks) - 1

    def add_prior_landmarks(self, poses_xyzrpy: np.ndarray, covs: np.ndarray, labels, *, stamp_s: float = 0.0,
                            names=None) -> list[int]:
        """Add landmarks known a priori (a surveyed map), independent of the vehicle. They start passive. ``covs``:
        (m, 6, 6) one covariance per landmark, or (6m, 6m) their joint covariance."""
        if self.recorder is not None:
            self.recorder.before_transition(self)
        self.flush()
        poses = np.asarray(poses_xyzrpy, dtype=float).reshape(-1, 6)
        m, n = len(poses), self.n
        P = np.zeros((n + 6 * m, n + 6 * m))
        P[:n, :n] = self.P
        covs = np.asarray(covs, dtype=float)
        if covs.shape == (6 * m, 6 * m):
            P[n:, n:] = covs
        else:
            for j in range(m):
                s = n + 6 * j
                P[s:s + 6, s:s + 6] = covs[j]
        self.P = P
        self.x = np.concatenate([self.x, poses.ravel()])
        self._N = None  # a surveyed landmark fixes the heading: nothing left unobservable to protect
        ids = []
        for j in range(m):
            self.landmarks.append(LandmarkInfo(labels[j], n + 6 * j, stamp_s, stamp_s, 0,
                                               "" if names is None else names[j]))
            ids.append(len(self.landmarks) - 1)
        self._set_active(self._A)
        if self.recorder is not None:
            self.recorder.compose(np.eye(n + 6 * m, n))
        return ids


def kern_wrap(a):
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi
