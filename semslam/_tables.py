"""Small human-written settings files (TOML, or JSON where a run wrote them): read with the checks every such
file gets (a regular file, a size cap, valid syntax, a table at the top), errors naming the file."""

from __future__ import annotations

import json
import os
import tomllib
from pathlib import Path

from .errors import SemslamError

MAX_BYTES = 1 << 20


def read_table(path: str | os.PathLike, what: str, error: type[SemslamError]) -> dict:
    """The top-level table of the TOML (or ``.json``) file ``path``; ``what`` names it in errors
    ("The vehicle file 'x.toml' ..."), ``error`` is the exception class raised."""
    p = Path(path)
    if not p.is_file():
        raise error(f"The {what} {str(p)!r} does not exist or is not a regular file.")
    size = p.stat().st_size
    if size > MAX_BYTES:
        raise error(f"The {what} {str(p)!r} must be at most {MAX_BYTES} bytes. Got {size} instead.")
    json_file = p.suffix.lower() == ".json"
    try:
        text = p.read_text(encoding="utf-8")
        d = json.loads(text) if json_file else tomllib.loads(text)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, tomllib.TOMLDecodeError, RecursionError) as exc:
        raise error(f"The {what} {str(p)!r} is not valid {'JSON' if json_file else 'TOML'}: {exc}") from None
    if not isinstance(d, dict):
        raise error(f"The {what} {str(p)!r} must hold a table of settings. Got {type(d).__name__} instead.")
    return d
