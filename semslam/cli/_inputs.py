"""Inputs shared by the commands: datasets (mission directories, ``synthetic:SEED``), vehicle files and
``--config`` files (TOML or JSON tables)."""

from __future__ import annotations

from pathlib import Path

from ..errors import ConfigError, InputError


def load_dataset(spec: str, vehicle: str | None = None):
    """A mission directory (or ``synthetic:SEED``, the analytic square mission), with its vehicle description
    replaced by the ``vehicle`` file when given (``girona500`` for the documented defaults)."""
    from dataclasses import replace

    from ..dataset import VehicleDescription, read_mission, read_vehicle_toml

    if spec.startswith("synthetic:"):
        from ..experiments.synthetic import square_mission

        try:
            seed = int(spec.split(":", 1)[1])
        except ValueError:
            raise InputError(f"The MISSION argument must be a directory or synthetic:SEED. Got {spec!r} instead.") from None
        ds = square_mission(seed=seed)
    else:
        path = Path(spec)
        if not path.is_dir():
            raise InputError(f"The MISSION argument must be an existing mission directory or synthetic:SEED. "
                             f"Got {spec!r} instead.")
        ds = read_mission(path)
    if vehicle:
        v = VehicleDescription.girona500() if vehicle == "girona500" else read_vehicle_toml(vehicle)
        ds = replace(ds, vehicle=v)
    return ds


def read_config_file(path: str, option: str = "--config") -> dict:
    """The table in a TOML (``.toml``) or JSON (``.json``) file, for a command's ``--config``."""
    from .._tables import read_table

    return read_table(path, f"{option} file", ConfigError)


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
