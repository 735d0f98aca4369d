"""DVL outages (issue 18): is the filter honest when the DVL is out for long, or never there?

``--measure`` first measures the unaided motion (``semslam.evaluation.motion_noise.measure_unaided_motion``: the
velocity random walk and the velocity spread) on the DVL logs of ``--measure-runs`` simulator missions whose
seeds (100..) are not those of the Monte Carlo (1..) and prints it: these are the defaults of
``SlamConfig().motion``. Then the Monte Carlo of the outage scenarios (first half, middle third, last third, the
whole dive) in every mode: ATE, dead reckoning's ATE on the same missions, the position ANEES with its 95 %
band and the fraction of epochs in it, the final error against the filter's 3-sigma. ``pose+heading`` flies
missions whose AHRS yaw bias is drawn from its prior (``--no-heading-bias``: none), the truth its model assumes.

    .venv/bin/python benchmarks/dvl_outage.py --runs 30 --measure
"""

from __future__ import annotations

import argparse
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--measure", action="store_true", help="measure the unaided motion first (prints the defaults)")
    ap.add_argument("--measure-runs", type=int, default=30)
    ap.add_argument("--scenarios", default="first_half,middle,last_third,whole")
    ap.add_argument("--modes", default="dr,position,pose,pose+heading")
    ap.add_argument("--no-heading-bias", action="store_true",
                    help="fly pose+heading on the unbiased missions too (default: a yaw bias drawn from its prior)")
    args = ap.parse_args()

    from semslam.experiments.montecarlo import make_dataset
    from semslam.experiments.outage import outage_table, run_outage_montecarlo
    from semslam.evaluation.motion_noise import measure_unaided_motion

    if args.measure:
        missions = [make_dataset(100 + i) for i in range(args.measure_runs)]
        d = missions[0].vehicle.dvl
        m = measure_unaided_motion([x.dvl for x in missions], noise_sigma_mps=d.noise_abs_mps + d.noise_rel * 0.3)
        print(f"measured on {args.measure_runs} missions (seeds 100..): unaided velocity random walk "
              f"{m.velocity_rw_mps_per_sqrt_s} m/s/sqrt(s), velocity rms {m.velocity_rms_mps} m/s "
              f"({m.n_increments} increments, lags {m.lags_s} s)\n")
    t = time.perf_counter()
    rows = run_outage_montecarlo(args.runs, scenarios=tuple(args.scenarios.split(",")),
                                 modes=tuple(args.modes.split(",")), seed=args.seed,
                                 heading_bias_from_prior=not args.no_heading_bias, progress=True)
    print(outage_table(rows))
    print(f"\n{args.runs} runs per scenario, {time.perf_counter() - t:.0f} s")


if __name__ == "__main__":
    main()
