"""Where the shared data and the PCL oracle are, skipping cleanly when absent.

No silent skips: a run that must have the data fails instead of skipping: ``SEMSLAM_REQUIRE_SHARED=1``
(``../shared`` and the data in it; CI sets it, since CI always has ``../shared`` beside the clone) and
``SEMSLAM_REQUIRE_PCL=1`` (the ``pcl_ref`` oracle).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TEST_DATA = ROOT / "tests" / "data"
SHARED = Path(os.environ.get("SEMSLAM_SHARED", ROOT.parent / "shared"))


def missing(what: str, env: str) -> None:
    """Skip (with the reason) unless ``env`` says this run must have ``what``: then fail."""
    if os.environ.get(env, "") not in ("", "0"):
        pytest.fail(f"{what} (required by {env}=1)")
    pytest.skip(what)


def require_shared(path: Path, what: str) -> Path:
    """``path`` from ``../shared``, or a skip (a failure under SEMSLAM_REQUIRE_SHARED=1) naming ``what``."""
    if not path.exists():
        missing(f"{what} not found at {path}", "SEMSLAM_REQUIRE_SHARED")
    return path
