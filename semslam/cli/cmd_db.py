"""``semslam db build`` / ``semslam db info``: the recognition view database.

* ``semslam db build VIEWS_DIR --out DB.npz``: from a folder ``CLASS/VIEW.{pcd,ply,npy}`` of partial
  views in each object's canonical frame (optional ``classes.json`` for symmetry and size).
* ``semslam db build --builtin --out DB.npz``: the four built-in fittings seen by the simulator's
  Kinect-like camera (``--n-views`` per object), by default in the survey geometry (75 degrees, 1.5 m),
  plus ``--model-views`` pose-model views per object (default 8 at 60 degrees, 0.7 m: less noise, more
  of the sides) that pose estimation fuses instead of the recognition views.
* ``semslam db build --models MODELS_DIR --out DB.npz``: your CAD models (STL, OBJ, PLY and a
  ``models.toml``, see :mod:`semslam.simulation.cad_models`) seen by the same camera, with the same options.
* ``--sensor laser`` (or ``kinect+laser``) with ``--builtin``/``--models``: the recognition views are rendered by
  a laser scanner from route-like viewpoints instead of (or as well as) the Kinect-like camera
  (:mod:`semslam.simulation.model_database`): ``--laser-views`` whole views and ``--laser-cut-views`` views cut by
  the swath's border per object; the pose-model views stay Kinect views. ``--vehicle FILE`` renders them with
  that vehicle's scanner (mounting, field of view, lines, range) and makes ``laser`` the default.
* ``semslam db info DB.npz``: classes, views per class, symmetry, size, descriptor settings, file version.
"""

from __future__ import annotations

import argparse

from ._inputs import parse_direction


def _length_or_auto(value: str):
    """A length in metres, or 'auto' (from the views' measured point spacing)."""
    if value == "auto":
        return value
    try:
        return float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of metres or 'auto', got {value!r}") from None


