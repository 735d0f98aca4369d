"""The SLAM session (``semslam/slam/session.py``): the smoother's budget, the start stamp, the initial
calibration covariance, surveyed landmarks, the history epochs, the rejected-update count."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.dataset.vehicle import VehicleDescription
from semslam.slam.config import OutputConfig, SlamConfig
from semslam.slam.session import SlamSession


def _feed(session, n=20):
    for k in range(n):
        t = 0.1 * k
        session.add_attitude(t, [0.0, 0.0, 0.3])
        session.add_dvl(t + 0.05, [0.3, 0.0, 0.0])
        session.add_depth(t + 0.05, 2.0)


def test_finish_when_the_smoother_ran_out_of_budget():
    """Catches a finish step that reads the smoothed states when there are none (``sm is None and len(sm.x)``
    in the consistency check): with a smoother budget too small for even one covariance the run still
    finishes, without a smoothed trajectory, and says why."""
    cfg = SlamConfig(output=OutputConfig(smoother_max_mb=1e-6))
    s = SlamSession(VehicleDescription.girona500(), mode="dr", config=cfg)
    _feed(s)
    res = s.finish()
    assert res.smoothed_position_ned_m is None
    assert res.metrics["smoother"]["status"].startswith("skipped")
    assert len(res.position_ned_m) == len(res.stamps_s) > 0
    ok = SlamSession(VehicleDescription.girona500(), mode="dr", config=SlamConfig())
    _feed(ok)
    full = ok.finish()
    assert full.smoothed_position_ned_m.shape == full.position_ned_m.shape
    assert np.isfinite(full.smoothed_position_ned_m).all()


@pytest.mark.parametrize("stream", ["dvl", "depth"])
def test_samples_at_the_start_stamp_are_used_and_earlier_ones_skipped(stream):
    """Catches a start-stamp test that also drops the samples *at* the start (``t > t0`` for ``t >= t0``): with
    ``start_stamp_s = 1.0``, a DVL or depth sample at 0.5 s is skipped and counted
    (``metrics["skipped_before_start"] == 1``), one at exactly 1.0 s is used (accepted in the update log)."""
    s = SlamSession(VehicleDescription.girona500(), mode="dr", start_stamp_s=1.0)
    add = (lambda t: s.add_dvl(t, [0.3, 0.0, 0.0])) if stream == "dvl" else (lambda t: s.add_depth(t, 0.0))
    s.add_attitude(0.4, [0.0, 0.0, 0.0])
    add(0.5)
    s.add_attitude(1.0, [0.0, 0.0, 0.0])
    add(1.0)
    for k in range(1, 4):
        s.add_attitude(1.0 + 0.1 * k, [0.0, 0.0, 0.0])
    res = s.finish()
    assert res.metrics["skipped_before_start"] == 1
    assert [r["stamp_s"] for r in res.update_log if r["kind"] == stream] == [1.0]


def test_initial_dvl_calibration_covariance_is_the_vehicle_description():
    """Catches a wrong floor of the DVL bias prior (``max(sigma, 1.000001)`` for ``max(sigma, 1e-6)``): when the
    filter starts, the DVL bias states' variances are the vehicle's ``bias_sigma_mps ** 2`` (a stationary
    Gauss-Markov process: unchanged by the first prediction), the scale factor's and misalignment's their sigmas
    squared."""
    import numpy as np

    v = VehicleDescription.girona500()
    d = v.dvl
    assert d.bias_sigma_mps > 1e-6
    s = SlamSession(v, mode="pose", start_stamp_s=0.0)
    s.add_attitude(0.0, [0.0, 0.0, 0.0])
    s.add_attitude(0.1, [0.0, 0.0, 0.0])
    assert s.ekf is not None and s.ekf.dvl_calibration
    cal = s.ekf.indices("dvl_calibration")
    P = s.ekf.full_state()[1]
    var = np.diag(P)[cal]
    assert len(var) == 8   # bias (3), slope bias (3), scale factor, misalignment
    np.testing.assert_allclose(var[:3], d.bias_sigma_mps ** 2, rtol=1e-6)   # stationary Gauss-Markov
    np.testing.assert_allclose(var[6:8], [max(d.scale_factor_sigma, 1e-6) ** 2, max(d.misalignment_sigma_rad, 1e-6) ** 2],
                               rtol=1e-9)


def _dr(rate=None):
    from semslam.slam.config import OutputConfig, SlamConfig

    cfg = SlamConfig() if rate is None else SlamConfig(output=OutputConfig(history_rate_hz=rate))
    return SlamSession(VehicleDescription.girona500(), mode="dr", start_stamp_s=0.0, config=cfg)


def test_surveyed_landmarks_are_accepted_when_consistent_and_refused_otherwise():
    """Catches an inverted consistency check of ``add_surveyed_landmarks`` (``not not (...)``): as many names,
    labels and RigidTransform poses are accepted; a missing label is a SlamError."""
    from semslam.errors import SlamError
    from semslam.geometry import RigidTransform

    s = _dr()
    s.add_surveyed_landmarks(["v1", "v2"], ["valve", "valve"], [RigidTransform.identity()] * 2)
    with pytest.raises(SlamError, match="as many names, labels and RigidTransform poses"):
        _dr().add_surveyed_landmarks(["v1", "v2"], ["valve"], [RigidTransform.identity()] * 2)


def test_add_dvl_options_are_keyword_only():
    """Catches ``/`` for ``*`` in ``add_dvl``'s signature: ``valid`` and ``beam_range_m`` are keyword-only (a stray
    positional ``False`` must not silently invalidate a sample) and ``stamp_s`` / ``velocity_mps`` may be named."""
    s = _dr()
    s.add_attitude(0.0, [0.0, 0.0, 0.0])
    with pytest.raises(TypeError):
        s.add_dvl(0.1, [0.3, 0.0, 0.0], False)
    s.add_dvl(stamp_s=0.1, velocity_mps=[0.3, 0.0, 0.0])


def test_history_epochs_are_spaced_by_the_history_rate():
    """Catches history epochs at twice the period (``2.0 / rate``) or every other epoch skipped
    (``_next_hist += 2``): a 2 s dive at ``history_rate_hz = 5`` has its epochs every 0.2 s from the start."""
    import numpy as np

    s = _dr(5.0)
    for k in range(21):
        s.add_attitude(0.1 * k, [0.0, 0.0, 0.0])
        s.add_dvl(0.1 * k + 0.05, [0.3, 0.0, 0.0])
    res = s.finish()
    st = np.asarray(res.stamps_s)
    np.testing.assert_allclose(st[:10], 0.2 * np.arange(10), atol=1e-9)


def test_rejected_landmark_updates_count_only_landmark_records():
    """Catches ``or`` for ``and`` in the count of rejected landmark updates: a dive without any detection has 0
    rejected landmark updates, even when a DVL sample was rejected (a 10 m/s outlier)."""
    s = _dr()
    for k in range(11):
        s.add_attitude(0.1 * k, [0.0, 0.0, 0.0])
        s.add_dvl(0.1 * k + 0.05, [10.0 if k == 5 else 0.3, 0.0, 0.0])
    res = s.finish()
    assert any(r["kind"] == "dvl" and not r["accepted"] for r in res.update_log)
    assert res.metrics["landmark_updates"]["rejected"] == 0


def test_history_epoch_at_a_measurement_stamp_is_recorded_after_it():
    """Catches a history epoch recorded *before* a measurement at its own stamp (the ``not inclusive`` of
    ``_history_before`` dropped): "every history epoch before t" is recorded before the message at t, so an epoch at
    exactly a depth sample's stamp holds the state after that depth update."""
    import numpy as np

    s = _dr(5.0)
    for k in range(6):
        s.add_attitude(0.1 * k, [0.0, 0.0, 0.0])
        if k == 2:
            s.add_depth(0.2, 0.02)   # the filter starts at depth 0 (known to 1 mm)
    res = s.finish()
    i = int(np.flatnonzero(np.isclose(res.stamps_s, 0.2))[0])
    (rec,) = [r for r in res.update_log if r["kind"] == "depth"]
    assert rec["accepted"]
    assert res.position_ned_m[i, 2] > 1e-4   # the epoch at 0.2 s includes the depth update at 0.2 s
