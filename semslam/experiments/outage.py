"""DVL outages: does the filter stay honest when the DVL is out for a long time (or never there)?

:func:`with_dvl_outage` marks a span of a mission's DVL log invalid (no bottom lock); :func:`run_outage_montecarlo`
runs seeded missions of each scenario in each mode and reports, per scenario and mode, the ATE, the ATE of dead
reckoning on the same missions, the position ANEES with its 95 % chi-square band, the fraction of epochs in the
band, and whether the final error is inside the filter's own 3-sigma bound. ``benchmarks/dvl_outage.py`` prints
the table (RESULTS.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .._progress import Progress, progress_steps
from .._validation import check_int
from ..dataset import Dataset, DvlLog
from ..errors import SlamError
from ..simulation.truth_slam import run_truth_slam
from ..slam import MODES, SlamConfig
from ..evaluation.metrics import anees, chi2_band, nees
from .montecarlo import make_dataset

#: scenario -> (start, end) of the outage as fractions of the DVL log's time span
OUTAGE_SCENARIOS = {"none": (0.0, 0.0), "first_half": (0.0, 0.5), "middle": (1 / 3, 2 / 3),
                    "last_third": (2 / 3, 1.0), "whole": (0.0, 1.0)}


def with_dvl_outage(dataset: Dataset, start_fraction: float, end_fraction: float) -> Dataset:
    """``dataset`` with its DVL samples between the two fractions of the log's time span marked invalid."""
    if not 0.0 <= start_fraction <= end_fraction <= 1.0:
        raise SlamError(f"with_dvl_outage needs 0 <= start_fraction <= end_fraction <= 1. Got {start_fraction!r} and "
                        f"{end_fraction!r} instead.")
    d = dataset.dvl
    t = d.stamp_s
    if len(t) == 0 or end_fraction == start_fraction:
        return dataset
    a, b = t[0] + start_fraction * (t[-1] - t[0]), t[0] + end_fraction * (t[-1] - t[0])
    cut = (t >= a) & (t <= b)
    v = d.velocity_body_mps.copy()
    v[cut] = np.nan
    return replace(dataset, dvl=DvlLog(t, v, d.valid & ~cut, d.beam_range_m))


@dataclass(frozen=True)
class OutageRow:
    scenario: str
    mode: str
    ate_mean_m: float
    dr_ate_mean_m: float
    anees_mean: float
    band: tuple
    fraction_in_band: float
    final_error_mean_m: float
    final_3sigma_mean_m: float
    final_inside_3sigma: float  #: fraction of runs whose final error is inside their 3-sigma bound
    worse_than_dr_beyond_sigma: int  #: runs whose ATE exceeds DR's by more than the run's mean 1-sigma
    yaw_bias_from_prior: bool = False  #: the missions carried an AHRS yaw bias drawn from the mode's prior


