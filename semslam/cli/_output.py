"""Printing helpers shared by the sub-commands: one JSON document with ``--json``, text otherwise."""

from __future__ import annotations

import json
from typing import Any, Callable

from .._jsonable import to_jsonable  # noqa: F401  (re-exported for the commands)


def emit(args: Any, payload: Any, text: Callable[[], str] | str) -> None:
    """Print ``payload`` as JSON when ``--json`` was given, else the human text."""
    if getattr(args, "json", False):
        print(json.dumps(to_jsonable(payload), indent=2))
    else:
        print(text() if callable(text) else text)
