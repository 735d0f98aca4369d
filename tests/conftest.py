"""Shared fixtures: where the shared data and the PCL oracle are, skipping cleanly when absent."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TEST_DATA = Path(__file__).resolve().parent / "data"
SHARED = Path(os.environ.get("SEMSLAM_SHARED", ROOT.parent / "shared"))


@pytest.fixture(scope="session")
def test_data() -> Path:
    """``tests/data``: small fixtures that always ship with the repository."""
    return TEST_DATA


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """``../shared`` beside the clone; tests that need it skip when it is absent."""
    if not SHARED.is_dir():
        pytest.skip(f"shared data folder not found at {SHARED} (set SEMSLAM_SHARED)")
    return SHARED


@pytest.fixture(scope="session")
def real_data(shared_dir: Path) -> Path:
    """``../shared/data/real``: PCL's real test scans."""
    path = shared_dir / "data" / "real"
    if not path.is_dir():
        pytest.skip(f"real scans not found at {path}")
    return path


@pytest.fixture(scope="session")
def pcl_ref() -> str:
    """Path of the ``pcl_ref`` oracle binary (``../shared/pcl_oracle/build.sh``); skip when not built."""
    candidates = [os.environ.get("PCL_REF", ""), str(Path.home() / ".cache/pcl_oracle/pcl_ref"),
                  shutil.which("pcl_ref") or ""]
    for c in candidates:
        if c and os.access(c, os.X_OK):
            return c
    pytest.skip("pcl_ref oracle not built (run ../shared/pcl_oracle/build.sh)")
