"""Inputs shared by the commands: datasets (mission directories, ``synthetic:SEED``), vehicle files and
``--config`` files (TOML or JSON tables)."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

from ..errors import ConfigError, InputError

_MAX_CONFIG_BYTES = 1 << 20


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
    """The table in a TOML (``.toml``) or JSON file, for a command's ``--config``."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"The {option} file {path!r} does not exist or is not a regular file.")
    if p.stat().st_size > _MAX_CONFIG_BYTES:
        raise ConfigError(f"The {option} file {path!r} must be at most {_MAX_CONFIG_BYTES} bytes.")
    try:
        text = p.read_text(encoding="utf-8")
        d = tomllib.loads(text) if p.suffix.lower() == ".toml" else json.loads(text)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, tomllib.TOMLDecodeError, RecursionError) as exc:
        kind = "TOML" if p.suffix.lower() == ".toml" else "JSON"
        raise ConfigError(f"The {option} file {path!r} cannot be read as {kind}: {exc}") from None
    if not isinstance(d, dict):
        raise ConfigError(f"The {option} file {path!r} must hold a table of settings. Got {type(d).__name__} instead.")
    return d
