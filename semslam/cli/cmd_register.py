"""``semslam register SOURCE TARGET``: align two point clouds (FPFH + prerejective RANSAC + ICP).

Prints ``T_target_source`` (maps SOURCE points into the TARGET frame), the fitness (inlier fraction),
the inlier RMSE and the stage timings; ``--json`` prints the whole result. ``--out FILE`` also writes the
source cloud moved into the target frame (atomically).

``--up X,Y,Z`` (the up direction in SOURCE's frame; ``--up-target`` in TARGET's, default the same) switches
to gravity-aligned registration (:func:`semslam.registration.align_upright`): a yaw scan about up, 4-DoF
point-to-plane refinement, hypotheses that would show the target sensor the object's back dropped, and a
verdict: ``reliable``, or ``ambiguous`` (a distinct yaw fits nearly as well; the yaw sigma then covers it).
``--clean`` first drops points at the sensor origin (invalid depth) and drawn lines (axes/normals saved
by a viewer; :func:`semslam.segmentation.clean.clean_view`). Exit 1 when the coarse alignment finds no
hypothesis with the required inlier fraction, or (one line on stderr) when a cloud is a plane or a line,
or the time budget runs out before the RANSAC.

Bounded: ``--time-budget S`` (default 10 s, 0 = none) counts from the process start (reading included);
``--voxel auto`` (default) picks the leaf from the clouds' spacing and extent (at most ``--max-voxels``
source voxels, 4x as many target voxels); far outliers are cropped; ``--remove-outliers`` adds statistical outlier
removal.
"""

from __future__ import annotations

import argparse

from ._inputs import parse_direction


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    p = subparsers.add_parser(
        "register", parents=[common], help="align a source cloud onto a target cloud (FPFH + RANSAC + ICP)",
        description="Align SOURCE onto TARGET as PCL's alignment tutorial: voxel grid, normals, FPFH, "
                    "prerejective RANSAC, then ICP. Prints T_target_source, fitness, RMSE and timings.")
    p.add_argument("source", metavar="SOURCE", help="source cloud (.pcd, .ply, .npy)")
    p.add_argument("target", metavar="TARGET", help="target cloud (.pcd, .ply, .npy)")
    p.add_argument("--voxel", type=_voxel, default="auto", metavar="M",
                   help="voxel leaf in metres, or 'auto' (default): from the clouds' spacing and extent "
                        "(PCL's tutorial uses 0.005)")
    p.add_argument("--max-voxels", type=int, default=2000, metavar="N",
                   help="with --voxel auto, at most N source voxels and 4N target voxels (default 2000)")
    p.add_argument("--time-budget", type=float, default=10.0, metavar="S",
                   help="wall-clock budget in seconds from the command's start, 0 = unbounded (default 10); "
                        "the RANSAC and ICP stop at it")
    p.add_argument("--remove-outliers", action="store_true",
                   help="statistical outlier removal (20 neighbours, 2 sigma) on the voxelised clouds")
    p.add_argument("--max-neighbors", type=int, default=200, metavar="K",
                   help="FPFH neighbours per point at most, the nearest (default 200; 0 = no cap)")
    p.add_argument("--progress", action="store_true", help="show a progress bar on stderr")
    p.add_argument("--seed", type=int, default=0, help="RANSAC seed (default 0)")
    p.add_argument("--max-iterations", type=int, default=50000, help="RANSAC hypotheses (default 50000)")
    p.add_argument("--k-correspondences", type=int, default=5, help="feature neighbours to pick from (default 5)")
    p.add_argument("--similarity", type=float, default=0.9, help="polygon pre-rejection threshold (default 0.9)")
    p.add_argument("--inlier-fraction", type=float, default=0.25, help="required inlier fraction (default 0.25)")
    p.add_argument("--max-correspondence", type=float, default=None, metavar="M",
                   help="RANSAC inlier distance, metres (default 2.5 x voxel)")
    p.add_argument("--icp", default="pcl", choices=("pcl", "point", "plane", "gicp", "none"),
                   help="ICP variant (default pcl: PCL's point-to-point ICP)")
    p.add_argument("--icp-max-iterations", type=int, default=50, help="ICP iterations (default 50)")
    p.add_argument("--icp-max-points", type=int, default=20000, metavar="N",
                   help="ICP on a seeded random subset of at most N source points (default 20000; 0 = all, as PCL)")
    p.add_argument("--up", type=parse_direction, default=None, metavar="X,Y,Z",
                   help="up direction in the SOURCE frame (e.g. 0,-1,0 for a level camera, y down): "
                        "gravity-aligned 4-DoF registration that resolves upside-down flips")
    p.add_argument("--up-target", type=parse_direction, default=None, metavar="X,Y,Z",
                   help="up direction in the TARGET frame (default: the same as --up)")
    p.add_argument("--clean", action="store_true",
                   help="drop points at the sensor origin (invalid depth) and drawn straight lines first")
    p.add_argument("--out", default=None, metavar="FILE", help="write the aligned source cloud here")
    p.add_argument("--overwrite", action="store_true", help="replace the --out file if it exists")
    p.set_defaults(func=run)


