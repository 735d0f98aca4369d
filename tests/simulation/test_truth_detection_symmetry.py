"""Truth-based detections of a symmetric class report any of its equivalent orientations, as a pose estimator
would: a plain cylinder (``continuous:z:flip``) either end first."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.simulation.detections import TruthDetectionConfig, _noisy
from semslam.symmetry import Symmetry


def test_a_cylinders_truth_detections_come_from_either_end_and_stay_equivalent():
    rng = np.random.default_rng(0)
    R_true = Rotation.from_euler("zyx", [0.3, 0.2, -0.1]).as_matrix()
    config = TruthDetectionConfig()
    for sym, both_ends in ((Symmetry("continuous", [0, 0, 1], flip=True), True),
                           (Symmetry("continuous", [0, 0, 1]), False)):
        signs = []
        for _ in range(200):
            det = _noisy(R_true, np.array([0.0, 0.0, 2.0]), "rod", sym, config, rng, 0.0, 0, {})
            R = det.T_sensor_object.rotation
            assert sym.rotation_error_rad(R, R_true) < 6 * config.rotation_sigma_rad + 1e-9
            signs.append(np.sign((R @ sym.axis_object) @ (R_true @ sym.axis_object)))
        n_reversed = sum(s < 0 for s in signs)
        assert (60 < n_reversed < 140) if both_ends else n_reversed == 0, n_reversed
