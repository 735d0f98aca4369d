"""``semslam recognize SCENE --db DB``: segment a scan, recognise every cluster against a view database and
estimate the 6-DoF pose of the recognised objects (the pipeline of :mod:`semslam.pipeline`).

Prints one block per detection (label, matching distance, ``T_scanner_object`` as 4x4 and as xyz + roll
pitch yaw + quat_wxyz, covariance, ICP fitness and RMSE, cluster size, reliable flag), then the clusters
rejected as unknown with their reason, then the time of each stage. ``--json`` prints one document;
``--out FILE.jsonl`` writes one detection per line (atomically).
"""

from __future__ import annotations

import argparse

from ._inputs import parse_direction

from .cmd_segment import add_range_options, parse_length, range_fields


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    parser = subparsers.add_parser(
        "recognize", parents=[common], help="recognise and localise database objects in a scan",
        description="Segment a scan (voxel grid, plane removal, Euclidean clusters), describe every cluster "
                    "(ESF/VFH), match it against a view database with unknown rejection, and estimate the "
                    "6-DoF pose and covariance of each recognised object in the scanner frame.")
    parser.add_argument("scene", metavar="SCENE", help="scan in the scanner frame (.pcd, .ply or .npy, metres)")
    parser.add_argument("--db", required=True, metavar="DB",
                        help="view database file (.npz), or 'builtin' (built-in fittings, cached under "
                             "~/.cache/semslam)")
    parser.add_argument("--descriptor", choices=("esf", "vfh", "esf+vfh"), default=None,
                        help="global descriptor (default: the pipeline's, esf+vfh)")
    parser.add_argument("--classifier", choices=("chi2", "svm"), default=None, help="default chi2")
    parser.add_argument("--seed", type=int, default=0, help="seed of RMSAC, ESF and the coarse alignment (default 0)")
    parser.add_argument("--no-pose", action="store_true", help="recognition only, no pose estimation")
    parser.add_argument("--out", metavar="FILE.jsonl", help="write one detection per line (JSON)")
    parser.add_argument("--overwrite", action="store_true", help="replace the --out file if it exists")
    seg = parser.add_argument_group(
        "segmentation", "the defaults suit a laser at 1-3 m; for a depth camera frame (e.g. RealSense at 30 cm) "
                        "use --max-range 0.5 --voxel auto --cluster-tolerance auto --max-planes 0")
    seg.add_argument("--voxel", default=None, metavar="M|auto",
                     help="voxel grid leaf in metres, 0 for none, 'auto': the scan's measured point spacing "
                          "(default: the pipeline's, 0.005)")
    seg.add_argument("--cluster-tolerance", default=None, metavar="M|auto",
                     help="Euclidean cluster tolerance in metres, 'auto': 4 voxel leaves (default: 0.02)")
    seg.add_argument("--max-planes", type=int, default=None, metavar="K",
                     help="dominant planes removed before clustering (default: 1, the floor)")
    add_range_options(seg)
    parser.add_argument("--border", choices=("reject", "flag", "keep"), default=None,
                        help="clusters at the edge of the scan's field of view: rejected as partial objects "
                             "(default), recognised and flagged, or kept")
    parser.add_argument("--reject-margin", type=float, default=None, metavar="X",
                        help="unknown-object threshold = X times the database's own spread (default: the pipeline's "
                             "6, for laser clusters against Kinect views; 1 when the database holds views from the "
                             "same sensor, e.g. db build --fuse of your camera's scans)")
    parser.add_argument("--up", type=parse_direction, default=None, metavar="X,Y,Z",
                        help="up direction in the scan's frame (0,-1,0 for a level camera, y down): classes whose "
                             "database records their up (db build --fuse --up) are posed upright, no half-turn flips")
    parser.add_argument("--attached", action="store_true",
                        help="find objects attached to structure: in clusters too big for any class (a valve and "
                             "the pipe it is mounted on), remove the pipe (cylinders) and recognise the rest "
                             "(PipelineConfig.attached; an [attached] table in --config sets its fields)")
    parser.add_argument("--config", help="a run configuration file (TOML or JSON: its preset and [pipeline] table, "
                                         "or PipelineConfig fields at the top; docs/configuration.md); the options "
                                         "here override it")
    parser.add_argument("--preset", metavar="NAME", help="named settings to start from: default, cluttered, seabed, "
                                                         "depth-camera (a --config file overrides them)")
    parser.set_defaults(func=run)


