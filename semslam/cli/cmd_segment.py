"""``semslam segment SCENE``: voxel grid, dominant plane removal (RMSAC) and Euclidean clustering of a
scan; prints the planes, the cluster sizes (largest first) and the time of each stage, and with
``--out DIR`` writes each cluster as ``cluster_NNN.pcd`` plus ``segmentation.json``."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    parser = subparsers.add_parser(
        "segment",
        parents=[common],
        help="split a scan into object clusters (voxel grid, RMSAC plane removal, Euclidean clusters)",
        description="Segment a point-cloud scene as the seed papers do: optional voxel grid, removal of the "
        "dominant plane(s) found by RMSAC, Euclidean clustering of the remaining points. Prints the plane "
        "coefficients (a, b, c, d: unit normal, d >= 0) and inlier counts, the cluster sizes largest first "
        "and the time of each stage.",
    )
    parser.add_argument("scene", metavar="SCENE", help="a .pcd, .ply or .npy file (metres)")
    parser.add_argument(
        "--voxel",
        default="0.005",
        metavar="M|auto",
        help="voxel grid leaf size in metres, 0 to disable, 'auto': the measured point spacing (default: 0.005)",
    )
    parser.add_argument(
        "--distance-threshold",
        type=float,
        default=0.01,
        metavar="M",
        help="plane inlier distance in metres (default: 0.01)",
    )
    parser.add_argument(
        "--max-planes",
        type=int,
        default=1,
        metavar="K",
        help="remove up to K dominant planes (default: 1)",
    )
    parser.add_argument(
        "--min-plane-inliers",
        type=int,
        default=None,
        metavar="N",
        help="smallest plane removed after the first (default: 5%% of the points)",
    )
    parser.add_argument(
        "--cluster-tolerance",
        default="0.02",
        metavar="M|auto",
        help="Euclidean cluster tolerance in metres, 'auto': 4 voxel leaves (default: 0.02)",
    )
    add_range_options(parser)
    parser.add_argument(
        "--min-cluster-size",
        type=int,
        default=50,
        metavar="N",
        help="smallest cluster kept, in points (default: 50)",
    )
    parser.add_argument(
        "--max-cluster-size",
        type=int,
        default=25000,
        metavar="N",
        help="largest cluster kept, in points, 0 for no limit (default: 25000)",
    )
    parser.add_argument(
        "--seed", type=int, default=0, metavar="S", help="seed of the plane fitting (default: 0)"
    )
    parser.add_argument(
        "--out",
        metavar="DIR",
        default=None,
        help="write cluster_NNN.pcd (largest first) and segmentation.json into DIR (new, or an earlier "
             "segmentation with --overwrite: never mixed with its stale clusters)",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an earlier semslam output in --out")
    parser.set_defaults(func=run)


def add_range_options(parser: argparse.ArgumentParser) -> None:
    """``--max-range``, ``--min-range`` and ``--keep-origin-points`` (shared with ``semslam recognize``)."""
    parser.add_argument("--max-range", default=None, metavar="M",
                        help="leave out points farther than M metres from the sensor (default: no limit; "
                             "e.g. 0.5 for a depth camera 30 cm from the object)")
    parser.add_argument("--min-range", default=None, metavar="M",
                        help="leave out points nearer than M metres to the sensor (default: 0)")
    parser.add_argument("--keep-origin-points", action="store_true",
                        help="keep points exactly at the sensor origin (by default they are left out: a depth "
                             "camera stores its invalid pixels there, and no real return lies there)")


def parse_length(option: str, value: str | None, command: str, *, auto: bool = False,
                 zero_disables: bool = False, check: bool = True) -> float | str | None:
    """The value of a length option: a finite number > 0 (metres), ``"auto"`` when ``auto``, 0 -> None when
    ``zero_disables``; anything else raises :class:`~semslam.errors.InputError` naming the option (with
    ``check=False`` any number is passed on, for the config's own check to name its field)."""
    from ..errors import InputError

    if value is None:
        return None
    if auto and value == "auto":
        return "auto"
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if zero_disables and v == 0:
        return None
    if not check and v == v:
        return v
    if not (v > 0 and v < float("inf")):
        expected = "a finite length > 0 in metres" + (" (0 disables)" if zero_disables else "") + \
            (" or 'auto'" if auto else "")
        raise InputError(f"The '{option}' option of semslam {command} must be {expected}. Got {value!r} instead.")
    return v


def range_fields(args: argparse.Namespace, command: str) -> dict:
    """SegmentationConfig fields of :func:`add_range_options` (only those given, plus ``drop_origin``)."""
    out: dict = {"drop_origin": not args.keep_origin_points}
    hi = parse_length("--max-range", args.max_range, command)
    lo = parse_length("--min-range", args.min_range, command)
    if hi is not None:
        out["max_range_m"] = hi
    if lo is not None:
        out["min_range_m"] = lo
    return out


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from .._atomic import atomic_write_text
    from ..errors import InputError
    from ..io import read_point_cloud, write_point_cloud
    from ..segmentation import SegmentationConfig, segment_scene
    from ._output import emit, to_jsonable

    voxel = parse_length("--voxel", args.voxel, "segment", auto=True, zero_disables=True)
    tolerance = parse_length("--cluster-tolerance", args.cluster_tolerance, "segment", auto=True, check=False)
    if args.max_cluster_size < 0:
        raise InputError(
            "The '--max-cluster-size' option of semslam segment must be >= 0 (0: no limit). "
            f"Got {args.max_cluster_size} instead."
        )
    if args.seed < 0:
        raise InputError(
            f"The '--seed' option of semslam segment must be >= 0. Got {args.seed} instead."
        )
    config = SegmentationConfig(
        voxel_leaf_m=voxel,
        distance_threshold_m=args.distance_threshold,
        max_planes=args.max_planes,
        min_plane_inliers=args.min_plane_inliers,
        cluster_tolerance_m=tolerance,
        min_cluster_size=args.min_cluster_size,
        max_cluster_size=args.max_cluster_size or None,
        **range_fields(args, "segment"),
    )
    if args.out:  # before the work (semslam._outdir)
        from .._outdir import check_output_dir

        check_output_dir(args.out, overwrite=args.overwrite, kind="segmentation", inputs=(args.scene,))
    cloud = read_point_cloud(args.scene)
    result = segment_scene(cloud, config, seed=args.seed)
    payload = {
        "scene": str(args.scene),
        "seed": args.seed,
        "config": config.to_dict(),
        **result.to_dict(),
    }
    if args.out:
        from .._outdir import staged_output_dir

        final = Path(args.out)
        payload["files"] = [str(final / f"cluster_{i:03d}.pcd") for i in range(len(result.clusters))]
        with staged_output_dir(final, overwrite=args.overwrite, kind="segmentation",
                               inputs=(args.scene,)) as out:
            for i, cluster in enumerate(result.clusters):
                write_point_cloud(out / f"cluster_{i:03d}.pcd", cluster)
            atomic_write_text(out / "segmentation.json", json.dumps(to_jsonable(payload), indent=2) + "\n")
    emit(args, payload, lambda: _text(payload))
    return 0


def _text(p: dict) -> str:
    t = p["timings_ms"]
    head = (
        f"{p['scene']}: {p['n_input_points']} points, {p['n_segmented_points']} after voxel grid, "
        f"{p['n_after_planes']} after plane removal"
    )
    lines = [head]
    r = p.get("resolved") or {}
    if r.get("spacing_m") is not None:
        leaf = "none" if r["voxel_leaf_m"] is None else f"{1000 * r['voxel_leaf_m']:.2f} mm"
        lines.append(f"auto: point spacing {1000 * r['spacing_m']:.2f} mm -> voxel {leaf}, cluster tolerance "
                     f"{1000 * r['cluster_tolerance_m']:.2f} mm")
    for i, plane in enumerate(p["planes"]):
        a, b, c, d = plane["coefficients"]
        lines.append(
            f"plane {i}: {a:+.6f} {b:+.6f} {c:+.6f} {d:+.6f}  inliers {plane['n_inliers']} "
            f"(rmse {plane['rmse_m'] * 1000:.2f} mm, {plane['n_iterations']} hypotheses)"
        )
    sizes = p["cluster_sizes"]
    lines.append(f"{len(sizes)} clusters: {' '.join(map(str, sizes)) if sizes else '-'}")
    lines.extend(f"note: {n}" for n in p["notes"])
    lines.append(
        f"time: voxel {t['voxel']:.1f} ms, planes {t['planes']:.1f} ms, clusters {t['clusters']:.1f} ms, "
        f"total {t['total']:.1f} ms"
    )
    if "files" in p:
        lines.append(f"wrote {len(p['files'])} cluster PCDs and segmentation.json")
    return "\n".join(lines)