def run_outage_montecarlo(n_runs: int, *, scenarios=("first_half", "middle", "last_third", "whole"),
                          modes=MODES, seed: int = 1, loops: int = 3,
                          config: SlamConfig | None = None, heading_bias_from_prior: bool = True,
                          progress: Progress = False) -> list[OutageRow]:
    """Run ``n_runs`` missions (seeds ``seed .. seed + n_runs - 1``) of every outage scenario in every mode.

    A consistency test needs the truth drawn from the model the filter assumes. ``pose+heading`` models a constant
    AHRS yaw bias with the prior ``N(0, yaw_bias_sigma_rad^2)``: with ``heading_bias_from_prior`` its missions carry
    a bias drawn from that prior (per run, seeded by the run's seed), and its dead-reckoning reference is run on
    the same biased missions; the other modes model no bias and fly the unbiased missions. Without it, every mode
    flies the unbiased missions (``pose+heading`` is then pessimistic by construction: its prior covers a bias
    that is not there)."""
    n_runs = check_int("n_runs", n_runs, caller="run_outage_montecarlo", minimum=1)
    bad = [s for s in scenarios if s not in OUTAGE_SCENARIOS] + [m for m in modes if m not in MODES]
    if bad:
        raise SlamError(f"run_outage_montecarlo takes scenarios from {sorted(OUTAGE_SCENARIOS)} and modes from "
                        f"{MODES}. Got {bad} instead.")
    cfg = SlamConfig() if config is None else config
    biased = bool(heading_bias_from_prior) and "pose+heading" in modes
    # (mode, mission kind) pairs run per mission: every mode on the unbiased mission, dead reckoning as the
    # reference on each kind, pose+heading on the biased one when asked
    runs = [(m, "biased" if biased and m == "pose+heading" else "plain") for m in dict.fromkeys(("dr", *modes))]
    if biased:
        runs.append(("dr", "biased"))
    rows = []
    with progress_steps(progress, n_runs * len(scenarios) * len(runs), "DVL outages", "run") as step:
        for scen in scenarios:
            per: dict = {key: [] for key in runs}
            for i in range(n_runs):
                missions = {"plain": make_dataset(seed + i, loops=loops)}
                if biased:
                    bias = float(np.random.default_rng(seed + i).normal(0.0, cfg.motion.yaw_bias_sigma_rad))
                    missions["biased"] = make_dataset(seed + i, loops=loops, yaw_bias_rad=bias)
                missions = {k: with_dvl_outage(m, *OUTAGE_SCENARIOS[scen]) for k, m in missions.items()}
                for mode, kind in runs:
                    r = run_truth_slam(missions[kind], mode=mode, config=cfg, seed=seed + i)
                    e = r.position_ned_m - r.truth_position_ned_m
                    sig = np.sqrt(np.trace(r.position_cov_m2, axis1=1, axis2=2))
                    per[mode, kind].append((nees(e, r.position_cov_m2), r.metrics["ate_rmse_m"],
                                            float(np.linalg.norm(e[-1])), 3.0 * float(sig[-1]), float(sig.mean())))
                    step()
            for mode in modes:
                kind = "biased" if biased and mode == "pose+heading" else "plain"
                P = per[mode, kind]
                dr_ate = np.array([p[1] for p in per["dr", kind]])
                K = min(len(p[0]) for p in P)
                a = anees(np.array([p[0][:K] for p in P]), 3)
                ate = np.array([p[1] for p in P])
                fin, s3 = np.array([p[2] for p in P]), np.array([p[3] for p in P])
                rows.append(OutageRow(scen, mode, float(ate.mean()), float(dr_ate.mean()), a["anees_mean"],
                                      chi2_band(3, n_runs), a["fraction_in_band"], float(fin.mean()), float(s3.mean()),
                                      float(np.mean(fin <= s3)),
                                      int(np.sum(ate > dr_ate + np.array([p[4] for p in P]))),
                                      kind == "biased"))
    return rows


def outage_table(rows: list[OutageRow]) -> str:
    """Markdown table of :func:`run_outage_montecarlo`'s rows."""
    out = [
        "| outage | mode | truth yaw bias | ATE (m) | DR ATE (m) | ANEES | 95 % band | epochs in band | final err (m) "
        "| "
        "final 3-sigma (m) | runs final inside 3-sigma | runs worse than DR beyond 1-sigma |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        out.append(
            f"| {r.scenario} | {r.mode} | {'from the prior' if r.yaw_bias_from_prior else 'none'} | "
            f"{r.ate_mean_m:.3f} | {r.dr_ate_mean_m:.3f} | {r.anees_mean:.2f} | "
            f"[{r.band[0]:.2f}, {r.band[1]:.2f}] | {100 * r.fraction_in_band:.0f} % | {r.final_error_mean_m:.3f} | "
            f"{r.final_3sigma_mean_m:.3f} | {100 * r.final_inside_3sigma:.0f} % | {r.worse_than_dr_beyond_sigma} |"
        )
    return "\n".join(out)
