"""Recognition on simulated laser missions: precision / recall of the pipeline against ground truth, the
clutter false-accept rate, and the leave-one-out accuracy of the built-in database per descriptor and VFH
variant.

Run from the repository root::

    .venv/bin/python benchmarks/recognition.py                       # missions 1-3 + clutter 11-12, LOO
    .venv/bin/python benchmarks/recognition.py --only loo
    .venv/bin/python benchmarks/recognition.py --seeds 1 2 --clutter-seeds 11 --descriptor esf --margin 8

Definitions: a cluster is an object when its majority ground-truth instance is a database object (else
background or clutter). A detection is correct when its label is the cluster's object. Precision =
correct / detections. Recall = object clusters not touching the scan border that are detected correctly
/ all such clusters. Clutter false-accept rate = clutter clusters (worlds with ``n_clutter`` rocks and
pipe offcuts) that are detected / all clutter clusters not touching the border.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def mission_pr(args) -> None:
    from semslam.pipeline import PipelineConfig, ScanRecognizer
    from semslam.simulation.builtin_db import builtin_database
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, WorldConfig, simulate_dataset
    from semslam.simulation.truth import cluster_truth

    db = builtin_database(seed=0)
    cfg = PipelineConfig(estimate_pose=False, descriptor=args.descriptor, reject_margin=args.margin,
                         size_tolerance=None if args.no_size else 1.15, border=args.border)
    rec = ScanRecognizer(db, cfg)
    print(f"\n### Pipeline on 1-loop missions (descriptor {cfg.descriptor}, margin {cfg.reject_margin}, "
          f"size test {'off' if cfg.size_tolerance is None else cfg.size_tolerance}, border {cfg.border})\n")
    print("| mission seed | clutter | scans | object clusters (whole) | detections | precision | recall | "
          "clutter false accepts | ms/scan |")
    print("|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    tot = np.zeros(5)
    for seed, clutter in [(s, False) for s in args.seeds] + [(s, True) for s in args.clutter_seeds]:
        m = simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1),
                                                       world=WorldConfig(clutter=clutter)), seed=seed)
        n_obj = n_det = n_ok = n_rec = n_clut = n_clut_fa = 0
        t = 0.0
        for record in m.scans:
            cloud = m.load_scan(record.scan_id)
            t0 = time.perf_counter()
            r = rec.recognize(cloud, seed=record.scan_id)
            t += time.perf_counter() - t0
            for c in r.clusters:
                truth = cluster_truth(m, cloud, r.segmentation.input_indices(c.cluster_index))
                is_obj = truth.label != "background" and truth.purity >= 0.5
                is_clutter = truth.object_index >= 0 and not m.objects[truth.object_index].in_database
                detected = c.detection is not None
                n_det += detected
                n_ok += detected and c.label == truth.label
                if is_obj and not c.touches_border:
                    n_obj += 1
                    n_rec += detected and c.label == truth.label
                if is_clutter and not c.touches_border:
                    n_clut += 1
                    n_clut_fa += detected
        tot += [n_obj, n_det, n_ok, n_rec, n_clut_fa]
        prec = n_ok / n_det if n_det else float("nan")
        print(f"| {seed} | {'yes' if clutter else 'no'} | {len(m.scans)} | {n_obj} | {n_det} | {100 * prec:.1f}% | "
              f"{100 * n_rec / max(n_obj, 1):.1f}% | {n_clut_fa}/{n_clut} | {1000 * t / max(len(m.scans), 1):.0f} |")
    print(f"| all | | | {int(tot[0])} | {int(tot[1])} | {100 * tot[2] / max(tot[1], 1):.1f}% | "
          f"{100 * tot[3] / max(tot[0], 1):.1f}% | {int(tot[4])} | |")


def loo_table(args) -> None:
    from semslam.recognition import build_database
    from semslam.evaluation.classifier import leave_one_out
    from semslam.simulation.config import KinectConfig
    from semslam.simulation.kinect import SURVEY_KINECT, builtin_view_clouds

    print("\n### Leave-one-out accuracy of the built-in database (8 views per object, chi2 / SVM)\n")
    print("| acquisition | voxel | VFH variant | ESF chi2 | VFH chi2 | ESF+VFH chi2 | ESF SVM | VFH SVM |")
    print("|---|---|---|---:|---:|---:|---:|---:|")
    for name, kinect in (("papers (45 deg, 0.7 m)", KinectConfig()), ("survey (75 deg, 1.5 m)", SURVEY_KINECT)):
        views, classes = builtin_view_clouds(seed=0, config=kinect)
        for leaf in (None, 0.005):
            for variant in ("pcl-1.13", "pcl-1.8", "rusu2010"):
                db = build_database(views, classes, seed=0, voxel_leaf_m=leaf, vfh_variant=variant,
                                    normal_radius_m=0.01 if leaf is None else 0.015)
                acc = [100 * leave_one_out(db, descriptor=d, classifier=c, seed=0).accuracy
                       for d, c in (("esf", "chi2"), ("vfh", "chi2"), ("esf+vfh", "chi2"), ("esf", "svm"), ("vfh", "svm"))]
                print(f"| {name} | {leaf or 'none'} | {variant} | " + " | ".join(f"{a:.2f}%" for a in acc) + " |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--only", action="append", choices=("missions", "loo"))
    p.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3])
    p.add_argument("--clutter-seeds", type=int, nargs="*", default=[11, 12])
    p.add_argument("--descriptor", default="esf+vfh", choices=("esf", "vfh", "esf+vfh"))
    p.add_argument("--margin", type=float, default=6.0)
    p.add_argument("--border", default="reject", choices=("reject", "flag", "keep"))
    p.add_argument("--no-size", action="store_true", help="disable the size plausibility test")
    args = p.parse_args()
    parts = args.only or ["missions", "loo"]
    if "missions" in parts:
        mission_pr(args)
    if "loo" in parts:
        loo_table(args)


if __name__ == "__main__":
    main()
