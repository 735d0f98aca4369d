"""Tests that kill surviving mutants of ``semslam/slam/config.py`` (benchmarks/mutation.py): the map settings."""

from __future__ import annotations

import pytest

from semslam.errors import ConfigError
from semslam.slam.config import MapConfig


def test_dense_max_landmarks_accepts_zero_and_refuses_negatives():
    """Catches a ``dense_max_landmarks`` check that refuses 0 (``<= 0`` or ``< 1`` for ``< 0``): the field must be
    ">= 0" (its own error message), so 0 is accepted and -1 is a ConfigError naming the setting."""
    assert MapConfig(dense_max_landmarks=0).dense_max_landmarks == 0
    with pytest.raises(ConfigError, match="dense_max_landmarks"):
        MapConfig(dense_max_landmarks=-1)


def test_initialisation_config_is_immutable():
    """Catches ``@dataclass(frozen=False)`` on ``InitialisationConfig``: like every section of ``SlamConfig`` it is
    frozen (a run's configuration cannot change under it); ``updated`` makes modified copies."""
    import dataclasses

    from semslam.slam.config import InitialisationConfig, SlamConfig

    c = InitialisationConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.survey_position_sigma_m = 1.0
    assert SlamConfig().updated(survey_position_sigma_m=0.5).initialisation.survey_position_sigma_m == 0.5
