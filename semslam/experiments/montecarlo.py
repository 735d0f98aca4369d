"""Seeded Monte-Carlo evaluation: N missions, each run in several modes; ATE and ANEES with chi-square bands.

Missions come from the simulator (``semslam.simulation.simulate_dataset(config, seed=..., with_scans=False)``)
when it is available, else from :func:`semslam.simulation.synthetic.square_dataset`. Run ``i`` uses seed
``seed + i`` for the mission and the truth-based detections, so every mode sees the same missions.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Callable

import numpy as np

from .._progress import Progress, progress_steps
from .._atomic import atomic_write_text
from .._validation import check_int
from ..errors import SlamError
from ..simulation.truth_slam import run_truth_slam
from ..slam import MODES, SlamConfig
from ..evaluation.metrics import anees, chi2_band, nees
from ..modes import BACKENDS


def make_dataset(seed: int, *, yaw_bias_rad: float = 0.0, source: str = "auto", loops: int = 3,
                 yaw_bias_walk_rad_per_sqrt_s: float = 0.0, white_dvl: bool = False):
    """One mission for Monte-Carlo run ``seed`` (simulator if available, else the synthetic square).

    ``white_dvl``: the simulator's DVL without its systematic errors (scale, misalignment, biases)."""
    if source not in ("auto", "simulator", "synthetic"):
        raise SlamError(f"The 'source' argument of make_dataset must be 'auto', 'simulator' or 'synthetic'. "
                        f"Got {source!r} instead.")
    if source in ("auto", "simulator"):
        from ..simulation import simulate_dataset
        from ..simulation.config import DvlConfig, SimulatorConfig

        base = SimulatorConfig()
        cfg = base.replace(ahrs=replace(base.ahrs, yaw_bias_rad=float(yaw_bias_rad),
                                        yaw_bias_walk_rad_per_sqrt_s=float(yaw_bias_walk_rad_per_sqrt_s)),
                           trajectory=replace(base.trajectory, loops=loops))
        if white_dvl:
            cfg = cfg.replace(dvl=DvlConfig.white())
        return simulate_dataset(cfg, seed=seed, with_scans=False)
    from ..simulation.synthetic import square_dataset

    return square_dataset(seed=seed, yaw_bias_rad=yaw_bias_rad, loops=loops)


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
    #: mode -> (N, K) error of the trajectory as held at the end of the dive (EKF: its RTS smoother; isam2 / batch:
    #: the graph's final estimate), or None when the runs have none
    end_error_runs: dict = field(default_factory=dict)
    backend: str = "ekf"
    settings: dict = field(default_factory=dict)  #: what defines the missions (seed, yaw bias, loops, overrides ...)

    def table(self) -> str:
        """Markdown table of the summary."""
        rows = [("| mode | ATE mean (m) | ATE max (m) | DR/mode ATE | final err (m) | 3-sigma at 1/3, 2/3, end (m) | "
                 "ANEES | band | epochs in band | landmark ANEES pos (band) | landmark ANEES pose (band) | "
                 "smoothed ATE mean (m) | smoothed DR/mode | smoothed epochs in band |"),
                "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]

        def lm(s, key):
            v = s[key]
            return "-" if v["n"] == 0 else f"{v['anees']:.2f} ([{v['band'][0]:.2f}, {v['band'][1]:.2f}], n={v['n']})"

        for mode in self.modes:
            s = self.summary[mode]
            ratio = s.get("dr_over_mode_ate")
            s3 = ", ".join(f"{x:.3f}" for x in s["sigma3_at_thirds_mean_m"])
            rows.append(f"| {mode} | {s['ate_rmse_mean_m']:.4f} | {s['ate_rmse_max_m']:.4f} | "
                        f"{'-' if ratio is None else f'{ratio:.2f}'} | {s['final_error_mean_m']:.4f} | {s3} | "
                        f"{s['anees_mean']:.2f} | [{s['band'][0]:.2f}, {s['band'][1]:.2f}] | "
                        f"{100 * s['fraction_in_band']:.0f} % | {lm(s, 'landmark_nees_position')} | "
                        f"{lm(s, 'landmark_nees_pose')} | {_smoothed_cells(s)} |")
        pairs = [(a, b, v) for a in self.modes for b, v in self.summary[a].get("paired", {}).items()]
        if pairs:
            rows += [
                "",
                (
                    "| paired, same missions | ATE difference mean +- s.e. (m) | runs not worse | "
                    "smoothed: difference mean +- s.e. (m) | smoothed: runs not worse |"
                ),
                "|---|---|---|---|---|",
            ]
            for a, b, v in pairs:
                sm = v.get("smoothed")
                rows.append(f"| {a} - {b} | {v['ate_diff_mean_m']:+.5f} +- {v['ate_diff_se_m']:.5f} | "
                            f"{100 * v['fraction_not_worse']:.0f} % | "
                            + (f"{sm['ate_diff_mean_m']:+.5f} +- {sm['ate_diff_se_m']:.5f} | "
                               f"{100 * sm['fraction_not_worse']:.0f} % |" if sm else "- | - |"))
        return "\n".join(rows)


def truth_run(mission, mode: str, config: SlamConfig, seed: int, backend: str = "ekf", surveyed=()):
    """:func:`run_truth_slam` on ``backend`` (``ekf``, ``isam2``, ``batch``): the same truth-based detections and
    seeds for every backend; ``surveyed``: objects given to the run as a (simulated) survey."""
    return run_truth_slam(mission, mode=mode, config=config, seed=seed, backend=backend, surveyed=surveyed)


def _montecarlo_run(i: int, *, opts: dict) -> dict:
    """Run ``i`` of :func:`run_montecarlo` (one mission, every mode): per mode the per-epoch NEES (online, smoothed),
    3-sigma bound, error, relative stamps and the metrics. A Dask task: small arguments, small result."""
    seed = opts["seed"] + i
    mission = make_dataset(
        seed,
        yaw_bias_rad=opts["yaw_bias_rad"],
        source=opts["source"],
        loops=opts["loops"],
        yaw_bias_walk_rad_per_sqrt_s=opts["yaw_bias_walk_rad_per_sqrt_s"],
        white_dvl=opts["white_dvl"],
    )
    cfg = SlamConfig().updated(**opts["config_overrides"])
    out = {}
    for mode in opts["modes"]:
        res = truth_run(mission, mode, cfg, seed, opts.get("backend", "ekf"), opts.get("surveyed", ()))
        if res.truth_position_ned_m is None:
            raise SlamError("Monte-Carlo runs need missions with ground truth.")
        e = res.position_ned_m - res.truth_position_ned_m
        smoothed = None if res.smoothed_position_ned_m is None else nees(
            res.smoothed_position_ned_m - res.truth_position_ned_m, res.smoothed_position_cov_m2)
        end = None if res.smoothed_position_ned_m is None else np.linalg.norm(
            res.smoothed_position_ned_m - res.truth_position_ned_m, axis=1)
        out[mode] = {"nees": nees(e, res.position_cov_m2), "nees_smoothed": smoothed, "error_end": end,
                     "sigma3": 3.0 * np.sqrt(np.trace(res.position_cov_m2, axis1=1, axis2=2)),
                     "error": np.linalg.norm(e, axis=1), "metrics": res.metrics,
                     "stamps_s": res.stamps_s - res.stamps_s[0]}
    return out


def run_montecarlo(n_runs: int, *, modes=("dr", "position", "pose"), yaw_bias_deg: float = 0.0, seed: int = 0,
                   source: str = "auto", loops: int = 3, config_overrides: dict | None = None,
                   progress: Progress = False, log: Callable[[str], None] | None = None,
                   yaw_bias_walk_deg_per_sqrt_s: float = 0.0,
                   white_dvl: bool = False, jobs: int = 1, scheduler: str | None = None,
                   client=None, backend: str = "ekf", surveyed=()) -> MonteCarloResult:
    """Run ``n_runs`` seeded missions in each of ``modes``; see the module docstring.

    ``yaw_bias_deg`` / ``yaw_bias_walk_deg_per_sqrt_s``: AHRS yaw bias of the missions (constant, random walk);
    ``config_overrides``: SlamConfig settings (e.g. ``{"initial_position_sigma_m": 0.01}``); ``surveyed``: names of
    objects given to every run as a survey (drawn around their true poses, as a surveyor's, seeded per run);
    ``progress``: a bar or ``progress(done, total)`` per run and mode (:mod:`semslam._progress`); ``log``: one line
    per run and mode (its ATE). ``jobs`` / ``scheduler`` / ``client``: the engine (serial in this process, a local Dask
    cluster of ``jobs`` processes, a running cluster; :func:`semslam.batch.engine.map_tasks`): same result.
    ``backend``: the estimator (``ekf``; ``isam2`` or ``batch``: the GTSAM factor graph, whose smoothed trajectory
    is its whole-dive estimate), with the same missions and detections for every backend; the result's
    ``end_error_runs`` holds the error of that whole-dive estimate (the EKF's: its RTS smoother) per run and epoch.
    Summary per mode: ATE (mean, median, max), DR/mode ATE ratio, final error, mean 3-sigma at 1/3, 2/3 and
    the end of the mission, position ANEES with its band and the fraction of epochs in it, and the landmark
    ANEES (position 3 dof; pose 6 dof for classes without a continuous symmetry) over all runs' final maps.
    """
    n_runs = check_int("n_runs", n_runs, caller="run_montecarlo", minimum=1)
    modes = _checked_modes(modes, backend)
    opts = {"seed": seed, "modes": modes, "yaw_bias_rad": math.radians(yaw_bias_deg), "source": source, "loops": loops,
            "yaw_bias_walk_rad_per_sqrt_s": math.radians(yaw_bias_walk_deg_per_sqrt_s), "white_dvl": white_dvl,
            "config_overrides": dict(config_overrides or {}), "backend": backend, "surveyed": tuple(surveyed)}
    runs = _run_all(n_runs, modes, opts, progress=progress, log=log, jobs=jobs, scheduler=scheduler, client=client)
    nees_r, nees_s, sig_r, err_r, end_r, met, stamps = _collect(runs, modes)
    K = len(stamps)
    summary = {}
    out = {}
    for mode in modes:
        N = np.array([a[:K] for a in nees_r[mode]])
        S3 = np.array([a[:K] for a in sig_r[mode]])
        E = np.array([a[:K] for a in err_r[mode]])
        out[mode] = (N, S3, E)
        summary[mode] = _mode_summary(N, S3, E, met[mode], nees_s[mode], n_runs, K)
    _paired(summary, met, modes)
    _dr_ratios(summary, modes)
    ends = {m: np.array([a[:K] for a in end_r[m]]) if len(end_r[m]) == n_runs else None for m in modes}
    settings = {k: v for k, v in opts.items() if k not in ("modes", "backend")}
    return MonteCarloResult(n_runs, modes, stamps, {m: out[m][0] for m in modes}, {m: out[m][1] for m in modes},
                            {m: out[m][2] for m in modes}, met, summary, ends, backend, settings)


def _checked_modes(modes, backend: str) -> tuple:
    if isinstance(modes, str) or not len(tuple(modes)):
        raise SlamError(f"The 'modes' argument of run_montecarlo must be a non-empty sequence of modes from {MODES}. "
                        f"Got {modes!r} instead.")
    modes = tuple(modes)
    for mode in modes:
        if mode not in MODES:
            raise SlamError(f"The 'modes' argument of run_montecarlo must contain only {MODES}. Got {mode!r} instead.")
    if backend not in BACKENDS:
        raise SlamError(f"The 'backend' argument of run_montecarlo must be one of {BACKENDS}. "
                        f"Got {backend!r} instead.")
    return modes


def _run_all(n_runs: int, modes: tuple, opts: dict, *, progress, log, jobs, scheduler, client) -> list:
    """Every run's outcome, in run order, on the chosen engine (progress and log lines as each run ends)."""
    with progress_steps(progress, n_runs * len(modes), "Monte Carlo", "run") as step:
        def done(i: int, run: dict) -> None:  # as each run ends (in any order on a cluster)
            for mode in modes:
                step()
                if log is not None:
                    log(f"run {i + 1}/{n_runs} {mode}: ATE {run[mode]['metrics']['ate_rmse_m']:.4f} m")

        from ..batch.engine import map_tasks

        return map_tasks(partial(_montecarlo_run, opts=opts), range(n_runs), jobs=jobs, scheduler=scheduler,
                         client=client, on_result=done)


def _collect(runs: list, modes: tuple):
    """Per mode, the runs' NEES, smoothed NEES, 3-sigma, error and whole-dive error series and metrics; the
    shortest run's stamps."""
    nees_r: dict = {m: [] for m in modes}
    nees_s: dict = {m: [] for m in modes}
    sig_r: dict = {m: [] for m in modes}
    err_r: dict = {m: [] for m in modes}
    end_r: dict = {m: [] for m in modes}
    met: dict = {m: [] for m in modes}
    stamps = None
    for run in runs:  # in run order, whatever the engine: the summary does not depend on it
        for mode in modes:
            r = run[mode]
            nees_r[mode].append(r["nees"])
            if r["nees_smoothed"] is not None:
                nees_s[mode].append(r["nees_smoothed"])
            sig_r[mode].append(r["sigma3"])
            err_r[mode].append(r["error"])
            if r.get("error_end") is not None:
                end_r[mode].append(r["error_end"])
            met[mode].append(r["metrics"])
            if stamps is None or len(r["stamps_s"]) < len(stamps):
                stamps = r["stamps_s"]
    return nees_r, nees_s, sig_r, err_r, end_r, met, stamps


def _mode_summary(N: np.ndarray, S3: np.ndarray, E: np.ndarray, met: list, nees_s: list, n_runs: int, K: int) -> dict:
    """One mode's summary over the runs (see :func:`run_montecarlo`)."""
    a = anees(N, 3)
    ate = np.array([m["ate_rmse_m"] for m in met])
    summary = {
        "ate_rmse_mean_m": float(ate.mean()),
        "ate_rmse_median_m": float(np.median(ate)),
        "ate_rmse_max_m": float(ate.max()),
        "final_error_mean_m": float(E[:, -1].mean()),
        "final_3sigma_mean_m": float(S3[:, -1].mean()),
        "max_3sigma_mean_m": float(S3.max(axis=1).mean()),
        "anees_mean": a["anees_mean"],
        "band": list(chi2_band(3, n_runs)),
        "fraction_in_band": a["fraction_in_band"],
        "n_landmarks_mean": float(np.mean([m["n_landmarks"] for m in met])),
        "cross_class_updates": int(sum(m["cross_class_updates"] for m in met)),
        "sigma3_at_thirds_mean_m": [
            float(S3[:, min(K - 1, int(round(f * (K - 1))))].mean()) for f in (1 / 3, 2 / 3, 1.0)
        ],
        "landmark_nees_position": _landmark_anees([m.get("landmark_nees_position", []) for m in met], 3),
        "landmark_nees_pose": _landmark_anees([m.get("landmark_nees_pose", []) for m in met], 6),
        "dvl_rejected_mean": float(np.mean([m.get("dvl_rejected", 0) for m in met])),
    }
    smoothed = [m.get("smoother", {}).get("ate_rmse_m") for m in met]
    if nees_s and len(nees_s) == n_runs and all(v is not None for v in smoothed):
        a_s = anees(np.array([v[:K] for v in nees_s]), 3)
        summary["smoothed"] = {"ate_rmse_mean_m": float(np.mean(smoothed)), "ate_rmse_max_m": float(np.max(smoothed)),
                               "anees_mean": a_s["anees_mean"], "fraction_in_band": a_s["fraction_in_band"]}
    return summary


def _dr_ratios(summary: dict, modes: tuple) -> None:
    """Each mode's DR/mode ATE ratio (filtered, and smoothed when both have one), when DR ran."""
    if "dr" in summary:
        for mode in modes:
            summary[mode]["dr_over_mode_ate"] = summary["dr"]["ate_rmse_mean_m"] / max(
                summary[mode]["ate_rmse_mean_m"], 1e-12
            )
            if "smoothed" in summary[mode] and "smoothed" in summary["dr"]:
                summary[mode]["smoothed"]["dr_over_mode_ate"] = summary["dr"]["smoothed"]["ate_rmse_mean_m"] / max(
                    summary[mode]["smoothed"]["ate_rmse_mean_m"], 1e-12
                )


#: mode -> the mode it is meant to improve on (paired comparison on the same missions)
_BASELINE = {"position": "dr", "pose": "position", "pose+heading": "pose"}


def _paired(summary: dict, met: dict, modes: tuple) -> None:
    """``summary[mode]["paired"][baseline]``: per-run ATE differences ``mode - baseline`` on the same missions
    (mean, standard error of the mean, fraction of runs with ``mode <= baseline``), online and smoothed. A mean
    difference within two standard errors of 0 is a tie that more runs would be needed to break."""
    for mode in modes:
        base = _BASELINE.get(mode)
        if base not in modes:
            continue
        entry = {}
        for key, get in (("online", lambda m: m["ate_rmse_m"]),
                         ("smoothed", lambda m: (m.get("smoother") or {}).get("ate_rmse_m"))):
            a = [get(m) for m in met[mode]]
            b = [get(m) for m in met[base]]
            if any(v is None for v in a + b):
                continue
            d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
            se = float(d.std(ddof=1) / math.sqrt(len(d))) if len(d) > 1 else float("nan")
            entry[key] = {"ate_diff_mean_m": float(d.mean()), "ate_diff_se_m": se,
                          "fraction_not_worse": float(np.mean(d <= 0.0))}
        if "online" in entry:
            summary[mode]["paired"] = {base: {**entry["online"], **({"smoothed": entry["smoothed"]}
                                                                    if "smoothed" in entry else {})}}


def _smoothed_cells(s: dict) -> str:
    sm = s.get("smoothed")
    if not sm:
        return "- | - | -"
    r = sm.get("dr_over_mode_ate")
    return f"{sm['ate_rmse_mean_m']:.4f} | {'-' if r is None else f'{r:.2f}'} | {100 * sm['fraction_in_band']:.0f} %"


def _landmark_anees(per_run: list, dof: int) -> dict:
    """Mean of all landmarks' final NEES over the runs, its chi-square band and the fraction of landmarks whose
    NEES is inside the two-sided 95 % chi-square(dof) interval."""
    v = np.array([x for run in per_run for x in run], dtype=float)
    if len(v) == 0:
        return {"n": 0, "anees": None, "band": None, "fraction_in_95": None}
    from scipy.stats import chi2

    lo, hi = chi2.ppf(0.025, dof), chi2.ppf(0.975, dof)
    return {"n": int(len(v)), "anees": float(v.mean()), "band": list(chi2_band(dof, len(v))),
            "fraction_in_95": float(np.mean((v >= lo) & (v <= hi)))}


def write_montecarlo(result: MonteCarloResult, out_dir: str | Path, *, report: bool = True) -> Path:
    """``summary.json``, ``summary.md``, per mode ``anees_<mode>.csv`` (epoch, ANEES, mean error, mean 3-sigma) and
    ``error_over_time_<mode>.csv`` (+ ``.json``: the mean position error over time of the current-time and of the
    end-of-dive estimates, :mod:`semslam.report.backends`), and ``report.html`` (``report``; figures embedded).
    Monte Carlos of several backends written to sibling directories are compared in one report by
    ``semslam report PARENT``."""
    from .._jsonable import to_jsonable
    from ..report.backends import build_backends_report, write_montecarlo_curves

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "summary.json", json.dumps(to_jsonable({"n_runs": result.n_runs, "backend": result.backend,
                                                                    "settings": result.settings,
                                                                    "summary": result.summary,
                                                                    "runs": result.run_metrics}), indent=2) + "\n")
    atomic_write_text(out / "summary.md", result.table() + "\n")
    for mode in result.modes:
        a = result.nees_runs[mode].mean(axis=0)
        e = result.error_runs[mode].mean(axis=0)
        s = result.sigma3_runs[mode].mean(axis=0)
        lines = ["t_s,anees,mean_error_m,mean_3sigma_m"] + [f"{t:.3f},{x:.6g},{y:.6g},{z:.6g}"
                                                            for t, x, y, z in zip(result.stamps_s, a, e, s)]
        atomic_write_text(out / f"anees_{mode.replace('+', '_')}.csv", "\n".join(lines) + "\n")
    write_montecarlo_curves(result, out)
    if report:
        build_backends_report(out)
    return out