def register(subparsers: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    parser = subparsers.add_parser("db", parents=[common], help="build or describe a recognition view database",
                                   description="Build or describe a recognition view database (.npz).")
    sub = parser.add_subparsers(dest="db_command", metavar="ACTION")
    parser.set_defaults(func=lambda args: _usage(parser))

    build = sub.add_parser("build", parents=[common], help="compute descriptors of partial views into a database",
                           description="Compute ESF and VFH descriptors of partial views and write one "
                                       "versioned database file (written atomically).")
    src = build.add_mutually_exclusive_group(required=True)
    src.add_argument("views_dir", nargs="?", metavar="VIEWS_DIR", help="folder CLASS/VIEW.{pcd,ply,npy}")
    src.add_argument("--builtin", action="store_true",
                     help="the four built-in objects acquired by the simulated Kinect-like camera")
    src.add_argument(
        "--models",
        metavar="MODELS_DIR",
        help="your CAD models (STL, OBJ, PLY, COLLADA, glTF, STEP + models.toml: file, unit, symmetry, T_mesh_object per "
        "class) acquired by the simulated Kinect-like camera",
    )
    build.add_argument("--fuse", action="store_true",
                       help="VIEWS_DIR views are in their own sensor frames: align each class's views into one "
                            "object frame (CLASS/poses.csv with T_object_sensor per view if present, else "
                            "estimated) and store the fused model")
    build.add_argument("--up", type=parse_direction, default=None, metavar="X,Y,Z",
                       help="with --fuse: the up direction in the views' sensor frames (0,-1,0 for a level "
                            "camera, y down): gravity-aligned alignment and refinement")
    build.add_argument("--no-clean", dest="clean", action="store_false",
                       help="keep points at the sensor origin and drawn lines in VIEWS_DIR views (default: dropped)")
    build.add_argument("--out", required=True, metavar="DB", help="database file to write (.npz)")
    build.add_argument("--overwrite", action="store_true", help="replace the --out file if it exists")
    build.add_argument("--n-views", type=int, default=8, help="views per object with --builtin/--models (default 8)")
    build.add_argument(
        "--kinect-elevation",
        type=float,
        default=75.0,
        metavar="DEG",
        help="camera elevation of the --builtin/--models views, degrees (default 75: the survey geometry; "
        "the papers used 45)",
    )
    build.add_argument("--kinect-distance", type=float, default=1.5, metavar="M",
                       help="camera distance of the --builtin/--models views, metres (default 1.5; the papers "
                            "~0.7); farther for a part too large to fit in the image from there")
    _add_sensor_options(build)
    build.add_argument(
        "--model-views",
        type=int,
        default=None,
        metavar="N",
        help="pose-model views per object with --builtin/--models (default 16 with the laser, 8 with the Kinect "
             "alone; 0: pose uses the recognition views)",
    )
    build.add_argument("--model-elevation", type=float, default=60.0, metavar="DEG",
                       help="camera elevation of the --builtin/--models pose-model views, degrees (default 60)")
    build.add_argument("--model-distance", type=float, default=0.7, metavar="M",
                       help="camera distance of the --builtin/--models pose-model views, metres (default 0.7); "
                            "farther for a part too large to fit in the image from there (wider than ~0.6 m)")
    build.add_argument("--voxel", type=_length_or_auto, default=0.005, metavar="M|auto",
                       help="voxel grid applied to views and queries before the descriptors, metres, or auto "
                            "(0.9 x the views' measured point spacing); 0 disables (default 0.005, the "
                            "segmentation's grid)")
    build.add_argument("--seed", type=int, default=0, help="seed of the simulated views and of ESF (default 0)")
    build.add_argument("--normal-radius", type=_length_or_auto, default=None, metavar="M|auto",
                       help="normal-estimation radius for the VFH, metres, or auto (3 voxels of the measured "
                            "spacing); default: 3 voxels of --voxel (0.015), auto with --voxel 0 or auto")
    build.add_argument("--vfh-variant", default=None, help="VFH binning variant (default: the descriptors' default)")
    build.add_argument("--esf-samples", type=int, default=20000, help="ESF point-triplet samples (default 20000)")
    build.add_argument("--progress", action="store_true", help="show a progress bar")
    build.add_argument("--jobs", type=int, default=1, metavar="N",
                       help="worker processes of a local Dask cluster for the descriptors (default 1: in this "
                            "process); the same database either way")
    build.add_argument("--scheduler", metavar="ADDRESS",
                       help="compute the descriptors on the Dask cluster of this scheduler (tcp://host:8786)")
    build.set_defaults(func=run_build)

    info = sub.add_parser("info", parents=[common], help="describe a database file",
                          description="Print the classes, views per class, symmetry, size, descriptor "
                                      "variants and file version of a database.")
    info.add_argument("db", metavar="DB", help="database file (.npz)")
    info.set_defaults(func=run_info)


def _add_sensor_options(build: argparse.ArgumentParser) -> None:
    """``--sensor``, ``--vehicle``, ``--laser-views``, ``--laser-cut-views`` of ``db build``."""
    build.add_argument("--sensor", default=None, choices=("kinect", "laser", "kinect+laser"),
                       help="with --builtin/--models: the recognition views' sensor: the Kinect-like camera (default "
                            "without --vehicle), the laser scanner from route-like viewpoints (default with "
                            "--vehicle; semslam.simulation.model_database), or both; the pose-model views stay "
                            "Kinect views")
    build.add_argument("--vehicle", metavar="FILE",
                       help="with --builtin/--models: your vehicle file (vehicle.toml): its laser scanner (mounting, "
                            "field of view, lines, range) renders the views; implies --sensor laser unless given")
    build.add_argument("--laser-views", type=int, default=48, metavar="N",
                       help="laser views per object whole in the swath, one heading every 360/N degrees (default 48)")
    build.add_argument("--laser-cut-views", type=int, default=16, metavar="N",
                       help="laser views per object that the swath's border may cut (default 16; 0: none)")


def _usage(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 2


def run_build(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from .._outdir import check_output_file, staged_output_file
    from ..errors import InputError
    from ..recognition import build_database, build_database_from_folder, save_database
    from ._output import emit

    t0 = time.perf_counter()
    inputs = (args.views_dir, args.models)
    check_output_file(args.out, overwrite=args.overwrite, inputs=inputs)  # before the work (semslam._outdir)
    kwargs = {"vfh_variant": args.vfh_variant, "normal_radius_m": args.normal_radius,
              "esf_n_samples": args.esf_samples,
              "voxel_leaf_m": args.voxel if args.voxel == "auto" or args.voxel > 0 else None,
              "seed": args.seed, "progress": args.progress}
    if args.jobs != 1 or args.scheduler:
        from functools import partial

        from ..batch.engine import check_jobs

        kwargs["mapper"] = partial(_dask_mapper, jobs=check_jobs(args.jobs), scheduler=args.scheduler)
    if (args.builtin or args.models is not None) and (args.fuse or args.up is not None):
        raise InputError("--fuse and --up are for a VIEWS_DIR of recorded views, not --builtin or --models.")
    _resolve_sensor(args)
    if (args.builtin or args.models is not None) and args.sensor != "kinect":
        db, warned = _build_with_laser(args, kwargs)
        source = "builtin" if args.builtin else str(args.models)
    elif args.builtin:
        import math

        from ..simulation.config import KinectConfig
        from ..simulation.kinect import builtin_view_clouds

        kinect = KinectConfig(elevation_rad=math.radians(args.kinect_elevation), distance_m=args.kinect_distance)
        views, classes = builtin_view_clouds(seed=args.seed, n_views=args.n_views, config=kinect)
        if args.model_views < 0:
            from ..errors import InputError

            raise InputError(f"The '--model-views' option must be >= 0. Got {args.model_views} instead.")
        if args.model_views:
            model_kinect = KinectConfig(
                elevation_rad=math.radians(args.model_elevation), distance_m=args.model_distance
            )
            kwargs["model_views"], _ = builtin_view_clouds(
                seed=args.seed, n_views=args.model_views, config=model_kinect
            )
        from ..simulation.cad_models import with_resting_up
        from ..simulation.objects import builtin_objects

        db = with_resting_up(build_database(views, classes, **kwargs), builtin_objects())
        source = "builtin"
    elif args.models is not None:
        db, warned = _build_from_models(args, kwargs)
        source = str(args.models)
    elif args.fuse:
        from ..recognition.fuse import build_fused_database

        if kwargs.pop("mapper", None) is not None:
            raise InputError("--fuse computes the descriptors in this process: drop --jobs/--scheduler.")
        db = build_fused_database(args.views_dir, up_sensor=args.up, clean=args.clean, **kwargs)
        source = str(args.views_dir)
    else:
        if args.up is not None:
            raise InputError("--up is for --fuse (views in their own sensor frames); add --fuse or drop --up.")
        db = build_database_from_folder(args.views_dir, clean=args.clean, **kwargs)
        source = str(args.views_dir)
    with staged_output_file(args.out, overwrite=args.overwrite, inputs=inputs) as tmp:
        save_database(db, tmp)
    path = Path(args.out)
    payload = {"path": str(path), "source": source, "seconds": round(time.perf_counter() - t0, 3), **db.summary()}
    if args.models is not None:
        payload["warnings"] = warned
    payload["sensor"] = args.sensor
    emit(args, payload, lambda: f"wrote {path}: {db.n_views} views of {len(db.classes)} classes "
                                f"({', '.join(db.classes)}) in {payload['seconds']:.1f} s")
    return 0


def _dask_mapper(fn, items, progress, *, jobs: int, scheduler: str | None):
    """``build_database``'s ``mapper`` on Dask (a local cluster of ``jobs`` workers, or ``scheduler``'s)."""
    from ..batch.engine import map_tasks

    return map_tasks(fn, items, jobs=jobs, scheduler=scheduler, progress=progress, desc="descriptors")


def _resolve_sensor(args: argparse.Namespace) -> None:
    """``args.sensor`` and ``args.model_views`` resolved from ``--vehicle`` (one-line errors for conflicts)."""
    from ..errors import InputError

    if args.sensor is None:
        args.sensor = "laser" if args.vehicle is not None else "kinect"
    if args.model_views is None:
        args.model_views = 8 if args.sensor == "kinect" else 16
    if args.vehicle is not None and args.sensor == "kinect":
        raise InputError("--vehicle gives the laser scanner the views are rendered with; --sensor kinect renders none. "
                         "Drop one of them.")
    if args.vehicle is not None and not (args.builtin or args.models is not None):
        raise InputError("--vehicle renders views of --builtin or --models objects; a VIEWS_DIR holds recorded views. "
                         "Drop --vehicle or use --builtin/--models.")
    if args.sensor != "kinect" and not (args.builtin or args.models is not None):
        raise InputError(f"--sensor {args.sensor} renders views of --builtin or --models objects; a VIEWS_DIR holds "
                         "recorded views. Drop --sensor or use --builtin/--models.")


def _build_with_laser(args: argparse.Namespace, kwargs: dict):
    """``--sensor laser|kinect+laser`` (or ``--vehicle``) with ``--builtin``/``--models``: the database
    (:func:`semslam.simulation.model_database.sensor_database`) and the models' warnings."""
    import math

    from ..simulation.config import KinectConfig
    from ..simulation.model_database import scanner_from_vehicle, sensor_database

    if args.builtin:
        from ..simulation.objects import builtin_objects

        models, warned = builtin_objects(), []
    else:
        from ..simulation.cad_models import read_models

        models, warned = _with_warnings(read_models, args.models)
    scanner = None if args.vehicle is None else scanner_from_vehicle(args.vehicle)
    db = sensor_database(
        models, sensor=args.sensor, n_views=args.n_views, n_model_views=args.model_views,
        kinect=KinectConfig(elevation_rad=math.radians(args.kinect_elevation), distance_m=args.kinect_distance),
        model_kinect=KinectConfig(elevation_rad=math.radians(args.model_elevation), distance_m=args.model_distance),
        scanner=scanner, laser_views=args.laser_views, laser_cut_views=args.laser_cut_views, **kwargs)
    return db, warned


def _build_from_models(args: argparse.Namespace, kwargs: dict):
    """``--models``: the database and the models' warnings (each also printed as one stderr line)."""
    import math

    from ..errors import InputError
    from ..simulation.cad_models import build_models_database
    from ..simulation.config import KinectConfig

    if args.model_views < 0:
        raise InputError(f"The '--model-views' option must be >= 0. Got {args.model_views} instead.")
    kinect = KinectConfig(elevation_rad=math.radians(args.kinect_elevation), distance_m=args.kinect_distance)
    model_kinect = KinectConfig(elevation_rad=math.radians(args.model_elevation), distance_m=args.model_distance)
    return _with_warnings(build_models_database, args.models, n_views=args.n_views, n_model_views=args.model_views,
                          kinect=kinect, model_kinect=model_kinect, **kwargs)


def _with_warnings(fn, *a, **kw):
    """``(fn(*a, **kw), [messages])``: the user's models' warnings (``UserWarning``), each also printed as one
    stderr line; other warnings pass through."""
    import sys
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = fn(*a, **kw)
    warned = []
    for w in caught:
        if issubclass(w.category, UserWarning):
            warned.append(str(w.message))
            print(f"semslam: warning: {w.message}", file=sys.stderr)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return out, warned


def format_summary(summary: dict, path: str) -> str:
    """Human-readable ``db info`` text."""
    d = summary["descriptors"]
    header = (f"{path}: {summary['format']} version {summary['version']}, {summary['n_views']} views, "
              f"{summary['n_points']} points")
    descriptors = (f"descriptors: ESF {d['esf']['bins']} bins ({d['esf']['n_samples']} samples), "
                   f"VFH {d['vfh']['bins']} bins (variant {d['vfh']['variant']!r}, "
                   f"normal radius {d['vfh']['normal_radius_m']} m)")
    lines = [header, descriptors, "", "| class | views | pose-model views | symmetry | size x y z (mm) |",
             "|---|---:|---:|---|---|"]
    for label, c in summary["classes"].items():
        sym = c["symmetry"]
        sym_text = sym["kind"]
        if "axis_object" in sym:
            sym_text += f" about {tuple(round(a, 3) for a in sym['axis_object'])}"
        if sym["kind"] == "discrete":
            sym_text += f", order {sym['order']}"
        if sym.get("flip"):
            sym_text += ", same end for end"
        size = " x ".join(f"{1000 * s:.1f}" for s in c["size_xyz_m"])
        n_model = c.get("n_model_views", 0)
        lines.append(f"| {label} | {c['n_views']} | {n_model or '(views)'} | {sym_text} | {size} |")
    return "\n".join(lines)


def run_info(args: argparse.Namespace) -> int:
    from ..recognition import load_database
    from ._output import emit

    db = load_database(args.db)
    summary = {"path": str(args.db), **db.summary()}
    emit(args, summary, lambda: format_summary(summary, str(args.db)))
    return 0
