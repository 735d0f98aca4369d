"""Gravity-aligned ("upright") registration: 4 degrees of freedom when both clouds know where up is.

A vehicle knows its roll and pitch (the AHRS), a tripod camera is level, a rig knows its mounting: the
direction "up" is then known in both clouds' frames and the relative rotation is one angle about it plus a
small tilt. This removes the near-symmetric flips that defeat feature-based 6-DoF registration on real
partial views of valves and pipework (a 180-degree turn about the viewing axis or the pipe axis turns
the object upside down; objects on a structure do not do that between two looks):

1. **Yaw scan.** The source is turned so that its up meets the target's, then about the up axis every
   ``yaw_step_deg``; at each yaw the translation is fitted (trimmed nearest-neighbour steps, rotation
   held) and the truncated mean squared distance scored. The distinct local minima of that circular
   profile are the hypotheses.
2. **Refinement.** Each of the best ``n_hypotheses`` is refined by point-to-plane ICP over yaw and
   translation only (4 parameters; tilt stays as the up vectors say).
3. **Verdict.** The best refined hypothesis wins. When a distinct one (more than ``min_separation_deg``
   away in yaw) scores within ``ambiguity_ratio`` of it (ratio of RMS residuals), the answer is flagged
   ``ambiguous`` and its yaw standard deviation widened to cover the alternative; it is ``reliable``
   only when unambiguous and the fitness reaches ``min_fitness``.

The covariance is the point-to-plane Gauss-Newton one, ``rmse^2 (J^T J)^-1`` over (yaw, x, y, z), with
the tilt taken from the stated uncertainty of the up vectors (``up_sigma_deg``), in the tangent
convention of :mod:`semslam.pose.covariance` (rotation then translation, target frame).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from .._validation import as_float_array, check_int, check_positive
from ..errors import RegistrationError
from ..geometry import RigidTransform
from ._upright_kernels import fit_translation, point_to_plane_4dof, target_normals, truncated_cost
from .result import RegistrationResult

__all__ = ["UprightConfig", "align_upright", "rotation_between", "upright_rotations"]


@dataclass(frozen=True)
class UprightConfig:
    """Settings of :func:`align_upright` (lengths in metres, angles in degrees)."""

    yaw_step_deg: float = 5.0
    n_hypotheses: int = 4
    min_separation_deg: float = 20.0
    #: a distinct hypothesis whose RMS residual is within this factor of the best one makes it ambiguous
    ambiguity_ratio: float = 1.25
    #: inlier fraction below which an answer is never reliable
    min_fitness: float = 0.5
    #: correspondence distance; None: 3 x the clouds' median point spacing (after thinning)
    max_correspondence_m: float | None = None
    max_points: int = 1500
    #: source points used by the yaw scan (the refinement uses up to ``max_points``)
    scan_points: int = 400
    icp_iterations: int = 30
    #: standard deviation of the stated up directions (tilt of the answer), degrees
    up_sigma_deg: float = 2.0
    #: floors of the reported standard deviations: point-to-plane information ignores that two partial
    #: views do not show the same surface; on the real valve pairs the yaw errors between views of one
    #: setting are 0-1.2 degrees and between settings 2-7 degrees (benchmarks/real_valves.py)
    min_yaw_sigma_deg: float = 3.0
    min_translation_sigma_m: float = 0.002
    #: a hypothesis is dropped when fewer of the source's surface normals face the target sensor than this
    #: fraction of the best-facing hypothesis' (it would show the target camera the object's back)
    min_facing_ratio: float = 0.6
    #: register the target onto the source too and score every hypothesis of both directions by both clouds'
    #: truncated distances: the answer does not depend on which cloud is the source, and a turn the source's
    #: own overlap pulls short is found from the other side (the real valves' 47-degree pairs 3/8 -> 6/8 within
    #: 10 degrees, benchmarks/real_valves.py); twice the time
    symmetric: bool = True

    def check(self, caller: str) -> None:
        check_positive("yaw_step_deg", self.yaw_step_deg, caller=caller)
        check_int("n_hypotheses", self.n_hypotheses, caller=caller, minimum=1)
        check_positive("min_separation_deg", self.min_separation_deg, caller=caller)
        check_positive("ambiguity_ratio", self.ambiguity_ratio, caller=caller)
        check_positive("up_sigma_deg", self.up_sigma_deg, caller=caller)
        check_int("max_points", self.max_points, caller=caller, minimum=50)
        check_int("scan_points", self.scan_points, caller=caller, minimum=20)
        check_int("icp_iterations", self.icp_iterations, caller=caller, minimum=1)
        if self.max_correspondence_m is not None:
            check_positive("max_correspondence_m", self.max_correspondence_m, caller=caller)
        if not 0.0 <= float(self.min_fitness) <= 1.0:
            raise RegistrationError(
                f"The 'min_fitness' setting of {caller} must be in [0, 1]. Got {self.min_fitness!r} instead."
            )


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation R with ``R @ a = b`` (unit vectors (3,)); a half turn about any normal when opposite."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    v, c = np.cross(a, b), float(np.dot(a, b))
    s = float(np.linalg.norm(v))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        return Rotation.from_rotvec(np.pi * perp / np.linalg.norm(perp)).as_matrix()
    return Rotation.from_rotvec(v / s * np.arctan2(s, c)).as_matrix()


def _unit(name: str, value: Any, caller: str) -> np.ndarray:
    """``value`` as a unit 3-vector; scaled by its largest entry first, so that 1e308 or 1e-300 entries (whose
    norm overflows or underflows) still give their direction."""
    v = as_float_array(name, value, (3,), caller=caller)
    m = float(np.abs(v).max())
    if not m > 0.0:
        raise RegistrationError(
            f"The '{name}' argument of {caller} must be a non-zero 3-vector (up direction). Got {v.tolist()} instead."
        )
    v = v / m
    return v / float(np.linalg.norm(v))


def _thin(pts: np.ndarray, max_points: int) -> np.ndarray:
    if len(pts) <= max_points:
        return pts
    return pts[np.linspace(0, len(pts) - 1, max_points).astype(np.int64)]


def align_upright(source: Any, target: Any, *, up_source: Any, up_target: Any,
                  config: UprightConfig | None = None) -> RegistrationResult:
    """Align ``source`` (N, 3) onto ``target`` (M, 3), both in metres, knowing up in each frame.

    ``source`` and ``target`` may be :class:`~semslam.cloud.PointCloud` (their ``viewpoint_xyz_m`` is the
    sensor origin; arrays mean a sensor at the frame's origin). A hypothesis that would turn most of the
    source's visible surface away from the target's sensor is dropped (``min_facing_ratio``). With ``symmetric``
    (the default) the target is registered onto the source too and every hypothesis of both directions is scored
    by the truncated distances of both clouds, so that the answer does not depend on which cloud is the source.

    Returns a :class:`RegistrationResult` with ``method="upright"``; ``extras`` hold ``ambiguous``,
    ``reliable``, ``yaw_sigma_deg``, ``covariance_6x6`` (tangent: rotation [rad] then translation [m],
    target frame) and ``hypotheses`` (yaw about the target's up in degrees, RMS residual, fitness, the direction
    it was found in, best first).
    """
    caller = "align_upright"
    cfg = config or UprightConfig()
    cfg.check(caller)
    src = as_float_array("source", getattr(source, "points_xyz_m", source), (None, 3), caller=caller)
    tgt = as_float_array("target", getattr(target, "points_xyz_m", target), (None, 3), caller=caller)
    for name, pts in (("source", src), ("target", tgt)):
        if len(pts) < 10:
            raise RegistrationError(f"The '{name}' cloud of {caller} needs at least 10 points. Got {len(pts)} instead.")
    u_s, u_t = _unit("up_source", up_source, caller), _unit("up_target", up_target, caller)
    vp_s = np.asarray(getattr(source, "viewpoint_xyz_m", np.zeros(3)), dtype=float)
    vp_t = np.asarray(getattr(target, "viewpoint_xyz_m", np.zeros(3)), dtype=float)
    t0 = time.perf_counter()
    fwd = _Direction(src, tgt, vp_s, vp_t, u_s, u_t, cfg)
    hyps = fwd.hypotheses(cfg)
    rev = None
    if cfg.symmetric:
        rev = _Direction(tgt, src, vp_t, vp_s, u_t, u_s, cfg)
        hyps += [_inverted(h, fwd) for h in rev.hypotheses(cfg)]
    for h in hyps:
        h["rms_m"] = _score(h, fwd, rev)
    hyps.sort(key=lambda h: h["rms_m"])
    hyps = [h for k, h in enumerate(hyps)  # starts that refined into the same answer count once
            if all(_angle_deg(h["yaw_deg"] - g["yaw_deg"]) > 2.0 for g in hyps[:k])]
    best = hyps[0]
    rivals = [h for h in hyps[1:] if _angle_deg(h["yaw_deg"] - best["yaw_deg"]) > cfg.min_separation_deg]
    ambiguous = bool(rivals) and rivals[0]["rms_m"] <= cfg.ambiguity_ratio * best["rms_m"]
    cov = _covariance(best, u_t, u_s, cfg)
    yaw_sigma = float(np.degrees(np.sqrt(max(u_t @ cov[:3, :3] @ u_t, 0.0))))
    if ambiguous:
        spread = np.radians(max(_angle_deg(h["yaw_deg"] - best["yaw_deg"]) for h in rivals
                                if h["rms_m"] <= cfg.ambiguity_ratio * best["rms_m"]))
        cov[:3, :3] += np.outer(u_t, u_t) * (
            spread**2 - np.radians(yaw_sigma) ** 2 if spread > np.radians(yaw_sigma) else 0.0
        )
        yaw_sigma = float(np.degrees(spread))
    # the result's fitness is the source's (forward) one: measured already for a forward answer
    fitness, rmse, n_inliers = ((best["fitness"], best["rmse_m"], best["n_inliers"]) if best["direction"] == "forward"
                                else fwd.inliers(best["R"], best["t"]))
    reliable = (not ambiguous) and best["fitness"] >= cfg.min_fitness
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = best["R"], best["t"]
    t1 = time.perf_counter()
    return RegistrationResult(
        T_target_source=RigidTransform(_orthonormal(T)), fitness=fitness, inlier_rmse_m=rmse,
        n_iterations=int(best["n_it"]), converged=True,
        timings_ms={"yaw_scan": fwd.scan_ms + (rev.scan_ms if rev else 0.0),
                    "refine": fwd.refine_ms + (rev.refine_ms if rev else 0.0), "total": 1e3 * (t1 - t0)},
        n_inliers=n_inliers, max_correspondence_m=fwd.mc, method="upright",
        extras={"ambiguous": ambiguous, "reliable": bool(reliable), "yaw_sigma_deg": yaw_sigma,
                "covariance_6x6": cov.tolist(), "up_source": u_s.tolist(), "up_target": u_t.tolist(),
                "direction": best["direction"],
                "hypotheses": [{"yaw_deg": h["yaw_deg"], "rms_m": h["rms_m"], "fitness": h["fitness"],
                                "facing": h["facing"], "direction": h["direction"]} for h in hyps]},
    )


class _Direction:
    """One direction of :func:`align_upright`: ``src`` onto ``tgt`` (thinned; the target's KD-tree, normals and
    correspondence gate), its yaw scan and refined hypotheses."""

    def __init__(self, src: np.ndarray, tgt: np.ndarray, vp_s: np.ndarray, vp_t: np.ndarray, u_s: np.ndarray,
                 u_t: np.ndarray, cfg: UprightConfig) -> None:
        self.src_t, self.tgt_t = _thin(src, cfg.max_points), _thin(tgt, 4 * cfg.max_points)
        self.src_n = target_normals(self.src_t, cKDTree(self.src_t))
        self.src_n *= np.where(np.einsum("ij,ij->i", self.src_n, vp_s - self.src_t) < 0, -1.0, 1.0)[:, None]
        self.tree = cKDTree(self.tgt_t)
        spacing = float(np.median(self.tree.query(self.tgt_t, 2)[0][:, 1]))
        self.mc = cfg.max_correspondence_m or max(3.0 * spacing, 1e-9)
        self.normals = target_normals(self.tgt_t, self.tree)
        self.u_t, self.vp_t = u_t, vp_t
        self.R_up = rotation_between(u_s, u_t)
        self.scan_ms = self.refine_ms = 0.0

    def hypotheses(self, cfg: UprightConfig) -> list[dict]:
        """The refined starts of the yaw scan's distinct minima, those that would show the target's sensor the
        source's back dropped."""
        t0 = time.perf_counter()
        c_src, c_tgt = np.median(self.src_t, axis=0), np.median(self.tgt_t, axis=0)
        yaws = np.radians(np.arange(0.0, 360.0, cfg.yaw_step_deg))
        costs = _yaw_scan_costs(yaws, _thin(self.src_t, cfg.scan_points), self.tree, self.tgt_t, self.u_t,
                                self.R_up, c_src, c_tgt, self.mc)
        t1 = time.perf_counter()
        starts = _distinct_minima(yaws, costs, np.radians(cfg.min_separation_deg), cfg.n_hypotheses)
        hyps = [_refined_start(yaw, self, c_src, c_tgt, cfg.icp_iterations) for yaw in starts]
        top_facing = max(h["facing"] for h in hyps)
        self.scan_ms, self.refine_ms = 1e3 * (t1 - t0), 1e3 * (time.perf_counter() - t1)
        return [h for h in hyps if h["facing"] >= cfg.min_facing_ratio * top_facing]

    def cost(self, R: np.ndarray, t: np.ndarray) -> float:
        return truncated_cost(self.src_t, self.tree, R, t, self.mc)

    def inliers(self, R: np.ndarray, t: np.ndarray) -> tuple[float, float, int]:
        """(fitness, inlier RMSE, inlier count) of the source under ``R p + t``."""
        d = self.tree.query(self.src_t @ R.T + t)[0]
        inl = d < self.mc
        rmse = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else float("inf")
        return float(inl.mean()), rmse, int(inl.sum())


def _inverted(h: dict, fwd: "_Direction") -> dict:
    """A hypothesis of the reverse direction (target onto source) as one of the forward direction."""
    R, t = h["R"].T, -h["R"].T @ h["t"]
    yaw_deg = float(np.degrees(_yaw_about(fwd.u_t, R @ fwd.R_up.T)))
    return {**h, "R": R, "t": t, "R_rev": h["R"], "t_rev": h["t"], "yaw_deg": yaw_deg, "direction": "reverse"}


def _score(h: dict, fwd: _Direction, rev: "_Direction | None") -> float:
    """RMS of the truncated nearest-neighbour distances: of the source's points (one direction), or of both
    clouds' points, each onto the other (``symmetric``)."""
    if rev is None:
        return float(np.sqrt(fwd.cost(h["R"], h["t"])))
    return float(np.sqrt(0.5 * (fwd.cost(h["R"], h["t"]) + rev.cost(h["R"].T, -h["R"].T @ h["t"]))))


def _yaw_scan_costs(yaws: np.ndarray, src_scan: np.ndarray, tree: cKDTree, tgt_t: np.ndarray, u_t: np.ndarray,
                    R_up: np.ndarray, c_src: np.ndarray, c_tgt: np.ndarray, mc: float) -> np.ndarray:
    """The truncated cost (len(yaws),) of the source turned up onto up then by each yaw about the target's up,
    its translation fitted (the yaw scan of :func:`align_upright`)."""
    costs = np.empty(len(yaws))
    for k, yaw in enumerate(yaws):
        R = Rotation.from_rotvec(u_t * yaw).as_matrix() @ R_up
        t = fit_translation(src_scan, tree, tgt_t, R, c_tgt - R @ c_src, mc)
        costs[k] = truncated_cost(src_scan, tree, R, t, mc)
    return costs


def _refined_start(yaw: float, d: _Direction, c_src: np.ndarray, c_tgt: np.ndarray, icp_iterations: int) -> dict:
    """One yaw start of direction ``d`` refined by the 4-DoF point-to-plane ICP, with its scores: inlier RMSE
    and fitness, the share of source normals facing the target's sensor and the yaw."""
    R = Rotation.from_rotvec(d.u_t * yaw).as_matrix() @ d.R_up
    t = fit_translation(d.src_t, d.tree, d.tgt_t, R, c_tgt - R @ c_src, d.mc)
    R, t, JtJ, n_it = point_to_plane_4dof(d.src_t, d.tree, d.tgt_t, d.normals, R, t, d.u_t, d.mc, icp_iterations)
    fitness, rmse, n_inliers = d.inliers(R, t)
    yaw_deg = float(np.degrees(_yaw_about(d.u_t, R @ np.linalg.inv(d.R_up))))
    facing = float(np.mean(np.einsum("ij,ij->i", d.src_n @ R.T, d.vp_t - (d.src_t @ R.T + t)) > 0))
    return {"R": R, "t": t, "JtJ": JtJ, "n_it": n_it, "rmse_m": rmse, "facing": facing, "fitness": fitness,
            "n_inliers": n_inliers, "yaw_deg": yaw_deg, "direction": "forward"}


def _angle_deg(delta_deg: float) -> float:
    """|delta| wrapped to [0, 180]."""
    return abs((delta_deg + 180.0) % 360.0 - 180.0)


def _yaw_about(axis: np.ndarray, R: np.ndarray) -> float:
    """The angle of R about ``axis`` (R is a rotation about it up to the refinement's precision)."""
    rv = Rotation.from_matrix(R).as_rotvec()
    return float(np.dot(rv, axis))


def _distinct_minima(yaws: np.ndarray, costs: np.ndarray, min_sep: float, n_keep: int) -> list[float]:
    """Yaws of the circular profile's local minima, best first, at least ``min_sep`` apart."""
    prev, nxt = np.roll(costs, 1), np.roll(costs, -1)
    order = [k for k in np.argsort(costs, kind="stable") if costs[k] <= prev[k] and costs[k] <= nxt[k]]
    kept: list[float] = []
    for k in order:
        if all(abs((yaws[k] - y + np.pi) % (2 * np.pi) - np.pi) >= min_sep for y in kept):
            kept.append(float(yaws[k]))
        if len(kept) == n_keep:
            break
    return kept or [float(yaws[int(np.argmin(costs))])]


def _covariance(best: dict, u_t: np.ndarray, u_s: np.ndarray, cfg: UprightConfig) -> np.ndarray:
    """6x6 tangent covariance (rotation, translation; left perturbation in the target frame) of ``best``: from the
    information of the direction it was refined in, mapped to the forward answer when that is the reverse one."""
    if best["direction"] == "forward":
        return _direction_covariance(best, u_t, cfg.up_sigma_deg, cfg.min_yaw_sigma_deg, cfg.min_translation_sigma_m)
    C = _direction_covariance(best, u_s, cfg.up_sigma_deg, cfg.min_yaw_sigma_deg, cfg.min_translation_sigma_m)
    J = _inverse_tangent_jacobian(best["R_rev"], best["t_rev"])
    C = J @ C @ J.T
    return 0.5 * (C + C.T)


def _inverse_tangent_jacobian(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Jacobian (6x6, rotation then translation) of the left perturbation of ``inv(T)`` with respect to that of
    ``T = [R, t]``: ``inv(Exp(phi, rho) T) = Exp(phi', rho') inv(T)`` with ``phi' = -R^T phi`` and
    ``rho' = R^T [t]x phi - R^T rho`` to first order (the perturbation ``p -> exp([phi]x) p + rho``)."""
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    J = np.zeros((6, 6))
    J[:3, :3] = -R.T
    J[3:, :3] = R.T @ tx
    J[3:, 3:] = -R.T
    return J


def _direction_covariance(best: dict, u_t: np.ndarray, up_sigma_deg: float, min_yaw_sigma_deg: float,
                          min_translation_sigma_m: float) -> np.ndarray:
    """6x6 tangent covariance (rotation, translation) from the 4-DoF Gauss-Newton information + tilt prior,
    each standard deviation at least its floor (the correlations kept)."""
    JtJ = best["JtJ"]
    sigma2 = max(best["rmse_m"], 1e-6) ** 2 if np.isfinite(best["rmse_m"]) else 1.0
    try:
        C4 = sigma2 * np.linalg.inv(JtJ)
    except np.linalg.LinAlgError:
        C4 = np.diag([np.pi ** 2, 1.0, 1.0, 1.0])
    if not np.all(np.isfinite(C4)):
        C4 = np.diag([np.pi ** 2, 1.0, 1.0, 1.0])
    floors = np.array([np.radians(min_yaw_sigma_deg)] + [min_translation_sigma_m] * 3)
    sd = np.sqrt(np.clip(np.diag(C4), 1e-30, None))
    scale = np.maximum(floors / sd, 1.0)
    C4 = C4 * np.outer(scale, scale)
    C = np.zeros((6, 6))
    tilt = np.eye(3) - np.outer(u_t, u_t)
    C[:3, :3] = np.outer(u_t, u_t) * C4[0, 0] + tilt * np.radians(up_sigma_deg) ** 2
    C[:3, 3:] = np.outer(u_t, C4[0, 1:])
    C[3:, :3] = C[:3, 3:].T
    C[3:, 3:] = C4[1:, 1:]
    return 0.5 * (C + C.T)


def _orthonormal(T: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(T[:3, :3])
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    out = T.copy()
    out[:3, :3] = R
    return out


#: yaw step (degrees) and tilts (degrees, about two horizontal axes) of the gravity-aligned grid search
UPRIGHT_YAW_STEP_DEG = 2.5
UPRIGHT_TILTS_DEG = (-6.0, 0.0, 6.0)


def upright_rotations(up_scanner: Any, up_object: Any, *, caller: str = "upright_rotations") -> np.ndarray:
    """Rotations ``R`` of ``T_object_scanner`` (n, 3, 3) with ``R @ up_scanner`` near ``up_object``: every yaw
    about ``up_object`` at ``UPRIGHT_YAW_STEP_DEG``, each with the tilts of ``UPRIGHT_TILTS_DEG``."""
    u_s, u_o = _unit("up_scanner", up_scanner, caller), _unit("up_object", up_object, caller)
    R0 = rotation_between(u_s, u_o)
    h1 = np.cross(u_o, [1.0, 0.0, 0.0] if abs(u_o[0]) < 0.9 else [0.0, 1.0, 0.0])
    h1 /= np.linalg.norm(h1)
    h2 = np.cross(u_o, h1)
    tilts = [Rotation.from_rotvec(np.radians(a) * h1 + np.radians(b) * h2).as_matrix()
             for a in UPRIGHT_TILTS_DEG for b in UPRIGHT_TILTS_DEG]
    yaws = Rotation.from_rotvec(np.outer(np.radians(np.arange(0.0, 360.0, UPRIGHT_YAW_STEP_DEG)), u_o)).as_matrix()
    return np.ascontiguousarray(np.einsum("tij,yjk,kl->tyil", np.array(tilts), yaws, R0).reshape(-1, 3, 3))
