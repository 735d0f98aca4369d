"""Printing helpers shared by the sub-commands: one JSON document with ``--json``, text otherwise."""

from __future__ import annotations

import json
import math
from typing import Any, Callable

import numpy as np


def to_jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays, dataclasses with ``to_dict`` and NaN/inf into JSON-safe values."""
    if hasattr(obj, "to_dict") and callable(obj.to_dict):
        return to_jsonable(obj.to_dict())
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def emit(args: Any, payload: Any, text: Callable[[], str] | str) -> None:
    """Print ``payload`` as JSON when ``--json`` was given, else the human text."""
    if getattr(args, "json", False):
        print(json.dumps(to_jsonable(payload), indent=2))
    else:
        print(text() if callable(text) else text)
