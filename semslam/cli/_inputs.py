"""Inputs shared by the commands: datasets (dataset directories, ``synthetic:SEED``), vehicle files and
``--config`` files (TOML or JSON tables)."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError


def load_dataset(spec: str, vehicle: str | None = None):
    """A dataset directory (or ``synthetic:SEED``, the analytic square mission), with its vehicle description
    replaced by the ``vehicle`` file when given (``girona500`` for the documented defaults)."""
    from dataclasses import replace

    from ..dataset import VehicleDescription, read_dataset, read_vehicle_toml

    if spec.startswith("synthetic:"):
        from ..simulation.synthetic import square_dataset

        try:
            seed = int(spec.split(":", 1)[1])
        except ValueError:
            raise InputError(
                f"The DATASET argument must be a directory or synthetic:SEED. Got {spec!r} instead."
            ) from None
        ds = square_dataset(seed=seed)
    else:
        path = Path(spec)
        if not path.is_dir():
            raise InputError(f"The DATASET argument must be an existing dataset directory or synthetic:SEED. "
                             f"Got {spec!r} instead.")
        ds = read_dataset(path)
    if vehicle:
        v = VehicleDescription.girona500() if vehicle == "girona500" else read_vehicle_toml(vehicle)
        ds = replace(ds, vehicle=v)
    return ds


def add_config_options(p, what: str = "the pipeline and the filter") -> None:
    """``--config FILE`` / ``--preset NAME`` (semslam.run.config; docs/configuration.md)."""
    p.add_argument("--config", metavar="FILE", help=f"TOML or JSON settings of {what}: [pipeline], [slam] and [run] "
                                                    "tables (older [slam]/[pipeline] files too); docs/configuration.md")
    p.add_argument("--preset", metavar="NAME", help="named settings to start from: default, cluttered, seabed, "
                                                    "depth-camera (a --config file overrides them)")


def run_config_from_args(args, *, default_modes: tuple | None = None):
    """The run's :class:`~semslam.run.config.RunConfig`: ``--preset``, then ``--config``, then the run options given
    on the command line (``--mode``, ``--backend``, ``--seed``: when not None; ``--keep-unreliable``,
    ``--up-from-attitude``: when set). ``default_modes``: the command's modes when neither names any."""
    from ..run.config import load_run_config

    rc = load_run_config(getattr(args, "config", None), getattr(args, "preset", None))
    opts: dict = {}
    mode = getattr(args, "mode", None)
    if mode is not None:
        from ..slam.config import MODES

        if mode != "all" and mode not in MODES:
            raise InputError(f"The '--mode' option must be one of {MODES} or 'all'. Got {mode!r} instead.")
        opts["modes"] = MODES if mode == "all" else (mode,)
    elif default_modes is not None and "modes" not in rc.run.model_fields_set:
        opts["modes"] = tuple(default_modes)
    opts.update({k: getattr(args, k) for k in ("backend", "seed") if getattr(args, k, None) is not None})
    opts.update({k: True for k in ("keep_unreliable", "up_from_attitude") if getattr(args, k, False)})
    return rc.with_run(**opts) if opts else rc


def parse_direction(text: str) -> tuple[float, float, float]:
    """``X,Y,Z`` as a non-zero finite 3-vector (argparse type: bad text is a usage error naming it)."""
    import argparse
    import math

    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values) or not any(values):
        raise argparse.ArgumentTypeError(f"expected a non-zero direction X,Y,Z (three finite numbers), got {text!r}")
    return values  # type: ignore[return-value]


def load_database_arg(spec: str):
    """``--db``: a view database file, or ``builtin`` (the papers' four objects, simulated Kinect views)."""
    if spec == "builtin":
        from ..simulation.builtin_db import builtin_database

        return builtin_database(seed=0)
    from ..recognition import load_database

    return load_database(spec)
