"""Object landmarks: association of detections with the map, landmark updates, consensus initialisation of
new landmarks, and surveyed (a-priori) landmarks.

The papers' cascade: a detection is first tested against the landmarks of its class with the full 6-DoF pose,
else with the position only; unassociated detections become candidates, and a candidate becomes a landmark
once ``consensus_min_observations`` of them agree (:class:`~semslam.slam.consensus.ConsensusInitializer`).
The gates are those of the iterated innovation (:func:`~semslam.slam.association.iterated_innovation`); a detection
that misses the association gate but passes the much wider creation gate of a landmark of its class is dropped,
never pooled towards a duplicate of that landmark.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..detection import Detection
from ..errors import SlamError
from ..geometry import RigidTransform, rpy_from_rotation
from ..symmetry import Symmetry
from . import _ekf_kernels as kern
from .association import GateThresholds, associate, associate_jcbb, iterated_innovation, measurement_from_detection
from .config import SlamConfig
from .consensus import ConsensusInitializer, Observation
from .ekf import SemanticEkf

_EZ = np.array([0.0, 0.0, 1.0])


def drift_since(P_now: np.ndarray, P_then: list[np.ndarray]) -> np.ndarray:
    """Covariance of ``mean_i (e_now - e_i)``, the vehicle's position-error growth since each of ``n``
    observations (``P_then`` their position covariances, oldest first), as for a random walk: the growth
    since observation ``i`` is the positive part ``D_i`` of ``P_now - P_i``, growths are nested, so
    ``cov(e_now - e_i, e_now - e_j) = D_max(i, j)`` and the mean's covariance is ``sum_ij D_max(i,j) / n^2``."""
    n = len(P_then)
    if n == 0:
        return np.zeros((3, 3))
    out = np.zeros((3, 3))
    for i, Pi in enumerate(P_then):
        w, V = np.linalg.eigh(0.5 * ((P_now - Pi) + (P_now - Pi).T))
        D = (V * np.maximum(w, 0.0)) @ V.T
        out += (2 * i + 1) * D  # D_i is the later member for pairs (i, j <= i): 2 i + 1 of them
    return out / (n * n)


