"""``semslam describe CLOUD --descriptor esf|vfh|fpfh``: compute a PCL-compatible descriptor of a cloud
and print its histogram."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    parser = subparsers.add_parser(
        "describe", parents=[common], help="compute an ESF, VFH or FPFH descriptor of a cloud",
        description="Compute a descriptor as PCL 1.13 does and print its bins. ESF (640) and VFH (308) "
                    "describe the whole cloud; FPFH (33) is printed for one point. VFH and FPFH need "
                    "normals: those stored in the cloud are used unless --normal-knn or --normal-radius "
                    "is given (normals are then estimated, flipped towards the cloud's viewpoint).",
    )
    parser.add_argument("cloud", metavar="CLOUD", help="a .pcd, .ply or .npy file")
    parser.add_argument("--descriptor", choices=("esf", "vfh", "fpfh"), default="esf",
                        help="which descriptor (default: esf)")
    parser.add_argument("--vfh-variant", choices=("pcl-1.13", "pcl-1.8", "rusu2010"), default="pcl-1.13",
                        help="VFH binning / view direction (default: pcl-1.13)")
    normals = parser.add_mutually_exclusive_group()
    normals.add_argument("--normal-knn", type=int, metavar="K", help="estimate normals from K nearest neighbours")
    normals.add_argument("--normal-radius", type=float, metavar="R", help="estimate normals within R metres")
    parser.add_argument("--fpfh-radius", type=float, metavar="R", help="FPFH search radius in metres (fpfh)")
    parser.add_argument("--point", type=int, default=0, metavar="I", help="FPFH of point I (default 0)")
    parser.add_argument("--max-neighbors", type=int, default=None, metavar="K",
                        help="FPFH: at most K neighbours per point, the nearest (default: no cap, as PCL; "
                             "the result is PCL's whenever no point has more than K)")
    parser.add_argument("--seed", type=int, default=0, help="ESF random seed (default 0); with --sampler pcl, "
                        "the value PCL's time() would return")
    parser.add_argument("--sampler", choices=("numpy", "pcl"), default="numpy",
                        help="ESF sampler: numpy (default) or pcl (glibc rand, bit-exact with PCL)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import time

    import numpy as np

    from ..descriptors import compute_esf, compute_vfh, estimate_normals
    from ..descriptors.fpfh import compute_fpfh
    from ..errors import InputError
    from ..io import read_point_cloud
    from ._output import emit

    cloud = read_point_cloud(args.cloud)
    pts = cloud.points_xyz_m
    payload: dict = {"descriptor": args.descriptor, "cloud": str(args.cloud), "n_points": cloud.n_points}
    t0 = time.perf_counter()
    if args.descriptor == "esf":
        bins = compute_esf(pts, seed=args.seed, sampler=args.sampler)
        payload.update(seed=args.seed, sampler=args.sampler)
    else:
        if args.normal_knn is not None:
            normals = estimate_normals(pts, k=args.normal_knn, viewpoint_xyz_m=cloud.viewpoint_xyz_m).normals_xyz
            payload["normals"] = f"knn={args.normal_knn}"
        elif args.normal_radius is not None:
            normals = estimate_normals(pts, radius_m=args.normal_radius,
                                       viewpoint_xyz_m=cloud.viewpoint_xyz_m).normals_xyz
            payload["normals"] = f"radius={args.normal_radius}"
        elif cloud.has_normals:
            normals = cloud.normals_xyz
            payload["normals"] = "file"
        else:
            raise InputError(
                f"The {args.descriptor} descriptor needs normals and {args.cloud} has none: "
                "give --normal-knn K or --normal-radius R."
            )
        payload["n_nan_normals"] = int((~np.isfinite(normals).all(axis=1)).sum())
        if args.descriptor == "vfh":
            bins = compute_vfh(pts, normals, viewpoint_xyz_m=cloud.viewpoint_xyz_m, variant=args.vfh_variant)
            payload["variant"] = args.vfh_variant
        else:
            if args.fpfh_radius is None:
                raise InputError("The fpfh descriptor needs --fpfh-radius R (metres).")
            if not 0 <= args.point < cloud.n_points:
                raise InputError(f"The --point argument must be in [0, {cloud.n_points}). Got {args.point} instead.")
            bins = compute_fpfh(pts, normals, radius_m=args.fpfh_radius, max_neighbors=args.max_neighbors)[args.point]
            payload.update(point=args.point, fpfh_radius_m=args.fpfh_radius, max_neighbors=args.max_neighbors)
    payload["time_ms"] = (time.perf_counter() - t0) * 1000.0
    payload["n_bins"] = len(bins)
    payload["bins"] = [float(b) for b in bins]

    def text() -> str:
        head = f"{args.descriptor.upper()} of {args.cloud} ({cloud.n_points} points, {len(bins)} bins)"
        return head + "\n" + " ".join(f"{b:.9g}" for b in bins)

    emit(args, payload, text)
    return 0
