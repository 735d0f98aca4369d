"""Tests that kill surviving mutants of ``semslam/slam/runner.py`` (benchmarks/mutation.py): a dataset without
ground truth."""

from __future__ import annotations

from dataclasses import replace

from semslam.experiments.synthetic import square_mission
from semslam.slam import run_slam


def test_run_without_ground_truth_starts_at_the_first_attitude():
    """Catches an inverted "has truth" test in the run's start (``not dataset.truth is not None``: the truth's first
    stamp read from a dataset that has none): a dataset without truth runs, from its first attitude sample, and its
    result has no truth trajectory."""
    m = replace(square_mission(seed=3, loops=1), truth=None)
    r = run_slam(m, {}, mode="dr", seed=3)
    assert r.stamps_s[0] == m.attitude.stamp_s[0]
    assert r.truth_position_ned_m is None and "ate_rmse_m" not in r.metrics


def test_run_without_ground_truth_starts_at_the_origin():
    """Catches a launch-point perturbation applied without ground truth (``or`` for ``and``: the origin moved by a
    random fix error): without truth the run's first epoch is exactly the origin (and its velocity that of the
    first valid DVL sample)."""
    import numpy as np

    m = replace(square_mission(seed=3, loops=1), truth=None)
    r = run_slam(m, {}, mode="dr", seed=3)
    assert r.config.initialisation.perturb_initial_position
    np.testing.assert_array_equal(r.position_ned_m[0], np.zeros(3))
    first = int(np.flatnonzero(m.dvl.valid)[0])
    np.testing.assert_allclose(r.velocity_body_mps[0], m.dvl.velocity_body_mps[first], atol=0.02)
    assert np.trace(r.velocity_cov[0]) < 3 * 0.05 ** 2 + 1e-9   # known to initial_velocity_sigma_mps, not unknown


def test_simulated_survey_errors_are_zero_mean_at_the_survey_sigma():
    """Catches a biased simulated survey (``rng.normal(1.0, ...)``: every surveyed orientation off by ~1.7 rad): the
    surveyed poses differ from the true object poses by errors of the configured sigmas (here all rotation errors
    below 5 sigma sqrt(3), position errors below 5 sigma sqrt(3))."""
    import numpy as np

    from semslam.slam import SlamConfig
    from semslam.slam.runner import _surveyed

    m = square_mission(seed=3, loops=1)
    names = [o.name for o in m.objects]
    cfg = SlamConfig().updated(surveyed_objects=tuple(names))
    _, labels, poses = _surveyed(m, cfg, np.random.default_rng(0))
    sr, sp = cfg.initialisation.survey_rotation_sigma_rad, cfg.initialisation.survey_position_sigma_m
    for o, T in zip(m.objects, poses):
        dR = T.rotation @ o.T_world_object.rotation.T
        ang = np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1))
        assert ang < 5 * sr * np.sqrt(3)
        assert np.linalg.norm(T.translation_m - o.T_world_object.translation_m) < 5 * sp * np.sqrt(3)
    assert labels == [o.label for o in m.objects]


def test_messages_at_one_stamp_come_in_the_documented_order():
    """Catches processing-order keys that tie two kinds (attitude with DVL, depth with detections: the order then
    follows the sample indices): at a stamp shared by every stream the messages come as attitude, DVL, depth,
    detections, whatever their indices."""
    import numpy as np

    from semslam.slam.runner import merged_messages

    m = square_mission(seed=3, loops=1)   # attitude at 20 Hz, depth at 10 Hz, DVL at 5 Hz: 0.4 s is in all three
    t = float(m.dvl.stamp_s[2])
    assert t == m.attitude.stamp_s[8] == m.depth.stamp_s[4]   # indices 8 > 2 and 4 > 0: a tie would misorder them
    from semslam.detection import Detection
    from semslam.geometry import RigidTransform

    det = Detection("valve", 0.9, RigidTransform.identity(), np.eye(6) * 1e-4, stamp_s=t)
    kinds = [k for s, k, _ in merged_messages(m, {0: [det]}) if s == t]
    assert kinds == ["attitude", "dvl", "depth", "detections"]


def test_initial_velocity_is_the_first_valid_dvl_sample_near_the_start(monkeypatch):
    """Catches a wrong choice of the initial velocity (a DVL sample searched before the start, ``|`` for ``&``
    (an invalid sample taken), or ``not len(valid)``): ``run_slam`` starts the filter with the first *valid* DVL
    velocity when that sample is within ``unaided_after_s`` of the start, and with an unknown velocity (None)
    when the DVL starts later."""
    import numpy as np

    from semslam.slam import runner

    seen = []

    class Spy(runner.SlamSession):
        def __init__(self, vehicle, **kw):
            seen.append(kw["initial_velocity_body_mps"])
            super().__init__(vehicle, **kw)

    monkeypatch.setattr(runner, "SlamSession", Spy)
    m = square_mission(seed=3, loops=1)
    valid = m.dvl.valid.copy()
    valid[0] = False   # the first sample is invalid: the second one is the start's velocity
    m1 = replace(m, dvl=replace(m.dvl, valid=valid))
    run_slam(replace(m1, truth=None), {}, mode="dr", seed=3)
    np.testing.assert_array_equal(seen[-1], m.dvl.velocity_body_mps[1])
    late = replace(m.dvl, stamp_s=m.dvl.stamp_s + 100.0)   # the DVL starts 100 s after the attitude
    run_slam(replace(m, dvl=late, truth=None), {}, mode="dr", seed=3)
    assert seen[-1] is None


def test_default_seed_is_zero():
    """Catches a changed default seed (``seed=1``): ``run_slam`` without a seed is the documented ``seed=0`` run,
    bit for bit (the launch fix error is drawn from it)."""
    import numpy as np

    m = square_mission(seed=3, loops=1)
    a, b, c = run_slam(m, {}, mode="dr"), run_slam(m, {}, mode="dr", seed=0), run_slam(m, {}, mode="dr", seed=1)
    np.testing.assert_array_equal(a.position_ned_m, b.position_ned_m)
    assert not np.array_equal(a.position_ned_m, c.position_ned_m)
