"""Fixtures of the registration tests."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.fixture(scope="module")
def rv():
    """``benchmarks/real_valves.py`` as a module: its view loading, measured turns and pair protocol."""
    sys.path.insert(0, str(BENCH))
    try:
        import real_valves
    finally:
        sys.path.remove(str(BENCH))
    return real_valves