def _voxel(text: str) -> str | float:
    if text == "auto":
        return "auto"
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'auto' or a length in metres, got {text!r}") from None


def _process_age_s() -> float:
    """Seconds since this process started (Linux /proc; 0 elsewhere): the interpreter start-up and the
    imports count against ``--time-budget``."""
    import os

    try:
        with open(f"/proc/{os.getpid()}/stat") as f:
            start_ticks = float(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            uptime_s = float(f.read().split()[0])
        return max(0.0, uptime_s - start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return 0.0


def run(args: argparse.Namespace) -> int:
    import time

    import numpy as np

    from .._outdir import check_output_file
    from ..errors import RegistrationError
    from ..io import read_point_cloud
    from ..registration import RegisterConfig
    from ..registration import register as register_clouds
    from ._output import emit

    t0 = time.perf_counter()
    if args.out:  # before the work (semslam._outdir)
        check_output_file(args.out, overwrite=args.overwrite, inputs=(args.source, args.target))
    budget = None if args.time_budget == 0 else args.time_budget
    cfg = RegisterConfig(voxel_m=args.voxel, max_iterations=args.max_iterations,
                         k_correspondences=args.k_correspondences, similarity=args.similarity,
                         inlier_fraction=args.inlier_fraction, max_correspondence_m=args.max_correspondence,
                         icp_method=args.icp, icp_max_iterations=args.icp_max_iterations, time_budget_s=budget,
                         max_voxels=args.max_voxels, remove_outliers=args.remove_outliers,
                         max_neighbors=args.max_neighbors or None, icp_max_points=args.icp_max_points or None)
    source = read_point_cloud(args.source)
    target = read_point_cloud(args.target)
    if args.clean:
        from ..segmentation.clean import clean_view

        source = clean_view(source, name=f"SOURCE {args.source}")[0]
        target = clean_view(target, name=f"TARGET {args.target}")[0]
    if args.up_target is not None and args.up is None:
        raise RegistrationError("--up-target needs --up (the up direction in the SOURCE frame).")
    if args.up is not None:
        return _run_upright(args, source, target)
    if budget is not None:  # start-up and reading the files count against the budget
        from dataclasses import replace

        spent = max(time.perf_counter() - t0, _process_age_s())
        cfg = replace(cfg, time_budget_s=max(0.1 * budget, budget - spent))
    try:
        res = register_clouds(source, target, cfg, seed=args.seed, progress=args.progress)
    except RegistrationError as exc:  # name the files: "the target cloud" alone does not say which
        note = (f" (--time-budget {args.time_budget:g} s counts from the command's start: "
                f"{cfg.time_budget_s:.3g} s were left for register)") if "time budget" in str(exc) else ""
        raise RegistrationError(
            f"Cannot register SOURCE {args.source} onto TARGET {args.target}: {exc}{note}"
        ) from None
    if args.out and res.converged:
        _write_aligned(args, source.transformed(res.T_target_source, frame_id=target.frame_id))
    payload = {"source": args.source, "target": args.target, "config": cfg.to_dict(), "seed": args.seed,
               **res.to_dict()}

    def text() -> str:
        T = res.T_target_source
        rows = "\n".join("  " + " ".join(f"{v:+.6f}" for v in row) for row in T.matrix)
        xyz, rpy = T.translation_m, np.degrees(T.as_rpy())
        times = ", ".join(f"{k} {v:.0f} ms" for k, v in res.timings_ms.items())
        status = "converged" if res.converged else "NOT converged (no hypothesis reached the inlier fraction)"
        if "reliable" in res.extras:
            status += (", reliable" if res.extras["reliable"] else
                       ", AMBIGUOUS: a half turn fits nearly as well (orientation not to be trusted)"
                       if res.extras["ambiguous"] else ", NOT reliable: low fitness of the answer")
        if res.extras.get("budget_exhausted"):
            status += f", time budget of {args.time_budget:g} s exhausted"
        return (
            f"T_target_source ({status}):\n{rows}\n"
            f"xyz_m [{xyz[0]:.4f}, {xyz[1]:.4f}, {xyz[2]:.4f}]  rpy_deg [{rpy[0]:.2f}, {rpy[1]:.2f}, {rpy[2]:.2f}]\n"
            f"fitness {res.fitness:.4f} (inliers within {res.max_correspondence_m:.4g} m), "
            f"inlier RMSE {1e3 * res.inlier_rmse_m:.3f} mm\n"
            f"voxel {res.extras.get('voxel_m', float('nan')):.4g} m, timings: {times}"
        )

    emit(args, payload, text)
    return 0 if res.converged else 1


def _write_aligned(args: argparse.Namespace, cloud) -> None:
    from .._outdir import staged_output_file
    from ..io import write_point_cloud

    with staged_output_file(args.out, overwrite=args.overwrite, inputs=(args.source, args.target)) as tmp:
        write_point_cloud(tmp, cloud)


def _run_upright(args: argparse.Namespace, source, target) -> int:
    import numpy as np

    from ..errors import RegistrationError
    from ..registration import align_upright
    from ._output import emit

    try:
        res = align_upright(source, target, up_source=args.up, up_target=args.up_target or args.up)
    except RegistrationError as exc:
        raise RegistrationError(f"Cannot register SOURCE {args.source} onto TARGET {args.target}: {exc}") from None
    if args.out:
        _write_aligned(args, source.transformed(res.T_target_source, frame_id=target.frame_id))
    payload = {"source": args.source, "target": args.target, "up_source": list(args.up),
               "up_target": list(args.up_target or args.up), **res.to_dict()}

    def text() -> str:
        T, ex = res.T_target_source, res.extras
        rows = "\n".join("  " + " ".join(f"{v:+.6f}" for v in row) for row in T.matrix)
        xyz, rpy = T.translation_m, np.degrees(T.as_rpy())
        verdict = "reliable" if ex["reliable"] else ("AMBIGUOUS: another yaw fits nearly as well" if ex["ambiguous"]
                                                     else f"NOT reliable: fitness below {0.5:g}")
        alts = ", ".join(f"{h['yaw_deg']:+.1f} deg (rms {1e3 * h['rms_m']:.2f} mm)" for h in ex["hypotheses"])
        times = ", ".join(f"{k} {v:.0f} ms" for k, v in res.timings_ms.items())
        return (
            f"T_target_source (upright, {verdict}):\n{rows}\n"
            f"xyz_m [{xyz[0]:.4f}, {xyz[1]:.4f}, {xyz[2]:.4f}]  rpy_deg [{rpy[0]:.2f}, {rpy[1]:.2f}, {rpy[2]:.2f}]\n"
            f"yaw about up sigma {ex['yaw_sigma_deg']:.2f} deg; hypotheses (yaw about the target's up): {alts}\n"
            f"fitness {res.fitness:.4f} (inliers within {res.max_correspondence_m:.4g} m), "
            f"inlier RMSE {1e3 * res.inlier_rmse_m:.3f} mm\ntimings: {times}"
        )

    emit(args, payload, text)
    return 0
