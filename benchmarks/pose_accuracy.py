"""Object pose accuracy on the simulator's own laser scans (issue 4 "Done when").

Clusters = the ground-truth instance points of each fitting in each scan of one-loop missions (voxel
5 mm, as the pipeline), truth at the cluster's median line stamp (see semslam/registration/_pose_eval.py).
Models:

* ``pipeline``: what ``ScanRecognizer`` aligns to with the built-in database (``builtin_database(seed=0)``):
  its pose-model views (8 per class, :data:`~semslam.simulation.kinect.POSE_MODEL_KINECT`: 60 deg, 0.7 m) fused;
* ``survey``: the built-in database's recognition views (8 per class, SURVEY_KINECT: 75 deg, 1.5 m) fused
  (the pipeline's model before the database stored pose-model views);
* ``fused``: the 8 views of ``builtin_view_clouds(seed=0)`` (default KinectConfig: 45 deg, 0.7 m) fused;
* ``view``: the single matched view of those (oracle match: the view whose camera direction, in the
  object frame, is closest to the scanner's; recognition picks it by descriptor in the pipeline).

Per class and overall: n, median rotation error (modulo symmetry) and translation error, success rate
(< 10 deg and < 1 cm), mean / median NEES of the successful poses (6-dof; for the socket the rotation
about its axis is compared with the closest equivalent truth and carries 1e4 rad^2), wrong poses, how
many of them are flagged unreliable, correct poses flagged, median CPU ms per object.

    .venv/bin/python benchmarks/pose_accuracy.py [--seeds 0 1 2] [--altitudes 1.0 1.5] [--models pipeline survey fused view]
                                                 [--method grid ransac] [--set NAME=VALUE ...]
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main() -> None:
    from semslam.simulation.builtin_db import builtin_database
    from semslam.pose import PoseConfig, prepare_pose_model
    from semslam.experiments.pose_eval import evaluate, simulated_clusters, summary_table
    from semslam.simulation import builtin_view_clouds

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--altitudes", type=float, nargs="+", default=[1.0, 1.5])
    ap.add_argument("--models", nargs="+", default=["pipeline", "survey", "view"],
                    choices=["pipeline", "survey", "fused", "view"])
    ap.add_argument("--method", nargs="+", default=["grid"], choices=["grid", "ransac"])
    ap.add_argument("--set", nargs="*", default=[], metavar="NAME=VALUE",
                    help="PoseConfig overrides, e.g. --set n_coarse_rotations=0 icp_backend=small_gicp")
    args = ap.parse_args()
    overrides = {}
    for item in args.set:
        name, _, value = item.partition("=")
        default = getattr(PoseConfig(), name)
        overrides[name] = (value if isinstance(default, str) else
                           tuple(float(v) for v in value.split(",") if v) if isinstance(default, tuple) else
                           type(default)(value))

    t0 = time.perf_counter()
    clusters = simulated_clusters(args.seeds, altitudes_m=args.altitudes)
    print(f"{len(clusters)} clusters from seeds {args.seeds} at altitudes {args.altitudes} m "
          f"({time.perf_counter() - t0:.0f} s to simulate)\n")
    views, classes = builtin_view_clouds(seed=0)
    for method in args.method:
        cfg = PoseConfig(coarse_method=method, **overrides)
        for kind in args.models:
            if kind in ("pipeline", "survey"):
                db = builtin_database(seed=0)
                models = {lab: prepare_pose_model(db.pose_views(lab) if kind == "pipeline" else
                                                  [db.view_cloud(int(i)) for i in db.views_of(lab)], cfg)
                          for lab in db.classes}
                rows = evaluate(clusters, models)
            elif kind == "fused":
                models = {lab: prepare_pose_model([v for lb, _, v in views if lb == lab], cfg) for lab in classes}
                rows = evaluate(clusters, models)
            else:
                per_view = [(lab, v, prepare_pose_model(v, cfg)) for lab, _, v in views]
                rows = []
                for i, c in enumerate(clusters):
                    # oracle match: camera direction closest to the scanner direction (object frame)
                    T_os = np.linalg.inv(c.T_scanner_object)
                    d = T_os[:3, 3] / np.linalg.norm(T_os[:3, 3])
                    cands = [(float(d @ v.viewpoint_xyz_m / np.linalg.norm(v.viewpoint_xyz_m)), m)
                             for lab, v, m in per_view if lab == c.label]
                    model = max(cands, key=lambda x: x[0])[1]
                    rows += evaluate([c], {c.label: model}, seed=i)
            print(summary_table(rows, f"method={method}, model={kind}" + (f", {overrides}" if overrides else "")))
            print()


if __name__ == "__main__":
    main()
