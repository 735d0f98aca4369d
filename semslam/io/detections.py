"""Detections on disk: ``Detection.to_dict()`` per JSON line (with ``stamp_s`` and ``scan_id``), the form
``semslam detect`` writes and ``semslam slam --detections`` reads, as ``{scan_id: [Detection, ...]}``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._atomic import atomic_write_text
from ..detection import Detection
from ..errors import InputError, SemslamError


def read_detections_jsonl(path: str | Path) -> dict[int, list[Detection]]:
    """Read ``Detection.to_dict()`` JSON lines (each with ``stamp_s`` and ``scan_id``) into ``{scan_id: [...]}``."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"The detections file {str(path)!r} does not exist.")
    out: dict[int, list[Detection]] = {}
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"The detections file {str(path)!r} cannot be read as UTF-8 text: {exc}") from None
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            d = Detection.from_dict(json.loads(line))
        except (json.JSONDecodeError, RecursionError) as exc:
            raise InputError(f"Line {n} of {str(path)!r} is not JSON: {getattr(exc, 'msg', exc)}.") from None
        except SemslamError as exc:
            raise InputError(f"Line {n} of {str(path)!r}: {exc}") from None
        if not np.isfinite(d.stamp_s):
            raise InputError(
                f"Line {n} of {str(path)!r}: a detection needs a finite 'stamp_s'. Got {d.stamp_s} instead."
            )
        out.setdefault(d.scan_id, []).append(d)
    return out


def write_detections_jsonl(path: str | Path, detections_by_scan: dict[int, list[Detection]]) -> None:
    """Write detections as JSON lines (atomic)."""
    lines = [json.dumps(d.to_dict()) for sid in sorted(detections_by_scan) for d in detections_by_scan[sid]]
    atomic_write_text(path, "\n".join(lines) + ("\n" if lines else ""))
