"""Detections as JSON lines (``semslam/io/detections.py``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from semslam.detection import Detection
from semslam.geometry import RigidTransform
from semslam.io.detections import write_detections_jsonl


def test_jsonl_lines_are_newline_terminated_and_round_trip(tmp_path: Path):
    """Catches a JSON-lines file whose last record is not newline-terminated (or an empty file given a lone
    newline): one line per detection, each a JSON object ending in a newline; no detection, an empty file."""
    det = Detection("valve", 1.5, RigidTransform.from_rotation_translation(np.eye(3), [1.0, 2.0, 3.0]),
                    np.eye(6) * 1e-3)
    path = tmp_path / "d.jsonl"
    write_detections_jsonl(path, {0: [det], 1: [det]})
    text = path.read_text()
    assert text.endswith("}\n") and text.count("\n") == 2
    assert [json.loads(line)["label"] for line in text.splitlines()] == ["valve", "valve"]
    write_detections_jsonl(tmp_path / "e.jsonl", {})
    assert (tmp_path / "e.jsonl").read_text() == ""
