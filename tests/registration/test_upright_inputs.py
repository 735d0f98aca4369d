"""Up directions at the limits of float: the upright search takes a direction, not a length."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.errors import RegistrationError
from semslam.registration.upright import upright_rotations


@pytest.mark.parametrize("scale", [1e308, 1e-310])
def test_an_up_direction_of_any_magnitude_gives_the_same_rotations(scale):
    """Regression: `register --up 0,-1,0 --up-target 1e308,1e308,0` ended in a cKDTree traceback ("'x' must be
    finite"): the norm of (1e308, 1e308, 0) overflows to inf and the normalised direction became (0, 0, nan).
    A subnormal direction (1e-310) underflowed the other way. Both must give the rotations of (1, 1, 0)."""
    ref = upright_rotations([0.0, -1.0, 0.0], [1.0, 1.0, 0.0])
    got = upright_rotations([0.0, -scale, 0.0], [scale, scale, 0.0])
    assert np.isfinite(got).all()
    np.testing.assert_allclose(got, ref, atol=1e-12)
    up = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    np.testing.assert_allclose(got @ np.array([0.0, -1.0, 0.0]), np.broadcast_to(up, (len(got), 3)), atol=0.2)


def test_a_zero_up_direction_is_a_clear_error():
    with pytest.raises(RegistrationError, match="'up_object' argument of upright_rotations must be a non-zero 3-vector"):
        upright_rotations([0.0, 1.0, 0.0], [0.0, 0.0, 0.0])
