"""The front end of the graph backend: the semantic EKF itself, whose every operation also writes the graph.

The filter keeps making the decisions it makes for the EKF backend (sensor gates, association, the pose/position
cascade, consensus initialisation: one association module for every backend), and every operation is mirrored:

* ``predict`` -> the segment accumulator (``F``, the linearisation offset ``u``, the process noise ``Q`` computed by
  the filter's own kernel from a zero covariance: the same process model and noise);
* a vehicle-only ``update`` (DVL, depth) -> segment rows; ``inflate`` (DVL manoeuvre reset) -> a process-noise step;
* a landmark ``update`` -> a nonlinear landmark factor (:class:`GraphMapper`);
* ``add_landmark`` / ``add_prior_landmarks`` -> a landmark variable with its initialisation factor / prior.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from .. import _ekf_kernels as kern
from ..ekf import SemanticEkf
from ..mapping import ObjectMapper
from . import factors as fac


class FrontEkf(SemanticEkf):
    """:class:`SemanticEkf` that mirrors its operations into ``self.backend`` (a
    :class:`~semslam.slam.graph.backend.GraphBackend`, set by :meth:`GraphSession._make_filter`)."""

    backend = None
    huber_k = None
    orientation_innovation = "rotvec"
    last_update = None

    def predict(self, dt_s, R_wv_ahrs, *, velocity_rw, attitude_cov_world=None, yaw_bias_rw=0.0, dvl_on_slope=False):
        if dt_s <= 0.0:
            return
        nv = self.n_v
        x = self.xa[:nv].copy()
        R = np.ascontiguousarray(self.true_attitude(R_wv_ahrs))
        att = np.zeros((3, 3)) if attitude_cov_world is None else np.ascontiguousarray(attitude_cov_world, dtype=float)
        a = float(np.exp(-dt_s / self.dvl_bias_tau_s))
        a2 = float(np.exp(-dt_s / self.dvl_slope_bias_tau_s))
        q2 = self.dvl_slope_bias_sigma_mps ** 2 * (1.0 - a2 * a2) if dvl_on_slope else 0.0
        q = np.ascontiguousarray(np.broadcast_to(np.asarray(velocity_rw, dtype=float), (3,)) ** 2)
        Q = np.zeros((nv, nv))
        xf = x.copy()
        F = kern.predict_vehicle(Q, xf, R, float(dt_s), q, att, nv, float(yaw_bias_rw), self.i_yaw, self.i_dvl, a,
                                 self.dvl_bias_sigma_mps ** 2 * (1.0 - a * a), a2, q2)
        super().predict(dt_s, R_wv_ahrs, velocity_rw=velocity_rw, attitude_cov_world=attitude_cov_world,
                        yaw_bias_rw=yaw_bias_rw, dvl_on_slope=dvl_on_slope)
        self.backend.seg.predict(F, xf - F @ x, Q)

    def update(self, idx, Hc, nu, Rn):
        idx = np.asarray(idx, dtype=np.intp)
        Hc, nu, Rn = (np.array(a, dtype=float) for a in (Hc, nu, Rn))
        self.last_update = (idx, Hc, nu, Rn)
        nv = self.n_v
        if idx.max() < nv:  # DVL, depth: rows of the current segment, linearised where the filter is now
            Hv = np.zeros((len(nu), nv))
            Hv[:, idx] = Hc
            self.backend.seg.measure(Hv, nu + Hv @ self.xa[:nv], Rn)
        super().update(idx, Hc, nu, Rn)

    def inflate(self, idx, Q):
        nv = self.n_v
        Qv = np.zeros((nv, nv))
        idx = np.asarray(idx, dtype=np.intp)
        Qv[np.ix_(idx, idx)] = Q
        self.backend.seg.predict(np.eye(nv), np.zeros(nv), Qv)
        super().inflate(idx, Q)

    def add_landmark(self, pose_xyzrpy, G_vehicle, noise_cov, *, label, stamp_s, name=""):
        x_lin = self.xa[:self.n_v].copy()
        j = super().add_landmark(pose_xyzrpy, G_vehicle, noise_cov, label=label, stamp_s=stamp_s, name=name)
        b = self.backend
        kx = b.keyframe(stamp_s, x_lin)
        kl = b.new_landmark(pose_xyzrpy)
        b.add_factor(fac.landmark_init_factor(kx, kl, pose_xyzrpy, G_vehicle, x_lin, noise_cov,
                                              f"the initialisation of landmark {j} ({label})"))
        return j

    def add_prior_landmarks(self, poses_xyzrpy, covs, labels, *, stamp_s=0.0, names=None):
        ids = super().add_prior_landmarks(poses_xyzrpy, covs, labels, stamp_s=stamp_s, names=names)
        poses = np.asarray(poses_xyzrpy, dtype=float).reshape(-1, 6)
        covs = np.asarray(covs, dtype=float)
        if covs.ndim == 2:  # a joint covariance: the graph's priors take its diagonal blocks
            covs = np.array([covs[6 * k:6 * k + 6, 6 * k:6 * k + 6] for k in range(len(poses))])
        for j, pose, C in zip(ids, poses, covs):
            kl = self.backend.new_landmark(pose)
            self.backend.add_factor(fac.prior_factor(kl, pose, C, f"surveyed landmark {j}", angles=slice(3, 6)))
        return ids


class GraphMapper(ObjectMapper):
    """:class:`ObjectMapper` whose accepted landmark updates also become graph factors; ``records`` the session's
    log (where the mapper's decisions are read back)."""

    def __init__(self, *args, records: list, **kw) -> None:
        super().__init__(*args, **kw)
        self.records = records

    def process(self, t, dets, R_ahrs, att_cov):
        ekf = self.ekf
        ekf.backend.keyframe(t, ekf.xa[:ekf.n_v])
        super().process(t, dets, R_ahrs, att_cov)

    def _update_landmark(self, t, x, j, R_ahrs, att_cov, det):
        ekf = self.ekf
        n, b_lin = len(self.records), ekf.yaw_bias_rad()  # the linearisation of the filter's decision
        super()._update_landmark(t, x, j, R_ahrs, att_cov, det)
        new = self.records[n:]
        if not (new and new[-1].get("kind") == "landmark" and new[-1].get("accepted")):
            return
        which = new[-1]["test"]
        Rn = ekf.last_update[3]
        b = ekf.backend
        b.add_landmark_factor((b.key, fac.L(j)), partial(
            fac.landmark_factor, b.key, fac.L(j), x, R_ahrs, which, Rn, n_v=ekf.n_v, yaw_bias=ekf.yaw_bias,
            i_yaw=ekf.i_yaw, orientation_innovation=ekf.orientation_innovation, huber_k=ekf.huber_k,
            what=f"detection {x.index} at {t!r} s ({x.label})", yaw_bias_lin=b_lin), robust=ekf.huber_k is not None)
