"""Is a 6-DoF registration answer trustworthy, or could the object be turned over?

Near-symmetric objects (valve bodies, pipe fittings) align almost as well after a half turn about one of their
principal axes; a feature registration then returns one of the two with high fitness, and nothing says which.
:func:`flip_check` takes the answer, turns the source by a half turn about each of its three principal axes
(through its centroid), refines each by point-to-plane ICP and compares: when a turned answer fits within
``FITNESS_RATIO`` of the fitness and ``RMSE_RATIO`` of the inlier RMSE of the answer, the answer is **ambiguous**
(the orientation cannot be trusted; the position can); a turned answer that fits better makes it ambiguous too
(it is reported, not substituted, so that the answer stays PCL's). An answer is **reliable** when it converged,
is not ambiguous and reaches ``MIN_FITNESS``.

Measured on the 60 ordered pairs of real RealSense valve views (``benchmarks/real_valves.py``): with
``FITNESS_RATIO`` 0.8 and ``MIN_FITNESS`` 0.8, 15 answers are reliable and none of them is off by more than
30 degrees; with ``MIN_FITNESS`` 0.5, two half-turn flips (fitness 0.70 and 0.79, their turned variants 0.51 and
0.57: the flip genuinely fits better) would pass as reliable. Geometry alone cannot settle those pairs.

With the up direction known, prefer :func:`~semslam.registration.align_upright`, which removes these flips.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from scipy.spatial import cKDTree

from ..geometry import RigidTransform
from .icp import align_icp
from .result import inlier_statistics

__all__ = ["FITNESS_RATIO", "MIN_FITNESS", "RMSE_RATIO", "flip_check", "half_turns"]

#: a turned answer with at least this share of the answer's fitness ...
FITNESS_RATIO = 0.8
#: ... and at most this multiple of its inlier RMSE makes the answer ambiguous
RMSE_RATIO = 1.25
#: fitness below which no answer is reliable
MIN_FITNESS = 0.8


def flip_check(source: np.ndarray, target: np.ndarray, T_target_source: np.ndarray, *, max_correspondence_m: float,
               max_iterations: int = 30) -> dict:
    """Compare the answer ``T_target_source`` (4x4) with its three half-turned variants (see the module docstring).

    Returns ``{"T": the answer 4x4, "fitness", "rmse_m", "ambiguous": bool, "alternatives": [...]}``;
    ``alternatives`` holds, per principal axis, the turned answer's fitness, RMSE and its rotation from the
    answer in degrees.
    """
    src = np.asarray(source, dtype=float)
    c = src.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov((src - c).T))
    tgt = np.asarray(target, dtype=float)
    T0 = np.asarray(T_target_source, dtype=float)
    fit0, rmse0, _ = inlier_statistics(src @ T0[:3, :3].T + T0[:3, 3], cKDTree(tgt), max_correspondence_m)
    best = {"T": T0, "fitness": float(fit0), "rmse_m": float(rmse0)}
    alts = []
    for axis in vecs.T:
        F = np.eye(4)
        F[:3, :3] = Rotation.from_rotvec(np.pi * axis).as_matrix()
        F[:3, 3] = c - F[:3, :3] @ c  # about the source's centroid
        res = align_icp(src, tgt, init_T=RigidTransform(best["T"] @ F), method="plane",
                        max_correspondence_m=max_correspondence_m, max_iterations=max_iterations)
        T = np.asarray(res.T_target_source.matrix)
        dR = best["T"][:3, :3].T @ T[:3, :3]
        alts.append({"T": T, "fitness": float(res.fitness), "rmse_m": float(res.inlier_rmse_m),
                     "rotation_deg": float(np.degrees(Rotation.from_matrix(dR).magnitude()))})
    ambiguous = any(a["rotation_deg"] > 30.0 and a["fitness"] >= FITNESS_RATIO * best["fitness"]
                    and a["rmse_m"] <= RMSE_RATIO * best["rmse_m"] for a in alts)
    return {**best, "ambiguous": bool(ambiguous),
            "alternatives": [{k: v for k, v in a.items() if k != "T"} for a in alts]}


def half_turns(T_target_source: np.ndarray, source: np.ndarray) -> list[np.ndarray]:
    """The three half-turned variants of ``T_target_source`` (4x4): the aligned source turned by pi about each of
    its principal axes through its centroid, in the target frame. The pose search refines and scores them with
    its own hypotheses, so that a near-equal flip the search did not keep is compared (and, when it scores within
    the margin, flags the pose ambiguous and widens its covariance) instead of leaving a confident wrong pose."""
    T = np.asarray(T_target_source, dtype=float)
    p = np.asarray(source, dtype=float) @ T[:3, :3].T + T[:3, 3]
    if len(p) < 4:
        return []
    c = p.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov((p - c).T))
    out = []
    for axis in vecs.T:
        F = np.eye(4)
        F[:3, :3] = Rotation.from_rotvec(np.pi * axis).as_matrix()
        F[:3, 3] = c - F[:3, :3] @ c
        out.append(F @ T)
    return out
