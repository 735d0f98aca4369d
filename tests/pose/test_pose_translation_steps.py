"""The translation-only steps of the pose search (``PoseConfig.translation_steps_m``): a start off the true
translation along a plate is pulled in only by the points off the plate (a tube, a post), by the mean offset of all
the points each step, so it needs more than one step per truncation (a border-cut torque-tool receptacle, mostly
plate, ended 26 mm off at its true orientation with one step each: benchmarks/history/real-models.md, session 28)."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.errors import InputError
from semslam.pose import PoseConfig
from semslam.pose import _search_kernels as K
from semslam.pose.search_index import DistanceField

DOUBLED_STEPS_M = (0.03, 0.03, 0.015, 0.015, 0.008, 0.008, 0.006)


@pytest.fixture(scope="module")
def plate_and_post():
    """A 28 x 28 cm plate (z = 0) with a 16 x 16 cm post 15 cm tall at its centre (the torque-tool receptacle's
    plate and tube), sampled every 4 mm on its top faces and the post's sides: the points (object frame) and their
    distance field."""
    g = np.arange(-0.14, 0.14 + 1e-9, 0.004)
    x, y = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    plate = np.c_[x, y, np.zeros_like(x)]
    plate = plate[(np.abs(plate[:, 0]) > 0.08) | (np.abs(plate[:, 1]) > 0.08)]
    s = np.arange(-0.08, 0.08 + 1e-9, 0.004)
    h = np.arange(0.0, 0.15 + 1e-9, 0.004)
    a, b = (v.ravel() for v in np.meshgrid(s, h, indexing="ij"))
    sides = [np.c_[a, np.full_like(a, c), b] for c in (-0.08, 0.08)] + [np.c_[np.full_like(a, c), a, b]
                                                                        for c in (-0.08, 0.08)]
    u, v = (w.ravel() for w in np.meshgrid(s, s, indexing="ij"))
    top = np.c_[u, v, np.full_like(u, 0.15)]
    pts = np.vstack([plate, *sides, top])
    return pts, DistanceField.build(pts, n_index=1)


def _aligned_offset_m(pts, field, start_offset, truncations):
    """Where the scan of the object (its own points) ends after the search's steps from ``start_offset`` (m)."""
    R = np.eye(3)[None]
    t = np.asarray(start_offset, dtype=np.float64)[None].copy()
    K.align_and_score(R, t, pts, field.params, field.cell_m, field.offsets, np.asarray(truncations[:-2]), 0.006)
    K.align_and_score(R, t, pts, field.params, field.cell_m, field.offsets, np.asarray(truncations[-2:]), 0.006)
    return float(np.linalg.norm(t[0]))


@pytest.mark.parametrize("start", [(0.025, 0.0, 0.0), (0.018, -0.018, 0.0), (0.0, 0.028, 0.004)])
def test_two_steps_per_truncation_pull_a_start_off_along_the_plate_onto_the_post(plate_and_post, start):
    pts, field = plate_and_post
    assert _aligned_offset_m(pts, field, start, PoseConfig(translation_steps_m=DOUBLED_STEPS_M).translation_steps_m) \
        < 0.005


def test_the_default_single_steps_stop_short_on_the_same_starts(plate_and_post):
    """Why the option exists (so the test above is not met by any schedule): one step per truncation leaves the same
    starts 13-20 mm off."""
    pts, field = plate_and_post
    for start in [(0.025, 0.0, 0.0), (0.018, -0.018, 0.0), (0.0, 0.028, 0.004)]:
        assert _aligned_offset_m(pts, field, start, PoseConfig().translation_steps_m) > 0.010


@pytest.mark.parametrize("steps", [(0.03, 0.008), (0.03, 0.0, 0.006), (0.008, 0.03, 0.006), (0.03, float("nan"), 0.006),
                                   "0.03", (0.03, True, 0.006)])
def test_a_schedule_that_is_too_short_widening_or_not_positive_is_refused(steps):
    with pytest.raises(InputError, match="translation_steps_m"):
        PoseConfig(translation_steps_m=steps)


def test_the_schedule_is_given_to_the_search(monkeypatch):
    """``estimate_object_pose`` hands ``translation_steps_m`` to the search (as floats, from a TOML list)."""
    import semslam.pose.estimate as estimate

    seen = {}

    def spy(*args, **kwargs):
        seen["truncations_m"] = kwargs["truncations_m"]
        raise RuntimeError("stop here")

    monkeypatch.setattr(estimate, "search_hypotheses", spy)
    from semslam.pose import estimate_object_pose, prepare_pose_model

    g = np.linspace(-0.05, 0.05, 11)
    model_pts = np.c_[np.repeat(g, 11), np.tile(g, 11), np.zeros(121)]
    cfg = PoseConfig(translation_steps_m=[0.02, 0.02, 0.01, 0.006])
    model = prepare_pose_model(model_pts, cfg)
    with pytest.raises(RuntimeError, match="stop here"):
        estimate_object_pose(model_pts + [0.0, 0.0, 1.0], model, config=cfg, seed=0)
    assert seen["truncations_m"] == (0.02, 0.02, 0.01, 0.006)
