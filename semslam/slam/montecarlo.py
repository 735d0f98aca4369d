"""Seeded Monte-Carlo evaluation: N missions, each run in several modes; ATE and ANEES with chi-square bands.

Missions come from the simulator (``semslam.simulation.simulate_mission(config, seed=..., with_scans=False)``)
when it is available, else from :func:`semslam.slam.synthetic.square_mission`. Run ``i`` uses seed
``seed + i`` for the mission and the truth-based detections, so every mode sees the same missions.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from .._atomic import atomic_write_text
from .._validation import check_int
from ..errors import SlamError
from .metrics import anees, chi2_band, nees
from .runner import MODES, SlamConfig, run_slam


def make_mission(seed: int, *, yaw_bias_rad: float = 0.0, source: str = "auto", loops: int = 3):
    """One mission for Monte-Carlo run ``seed`` (simulator if available, else the synthetic square)."""
    if source in ("auto", "simulator"):
        try:
            from ..simulation import simulate_mission  # type: ignore[attr-defined]
            from ..simulation.config import AhrsConfig, SimulatorConfig, TrajectoryConfig
        except ImportError:
            if source == "simulator":
                raise SlamError("semslam.simulation.simulate_mission is not available.") from None
        else:
            base = SimulatorConfig()
            cfg = base.replace(ahrs=replace(base.ahrs, yaw_bias_rad=float(yaw_bias_rad)),
                               trajectory=replace(base.trajectory, loops=loops))
            return simulate_mission(cfg, seed=seed, with_scans=False)
    from .synthetic import square_mission

    return square_mission(seed=seed, yaw_bias_rad=yaw_bias_rad, loops=loops)


@dataclass(frozen=True, eq=False)
class MonteCarloResult:
    """Per mode: per-run metrics and per-epoch ANEES (position, 3 dof)."""

    n_runs: int
    modes: tuple
    stamps_s: np.ndarray  #: (K,) common epochs (relative to each run's start)
    nees_runs: dict  #: mode -> (N, K)
    sigma3_runs: dict  #: mode -> (N, K) 3-sigma position bound (m)
    error_runs: dict  #: mode -> (N, K) position error (m)
    run_metrics: dict  #: mode -> list of metrics dicts
    summary: dict

    def table(self) -> str:
        """Markdown table of the summary."""
        rows = ["| mode | ATE RMSE mean (m) | ATE max (m) | final err (m) | final 3-sigma (m) | max 3-sigma (m) | ANEES | band | epochs in band |",
                "|---|---|---|---|---|---|---|---|---|"]
        for mode in self.modes:
            s = self.summary[mode]
            rows.append(f"| {mode} | {s['ate_rmse_mean_m']:.4f} | {s['ate_rmse_max_m']:.4f} | {s['final_error_mean_m']:.4f} | "
                        f"{s['final_3sigma_mean_m']:.4f} | {s['max_3sigma_mean_m']:.4f} | {s['anees_mean']:.2f} | "
                        f"[{s['band'][0]:.2f}, {s['band'][1]:.2f}] | {100 * s['fraction_in_band']:.0f} % |")
        return "\n".join(rows)


def run_montecarlo(n_runs: int, *, modes=("dr", "position", "pose"), yaw_bias_deg: float = 0.0, seed: int = 0,
                   source: str = "auto", loops: int = 3, config_overrides: dict | None = None,
                   progress: Callable[[str], None] | None = None) -> MonteCarloResult:
    """Run ``n_runs`` seeded missions in each of ``modes``; see the module docstring."""
    n_runs = check_int("n_runs", n_runs, caller="run_montecarlo", minimum=1)
    modes = tuple(modes)
    for mode in modes:
        if mode not in MODES:
            raise SlamError(f"The 'modes' argument of run_montecarlo must contain only {MODES}. Got {mode!r} instead.")
    nees_r: dict = {m: [] for m in modes}
    sig_r: dict = {m: [] for m in modes}
    err_r: dict = {m: [] for m in modes}
    met: dict = {m: [] for m in modes}
    stamps = None
    for i in range(n_runs):
        mission = make_mission(seed + i, yaw_bias_rad=math.radians(yaw_bias_deg), source=source, loops=loops)
        cfg = SlamConfig.for_mission(mission, **(config_overrides or {}))
        for mode in modes:
            res = run_slam(mission, mode=mode, config=cfg, seed=seed + i)
            if res.truth_position_ned_m is None:
                raise SlamError("Monte-Carlo runs need missions with ground truth.")
            e = res.position_ned_m - res.truth_position_ned_m
            nees_r[mode].append(nees(e, res.position_cov_m2))
            sig_r[mode].append(3.0 * np.sqrt(np.trace(res.position_cov_m2, axis1=1, axis2=2)))
            err_r[mode].append(np.linalg.norm(e, axis=1))
            met[mode].append(res.metrics)
            if stamps is None or len(res.stamps_s) < len(stamps):
                stamps = res.stamps_s - res.stamps_s[0]
            if progress:
                progress(f"run {i + 1}/{n_runs} {mode}: ATE {res.metrics['ate_rmse_m']:.4f} m")
    K = len(stamps)
    summary = {}
    out = {}
    for mode in modes:
        N = np.array([a[:K] for a in nees_r[mode]])
        S3 = np.array([a[:K] for a in sig_r[mode]])
        E = np.array([a[:K] for a in err_r[mode]])
        out[mode] = (N, S3, E)
        a = anees(N, 3)
        ate = np.array([m["ate_rmse_m"] for m in met[mode]])
        summary[mode] = {
            "ate_rmse_mean_m": float(ate.mean()), "ate_rmse_median_m": float(np.median(ate)),
            "ate_rmse_max_m": float(ate.max()),
            "final_error_mean_m": float(E[:, -1].mean()),
            "final_3sigma_mean_m": float(S3[:, -1].mean()), "max_3sigma_mean_m": float(S3.max(axis=1).mean()),
            "anees_mean": a["anees_mean"], "band": list(chi2_band(3, n_runs)), "fraction_in_band": a["fraction_in_band"],
            "n_landmarks_mean": float(np.mean([m["n_landmarks"] for m in met[mode]])),
            "cross_class_updates": int(sum(m["cross_class_updates"] for m in met[mode])),
        }
    return MonteCarloResult(n_runs, modes, stamps, {m: out[m][0] for m in modes}, {m: out[m][1] for m in modes},
                            {m: out[m][2] for m in modes}, met, summary)


def write_montecarlo(result: MonteCarloResult, out_dir: str | Path) -> Path:
    """``summary.json``, ``summary.md`` and per mode ``anees_<mode>.csv`` (epoch, ANEES, mean error, mean 3-sigma)."""
    from ..cli._output import to_jsonable

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "summary.json", json.dumps(to_jsonable({"n_runs": result.n_runs, "summary": result.summary,
                                                                    "runs": result.run_metrics}), indent=2) + "\n")
    atomic_write_text(out / "summary.md", result.table() + "\n")
    for mode in result.modes:
        a = result.nees_runs[mode].mean(axis=0)
        e = result.error_runs[mode].mean(axis=0)
        s = result.sigma3_runs[mode].mean(axis=0)
        lines = ["t_s,anees,mean_error_m,mean_3sigma_m"] + [f"{t:.3f},{x:.6g},{y:.6g},{z:.6g}"
                                                            for t, x, y, z in zip(result.stamps_s, a, e, s)]
        atomic_write_text(out / f"anees_{mode.replace('+', '_')}.csv", "\n".join(lines) + "\n")
    return out