def _fmt_detection(i: int, d: dict, outcome: dict) -> list[str]:
    import numpy as np

    T = d["T_sensor_object"]
    xyz, rpy, q = T["xyz_m"], np.degrees(T["rpy_rad"]), T["quat_wxyz"]
    cov = np.asarray(d["covariance_6x6"])
    sig = np.sqrt(np.clip(np.diag(cov), 0, None))
    fit = "n/a" if d["fitness"] is None else f"{d['fitness']:.3f}"
    rmse = "n/a" if d["rmse_m"] is None else f"{1000 * d['rmse_m']:.2f} mm"
    head = (f"[{i}] {d['label']}  distance {d['score']:.4g}  cluster {outcome['n_points']} points  "
            f"reliable {'yes' if d['reliable'] else 'no'}  fitness {fit}  rmse {rmse}")
    pose = (f"    xyz_m [{xyz[0]:.4f}, {xyz[1]:.4f}, {xyz[2]:.4f}]  rpy_deg [{rpy[0]:.2f}, {rpy[1]:.2f}, {rpy[2]:.2f}]"
            f"  quat_wxyz [{', '.join(f'{v:.4f}' for v in q)}]")
    lines = [
        head,
        pose,
        "    T_scanner_object = " + " / ".join("[" + ", ".join(f"{v: .4f}" for v in row) + "]" for row in T["matrix"]),
        "    sigma (x y z m, roll pitch yaw deg) = "
        + ", ".join(f"{v:.4f}" for v in sig[:3])
        + " | "
        + ", ".join(f"{np.degrees(v):.2f}" for v in sig[3:]),
        "    covariance_6x6 = " + " / ".join("[" + ", ".join(f"{v:.3e}" for v in row) + "]" for row in cov),
    ]
    if outcome.get("touches_border"):
        lines.append("    (cluster touches the scan border)")
    return lines


def format_result(payload: dict) -> str:
    """Human-readable text of a ``recognize`` payload."""
    lines = [(f"{payload['scene']}: {payload['n_points']} points, {len(payload['clusters'])} clusters, "
              f"{len(payload['detections'])} detection(s) (db {payload['db']}, {payload['descriptor']}, "
              f"{payload['classifier']})")]
    seg = payload.get("segmentation") or {}
    r = seg.get("resolved") or {}
    if r.get("spacing_m") is not None:
        leaf = "none" if r["voxel_leaf_m"] is None else f"{1000 * r['voxel_leaf_m']:.2f} mm"
        lines.append(f"segmentation: point spacing {1000 * r['spacing_m']:.2f} mm -> voxel {leaf}, cluster "
                     f"tolerance {1000 * r['cluster_tolerance_m']:.2f} mm")
    lines += [f"note: {n}" for n in seg.get("notes", []) + payload.get("notes", [])]
    by_cluster = {c["cluster_index"]: c for c in payload["clusters"]}
    k = 0
    for c in payload["clusters"]:
        if c["detected"]:
            lines += _fmt_detection(k, payload["detections"][k], by_cluster[c["cluster_index"]])
            k += 1
    rejected = [c for c in payload["clusters"] if not c["detected"]]
    if rejected:
        lines.append("rejected as unknown:")
        for c in rejected:
            near = f", nearest {c['nearest_label']} at {c['distance']:.4g}" if c["nearest_label"] else ""
            lines.append(f"  cluster {c['cluster_index']} ({c['n_points']} points{near}): {c['reason']}")
    t = payload["timings_ms"]
    lines.append("timings (ms): " + ", ".join(f"{k} {v:.1f}" for k, v in t.items()))
    return "\n".join(lines)


