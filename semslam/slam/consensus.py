"""Delayed landmark initialisation by consensus (Himri et al. 2019, section II-B).

Unassociated observations are kept per class in the world frame. For each pair the position error
(Euclidean distance) and the attitude error ``d = 1 - <q1, q2>^2`` (= sin^2 of half the angle, sign
invariant; computed modulo the class symmetry) are compared with two thresholds. The observation with the
most consensus is selected; once its consensus set (itself included) holds ``min_observations``, the set is
averaged (positions arithmetically, orientations by the quaternion eigenvector method of Markley et al.
2007, not Euler angles) and handed back for initialisation; a minority outlier never enters the average.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry import quat_wxyz_from_rotation, rotation_from_quat_wxyz
from ..symmetry import Symmetry
from .association import align_rotation


@dataclass(eq=False)
class Observation:
    """An unassociated observation in the world frame, with what initialisation needs."""

    label: str
    stamp_s: float
    position_world_m: np.ndarray
    R_world_object: np.ndarray
    symmetry: Symmetry = field(default_factory=Symmetry)
    axes_world: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    payload: object = None  #: anything the caller needs back (measurement, vehicle pose, ...)


def attitude_distance(R1: np.ndarray, R2: np.ndarray) -> float:
    """``1 - <q1, q2>^2`` of two rotations (0 = same orientation, 1 = 180 degrees apart)."""
    q1, q2 = quat_wxyz_from_rotation(R1), quat_wxyz_from_rotation(R2)
    return float(1.0 - np.dot(q1, q2) ** 2)


def quaternion_mean(rotations: list[np.ndarray]) -> np.ndarray:
    """Rotation of the average quaternion: the principal eigenvector of ``sum q q^T`` (sign invariant)."""
    Q = np.array([quat_wxyz_from_rotation(R) for R in rotations])
    w, V = np.linalg.eigh(Q.T @ Q)
    return rotation_from_quat_wxyz(V[:, -1])


@dataclass
class ConsensusInitializer:
    """Per-class pools of unassociated observations (see module docstring).

    Parameters
    ----------
    position_threshold_m : float
        Two observations agree in position if their distance is below this.
    attitude_threshold : float
        ... and in attitude if ``1 - <q1,q2>^2`` is below this (0.02 ~ 16 degrees).
    min_observations : int
        Size of the consensus set (the selected observation included) needed to initialise a landmark.
    max_age_s : float
        Observations older than this are forgotten.
    use_attitude : bool
        Use the attitude test (False: position only).
    """

    position_threshold_m: float = 0.5
    attitude_threshold: float = 0.02
    min_observations: int = 4
    max_age_s: float = 120.0
    use_attitude: bool = True
    pools: dict = field(default_factory=dict)

    def add(self, obs: Observation) -> tuple[list[Observation], np.ndarray, np.ndarray] | None:
        """Add ``obs``; return ``(consensus_set, position_mean, R_mean)`` when a landmark can be
        initialised (those observations leave the pool), else None."""
        pool = [o for o in self.pools.get(obs.label, []) if obs.stamp_s - o.stamp_s <= self.max_age_s]
        pool.append(obs)
        self.pools[obs.label] = pool
        agree = self.agreement(pool)
        counts = agree.sum(axis=1)
        best = int(np.argmax(counts))
        if counts[best] < self.min_observations:
            return None
        members = [pool[i] for i in np.flatnonzero(agree[best])]
        ref = pool[best]
        pos = np.mean([o.position_world_m for o in members], axis=0)
        R_mean = quaternion_mean([align_rotation(o.R_world_object, ref.R_world_object, o.symmetry, o.axes_world)
                                  for o in members])
        self.pools[obs.label] = [o for i, o in enumerate(pool) if not agree[best, i]]
        return members, pos, R_mean

    def agreement(self, pool: list[Observation]) -> np.ndarray:
        """Boolean (n, n) matrix: observation i agrees with j (diagonal True)."""
        P = np.array([o.position_world_m for o in pool])
        ok = np.linalg.norm(P[:, None] - P[None], axis=-1) < self.position_threshold_m
        if self.use_attitude:
            n = len(pool)
            for i in range(n):
                for j in range(i + 1, n):
                    if ok[i, j]:
                        Rj = align_rotation(pool[j].R_world_object, pool[i].R_world_object, pool[j].symmetry,
                                            pool[j].axes_world)
                        ok[i, j] = ok[j, i] = attitude_distance(pool[i].R_world_object, Rj) < self.attitude_threshold
        return ok
