"""SLAM settings (``semslam/slam/config.py``): documented defaults, the gate probabilities' open interval, the
map settings' limits, and immutable sections."""

from __future__ import annotations

import pytest

from semslam.errors import ConfigError
from semslam.slam.config import GatingConfig, MapConfig, MotionConfig, OutputConfig


def test_documented_defaults():
    """Catches a changed default: the unaided velocity walk measured on the simulator's DVL logs
    (0.054, 0.021, 0.026) m/s/sqrt(s), the 10 m association radius, the RTS smoother on by default."""
    assert MotionConfig().unaided_velocity_rw_mps_per_sqrt_s == (0.054, 0.021, 0.026)
    assert MotionConfig().velocity_rw_mps_per_sqrt_s == (0.02, 0.01, 0.01)
    g = GatingConfig()
    assert g.candidate_radius_m == 10.0 and g.gate_probability == 0.99 and g.sensor_gate_probability == 0.9999
    assert OutputConfig().smooth is True


@pytest.mark.parametrize("field", ["gate_probability", "sensor_gate_probability"])
@pytest.mark.parametrize("value", [0.5, 1.0])
def test_gate_probabilities_are_in_the_open_interval(field, value):
    """Catches a closed bound in the gate-probability check: 0.5 and 1 are both rejected (a 100 % gate accepts
    everything; below 50 % it rejects most good data), naming the field values."""
    with pytest.raises(ConfigError, match=r"gate probabilities of GatingConfig must be in \(0\.5, 1\)"):
        GatingConfig(**{field: value})
    GatingConfig(**{field: 0.51})


def test_config_sections_are_immutable():
    """Catches a section that is no longer frozen (``frozen=False``): a config shared between runs must not be
    changed in place; ``updated``/``replace`` make new ones."""
    import dataclasses

    for section in (OutputConfig(), GatingConfig(), MotionConfig()):
        name = dataclasses.fields(section)[0].name
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(section, name, getattr(section, name))


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