def _segmentation_table(args: argparse.Namespace, table: object) -> object:
    """The config file's segmentation table with the command-line options laid over it. Points exactly at the
    sensor origin are left out unless --keep-origin-points or the file says ``drop_origin = false``."""
    if not isinstance(table, dict):
        return table  # PipelineConfig.from_dict names the problem
    out = dict(table)
    given = range_fields(args, "recognize")
    if not args.keep_origin_points and "drop_origin" in out:
        given.pop("drop_origin")
    out.update(given)
    if args.voxel is not None:
        out["voxel_leaf_m"] = parse_length("--voxel", args.voxel, "recognize", auto=True, zero_disables=True)
    if args.cluster_tolerance is not None:
        out["cluster_tolerance_m"] = parse_length("--cluster-tolerance", args.cluster_tolerance, "recognize",
                                                  auto=True)
    if args.max_planes is not None:
        if args.max_planes < 0:
            from ..errors import InputError

            raise InputError(f"The '--max-planes' option of semslam recognize must be >= 0. "
                             f"Got {args.max_planes} instead.")
        out["max_planes"] = args.max_planes
    return out


def run(args: argparse.Namespace) -> int:
    import json
    import time

    from .._atomic import atomic_write_text
    from .._outdir import check_output_file, staged_output_file
    from ..io import read_point_cloud
    from ..pipeline import PipelineConfig, ScanRecognizer
    from ..recognition import load_database
    from ._output import emit, to_jsonable

    inputs = (args.scene, args.db, args.config)
    if args.out:  # say so before the work, not after it (semslam._outdir)
        check_output_file(args.out, overwrite=args.overwrite, inputs=inputs)
    raw, up_from_attitude = {}, False
    if args.config or args.preset:  # the one configuration front door (docs/configuration.md), as run and detect
        from ..run.config import load_run_config

        rc = load_run_config(args.config, args.preset)
        raw, up_from_attitude = rc.pipeline_config().to_dict(), rc.run.up_from_attitude
    if args.classifier is not None:
        raw["classifier"] = args.classifier
    if args.no_pose:
        raw["estimate_pose"] = False
    if args.descriptor is not None:
        raw["descriptor"] = args.descriptor
    if args.border is not None:
        raw["border"] = args.border
    if args.up is not None:
        raw["up_scanner"] = list(args.up)
    if args.reject_margin is not None:
        raw["reject_margin"] = args.reject_margin
    if args.attached and raw.get("attached") is None:
        raw["attached"] = {}
    raw["segmentation"] = _segmentation_table(args, raw.get("segmentation", {}))
    config = PipelineConfig.from_dict(
        raw, source=f"the --config file {args.config!r}" if args.config else "one of the options"
    )
    t0 = time.perf_counter()
    if args.db == "builtin":
        from ..simulation.builtin_db import builtin_database  # the simulator (trimesh...) only when asked for

        db = builtin_database(seed=0)
    else:
        db = load_database(args.db)
    t_db = (time.perf_counter() - t0) * 1e3
    notes = []
    if up_from_attitude and config.up_scanner is None:
        notes.append("up_from_attitude (the configuration's [run]) is not used: one scan file has no attitude; give "
                     "the up direction in the scan's frame with --up X,Y,Z")
    if config.up_scanner is not None:
        no_up = [c for c in db.classes if db.up_objects(c) is None]
        if no_up:
            notes.append(
                f"--up is not used for {', '.join(no_up)}: the database records no up direction for "
                f"{'it' if len(no_up) == 1 else 'them'} (a database of models built before 2026-11-28 has none for "
                "a model that rests on either of two faces; for your scans: "
                "'semslam db build VIEWS --fuse --up X,Y,Z'); "
                "their pose search spans all orientations"
            )
    scan = read_point_cloud(args.scene)
    result = ScanRecognizer(db, config, seed=args.seed).recognize(scan, seed=args.seed)
    timings = {"load_db": t_db, **result.timings_ms}
    payload = {"scene": str(args.scene), "db": str(args.db), "n_points": scan.n_points,
               "descriptor": config.descriptor, "classifier": config.classifier,
               "detections": [d.to_dict() for d in result.detections],
               "clusters": [c.to_dict() for c in result.clusters], "timings_ms": timings,
               "segmentation": result.segmentation.to_dict(), "notes": notes}
    if args.out:
        text = "".join(json.dumps(to_jsonable(d)) + "\n" for d in payload["detections"])
        with staged_output_file(args.out, overwrite=args.overwrite, inputs=inputs) as tmp:
            atomic_write_text(tmp, text)
        payload["out"] = str(args.out)
    emit(args, payload, lambda: format_result(payload))
    return 0