class ObjectMapper:
    """Turns detections into landmark updates and new landmarks on ``ekf``; ``log`` receives one record
    per decision (the run's ``updates.csv``)."""

    def __init__(self, ekf: SemanticEkf, cfg: SlamConfig, mode: str, symmetries: dict[str, Symmetry],
                 T_vehicle_scanner: RigidTransform, log: Callable[..., None]) -> None:
        self.ekf, self.cfg, self.sym, self.T_vs, self._log = ekf, cfg, symmetries, T_vehicle_scanner, log
        self.test = "position" if mode == "position" else "pose"
        self.consensus = ConsensusInitializer(
            cfg.initialisation.consensus_position_m,
            cfg.initialisation.consensus_attitude,
            cfg.initialisation.consensus_min_observations,
            cfg.initialisation.consensus_max_age_s,
        )
        gate = GateThresholds(cfg.gating.gate_probability)
        self._thr = {d: gate.threshold(d) for d in range(1, 7)}
        self._thr_create = max(self._thr[3], GateThresholds(cfg.gating.creation_gate_probability).threshold(3))

    # ------------------------------------------------------------------ surveyed landmarks
    def add_surveyed(self, stamp_s: float, names, labels, T_world_objects, position_sigma_m: float,
                     rotation_sigma_rad: float, covariances_6x6=None, joint=None) -> None:
        """Landmarks of surveyed objects (a known reference structure, an earlier dive's map), independent of the
        vehicle, each known to its own 6x6 covariance (x, y, z, roll, pitch, yaw) or, where None, to the given
        standard deviations. They make the absolute heading observable."""
        poses, covs = [], []
        given = list(covariances_6x6) if covariances_6x6 is not None else [None] * len(T_world_objects)
        for T, Cg in zip(T_world_objects, given):
            rpy = rpy_from_rotation(T.rotation)
            if Cg is not None:
                poses.append(np.concatenate([T.translation_m, rpy]))
                covs.append(0.5 * (np.asarray(Cg, dtype=float) + np.asarray(Cg, dtype=float).T))
                continue
            Einv = kern.world_rate_to_rpy(rpy)
            C = np.zeros((6, 6))
            C[0:3, 0:3] = np.eye(3) * position_sigma_m ** 2
            C[3:6, 3:6] = Einv @ Einv.T * rotation_sigma_rad ** 2
            poses.append(np.concatenate([T.translation_m, rpy]))
            covs.append(0.5 * (C + C.T))
        self.ekf.add_prior_landmarks(np.array(poses), np.array(covs) if joint is None else joint, list(labels),
                                     stamp_s=stamp_s, names=list(names))

    # ------------------------------------------------------------------ detections
    def _ensure_active(self, j: int) -> None:
        ekf, cfg = self.ekf, self.cfg
        if ekf.is_active(j):
            return
        if len(ekf.landmarks) <= cfg.map.dense_max_landmarks:
            ids = range(len(ekf.landmarks))
        else:
            ekf.flush()
            d = np.linalg.norm(ekf.landmark_positions() - ekf.position_ned_m, axis=1)
            ids = set(np.flatnonzero(d < cfg.map.active_radius_m).tolist()) | {j}
        ekf.set_active_landmarks(ids)

    def process(self, t: float, dets: list[Detection], R_ahrs: np.ndarray, att_cov: np.ndarray | None) -> None:
        """Associate the detections of one stamp with the map (per class), update, or start candidates."""
        ekf, cfg = self.ekf, self.cfg
        meas = [measurement_from_detection(d, self.T_vs, symmetry=self.sym.get(d.label),
                                           unobservable_var_rad2=cfg.initialisation.unobservable_var_rad2, index=k)
                for k, d in enumerate(dets)]
        labels = [lm.label for lm in ekf.landmarks]
        lpos = ekf.landmark_positions()
        p = ekf.position_ned_m
        unassociated = []
        for label in sorted({x.label for x in meas}):
            M = [x for x in meas if x.label == label]
            L = [j for j, lb in enumerate(labels) if lb == label
                 and np.linalg.norm(lpos[j] - p) < cfg.gating.candidate_radius_m]
            d2 = np.full((len(M), len(L)), np.inf)
            inns = {}
            for a, x in enumerate(M):
                for b, j in enumerate(L):
                    inn = iterated_innovation(ekf, j, x, R_ahrs, att_cov, rows=("position",), keep_within=self._thr,
                                              orientation_innovation=cfg.gating.orientation_innovation)
                    inns[(a, b)] = inn
                    d2[a, b] = inn.d2_position
            gate = d2 <= self._thr[3]
            if cfg.gating.association == "jcbb" and len(M) > 1:
                pairs = associate_jcbb(inns, ekf, len(M), gate, cfg.gating.gate_probability)
            else:
                pairs = associate(d2, gate)
            paired = {a for a, _ in pairs}
            for a, b in pairs:
                self._update_landmark(t, M[a], L[b], R_ahrs, att_cov, dets[M[a].index])
            for a, x in enumerate(M):
                if a not in paired:
                    if gate[a].any():  # compatible with a landmark taken by another detection: ambiguous, drop
                        self._log(stamp_s=t, kind="landmark", accepted=False, test="none", label=label,
                                  detection=x.index, reason="ambiguous")
                    elif (d2[a] <= self._thr_create).any():  # a near miss of a landmark: not a new object
                        self._log(stamp_s=t, kind="landmark", accepted=False, test="none", label=label,
                                  detection=x.index, reason="near landmark")
                    else:
                        unassociated.append(x)
        for x in unassociated:
            self._to_consensus(t, x, R_ahrs, att_cov, dets[x.index])

    def _update_landmark(self, t, x, j, R_ahrs, att_cov, det) -> None:
        ekf = self.ekf
        self._ensure_active(j)
        rows = ("position", "pose") if self.test == "pose" else ("position",)
        inn = iterated_innovation(ekf, j, x, R_ahrs, att_cov, rows=rows, keep_within=self._thr,
                                  orientation_innovation=self.cfg.gating.orientation_innovation)
        lm = ekf.landmarks[j]
        common = dict(stamp_s=t, kind="landmark", landmark=j, label=x.label, landmark_label=lm.label,
                      detection=x.index, object_name=det.extras.get("object_name", ""))
        if self.test == "pose" and inn.dof_pose > 3 and inn.d2_pose <= self._thr[inn.dof_pose]:
            which, d2, dof = "pose", inn.d2_pose, inn.dof_pose
        elif inn.d2_position <= self._thr[3]:
            which, d2, dof = "position", inn.d2_position, 3
        else:
            self._log(**common, nis=inn.d2_position, dof=3, threshold=self._thr[3], accepted=False, test="none")
            return
        if x.label != lm.label:  # pragma: no cover - guarded by construction
            raise SlamError("internal error: cross-class landmark update")
        Hc, nu, Rn = inn.rows(which)
        ekf.update(inn.idx, Hc, nu, Rn)
        lm.last_seen_s = t
        lm.n_updates += 1
        self._log(**common, nis=d2, dof=dof, threshold=self._thr[dof], accepted=True, test=which)

    def _to_consensus(self, t, x, R_ahrs, att_cov, det) -> None:
        ekf = self.ekf
        R = ekf.true_attitude(R_ahrs)
        p = ekf.position_ned_m.copy()
        axes_w = x.unobservable_axes_vehicle @ R.T
        obs = Observation(x.label, t, p + R @ x.p_vehicle_object_m, R @ x.R_vehicle_object, x.symmetry, axes_w,
                          payload=(R, p, x, att_cov, det.extras.get("object_name", ""), ekf.position_cov_m2.copy()))
        res = self.consensus.add(obs)
        self._log(stamp_s=t, kind="candidate", label=x.label, detection=x.index, accepted=res is not None,
                  object_name=det.extras.get("object_name", ""))
        if res is None:
            return
        members, pos, R_mean = res
        self._add_landmark(t, members, pos, R_mean)

    def _add_landmark(self, t, members, pos, R_mean) -> None:
        ekf = self.ekf
        n = len(members)
        rpy = rpy_from_rotation(R_mean)
        Cp = np.zeros((3, 3))
        Cr = np.zeros((3, 3))
        for o in members:
            R, p, x, att_cov, _, _ = o.payload
            N = x.noise_cov
            Cp += R @ N[0:3, 0:3] @ R.T
            Cr += R @ N[3:6, 3:6] @ R.T
            if att_cov is not None:
                d = o.position_world_m - p
                Cp += kern.skew(d) @ att_cov @ kern.skew(d).T
                Cr += att_cov
        Cp /= n * n
        Cr /= n * n
        # the members' world positions carry the vehicle's error at *their* stamps, the new landmark is tied to
        # the vehicle *now*: add the covariance of the mean displacement error since then (else the landmark looks
        # n-fold more precise relative to the vehicle than it is, and the next detections fail the gate)
        Cp += drift_since(ekf.position_cov_m2, [o.payload[5] for o in sorted(members, key=lambda o: o.stamp_s)])
        for u in members[0].axes_world:  # free rotation about an unobservable axis: wide prior, never updated
            Cr += np.outer(u, u) * np.pi ** 2
        Einv = kern.world_rate_to_rpy(rpy)
        noise = np.zeros((6, 6))
        noise[0:3, 0:3] = Cp
        noise[3:6, 3:6] = Einv @ Cr @ Einv.T
        G = np.zeros((6, ekf.n_v))
        G[0:3, 0:3] = np.eye(3)
        if ekf.yaw_bias:
            G[0:3, ekf.i_yaw] = -kern.skew(_EZ) @ (pos - ekf.position_ned_m)
            G[5, ekf.i_yaw] = -1.0
        names = [o.payload[4] for o in members]
        name = max(set(names), key=names.count) if names else ""
        j = ekf.add_landmark(np.concatenate([pos, rpy]), G, noise, label=members[0].label, stamp_s=t, name=name)
        ekf.landmarks[j].first_seen_s = min(o.stamp_s for o in members)
        self._log(stamp_s=t, kind="new_landmark", landmark=j, label=members[0].label, accepted=True,
                  n_observations=n, object_name=name)

