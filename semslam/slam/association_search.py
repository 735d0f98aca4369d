"""Data association: which landmark each object measurement of a stamp is, among the gated pairs: global nearest
neighbour (:func:`associate`) or joint compatibility branch and bound (:func:`associate_jcbb`), with the chi-square
gates (:class:`GateThresholds`). The innovations come from :mod:`semslam.slam.association`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from . import _ekf_kernels as kern

__all__ = ["GateThresholds", "associate", "associate_jcbb"]


@dataclass(frozen=True)
class GateThresholds:
    """Chi-square gates (squared Mahalanobis distance) at probability ``probability``."""

    probability: float = 0.99

    def threshold(self, dof: int) -> float:
        from scipy.stats import chi2  # lazily: scipy.stats costs ~1 s to import

        return float(chi2.ppf(self.probability, dof))


def associate(d2: np.ndarray, gate: np.ndarray) -> list[tuple[int, int]]:
    """Global nearest neighbour: pairs ``(measurement, landmark)`` minimising the summed squared
    Mahalanobis distance among gated pairs (Hungarian algorithm). ``d2``, ``gate``: (n_meas, n_landmarks)."""
    if d2.size == 0:
        return []
    cost = np.where(gate, d2, 1e12)
    from scipy.optimize import linear_sum_assignment

    rows, cols = linear_sum_assignment(cost)
    return [(int(r), int(c)) for r, c in zip(rows, cols) if gate[r, c]]


def associate_jcbb(innovations: dict[tuple[int, int], Any], ekf: Any, n_meas: int,
                   gate: np.ndarray, probability: float) -> list[tuple[int, int]]:
    """Joint compatibility branch and bound (Neira & Tardos 2001) on the position rows (``innovations``: the
    :class:`~semslam.slam.association.Innovation` of each gated ``(measurement, landmark)`` pair; ``ekf``: the
    :class:`~semslam.slam.ekf.SemanticEkf` they were computed on).

    Maximises the number of pairings, then minimises the joint squared Mahalanobis distance; a hypothesis
    is kept only if its stacked innovation passes the joint chi-square test (``3 * pairs`` dof).
    """
    best: list = [[], np.inf]

    def joint_d2(pairs):
        if not pairs:
            return 0.0
        idx = np.unique(np.concatenate([innovations[p].idx for p in pairs]))
        pos = {g: i for i, g in enumerate(idx)}
        Hs, nus, Rs = [], [], []
        for p in pairs:
            inn = innovations[p]
            Hp, nup, Rp = inn.rows("position")
            Hrow = np.zeros((3, len(idx)))
            Hrow[:, [pos[g] for g in inn.idx]] = Hp
            Hs.append(Hrow)
            nus.append(nup)
            Rs.append(Rp)
        H = np.vstack(Hs)
        from scipy.linalg import block_diag

        S = H @ ekf.cov(idx) @ H.T + block_diag(*Rs)
        return kern.mahalanobis2(np.concatenate(nus), S)

    def recurse(i, pairs, used):
        if len(pairs) + (n_meas - i) < len(best[0]):
            return
        if i == n_meas:
            d2 = joint_d2(pairs)
            if len(pairs) > len(best[0]) or (len(pairs) == len(best[0]) and d2 < best[1]):
                best[0], best[1] = list(pairs), d2
            return
        for j in np.flatnonzero(gate[i]):
            if j in used:
                continue
            cand = pairs + [(i, int(j))]
            if joint_d2(cand) <= GateThresholds(probability).threshold(3 * len(cand)):
                recurse(i + 1, cand, used | {int(j)})
        recurse(i + 1, pairs, used)

    recurse(0, [], frozenset())
    return best[0]
