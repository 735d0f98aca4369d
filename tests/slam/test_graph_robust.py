"""Robustness of the graph backends to outlier detections (issue 17): the seeded corruption of a run's detections
(:mod:`semslam.experiments.outliers`), the accounting of the outliers the gate lets through, and the Huber graph on
a mission whose displaced detections pass the gate.

Bugs caught: a corruption that is not reproducible from its seed, corrupts another fraction than stated or modifies
its input; an outlier count that matches the update log wrongly (each detection leaves exactly one record:
accepted, rejected or candidate); a ``huber_k`` that never reaches the detection factors (the Huber graph would
equal the Gaussian one); a robust graph whose end-of-dive ATE with 10 % accepted-in-gate outliers leaves the
issue's 1.2x of its clean run. One simulated mission (~70 s of dive, 114 detections): a few seconds in all.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gtsam", reason="the graph backends need GTSAM (pip install gtsam)")

from semslam._validation import as_rng  # noqa: E402
from semslam.errors import InputError  # noqa: E402
from semslam.experiments.montecarlo import make_dataset  # noqa: E402
from semslam.experiments.outliers import corrupt_detections, outlier_usage  # noqa: E402
from semslam.simulation.detections import simulate_detections  # noqa: E402
from semslam.simulation.truth_slam import builtin_symmetries, truth_detection_config  # noqa: E402
from semslam.run import run_slam

#: displaced by 1-3 cm and rotated 3-6 deg: about half pass the 99 % gate on this mission (0.3 m: none does)
IN_GATE = dict(kind="displaced", translation_m=(0.01, 0.03), rotation_deg=(3.0, 6.0))


@pytest.fixture(scope="module")
def case():
    mission = make_dataset(0)
    sym = builtin_symmetries()
    dets = simulate_detections(mission, truth_detection_config(mission), seed=as_rng(0), symmetries=sym)
    return mission, sym, dets


def _n(dets) -> int:
    return sum(len(v) for v in dets.values())


def _poses(dets):
    return [(d.label, d.T_sensor_object.matrix.copy()) for sid in sorted(dets) for d in dets[sid]]


def test_corruption_is_seeded_exact_and_leaves_input(case):
    _, _, dets = case
    before = _poses(dets)
    a, ra = corrupt_detections(dets, fraction=0.1, kind="mixed", seed=5)
    b, rb = corrupt_detections(dets, fraction=0.1, kind="mixed", seed=np.random.default_rng(5))
    c, rc = corrupt_detections(dets, fraction=0.1, kind="mixed", seed=6)
    assert ra == rb and all(x[0] == y[0] and np.array_equal(x[1], y[1]) for x, y in zip(_poses(a), _poses(b)))
    assert [r[:2] for r in rc] != [r[:2] for r in ra]
    assert len(ra) == round(0.1 * _n(dets)) and _n(a) == _n(dets)
    assert {k for _, _, k in ra} == {"displaced", "wrong_class"}
    after = _poses(dets)  # the input is untouched
    assert all(x[0] == y[0] and np.array_equal(x[1], y[1]) for x, y in zip(before, after))
    changed = 0
    for sid, k, kind in ra:
        old, new = dets[sid][k], a[sid][k]
        assert new.extras["outlier"] == kind and "outlier" not in old.extras
        if kind == "wrong_class":
            assert new.label != old.label
        else:
            dt = np.linalg.norm(new.T_sensor_object.translation_m - old.T_sensor_object.translation_m)
            R = new.T_sensor_object.rotation @ old.T_sensor_object.rotation.T
            ang = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
            assert 0.3 - 1e-9 <= dt <= 0.5 + 1e-9 and 20 - 1e-6 <= ang <= 40 + 1e-6
        changed += 1
    assert changed == sum("outlier" in d.extras for v in a.values() for d in v)
    with pytest.raises(InputError):
        corrupt_detections(dets, fraction=1.5)
    with pytest.raises(InputError):
        corrupt_detections(dets, kind="bogus")


def test_huber_graph_with_in_gate_outliers(case):
    mission, sym, dets = case
    bad, rec = corrupt_detections(dets, fraction=0.1, seed=10_000, **IN_GATE)
    kw = dict(mode="pose", symmetries=sym)
    clean = run_slam(mission, dets, backend="isam2", huber_k=2.0, **kw)
    robust = run_slam(mission, bad, backend="isam2", huber_k=2.0, **kw)
    gauss = run_slam(mission, bad, backend="isam2", **kw)
    u = outlier_usage(robust, bad)
    assert u["n_outliers"] == len(rec) == round(0.1 * _n(dets))
    # every detection leaves one record: accepted (a factor), rejected, or a landmark candidate
    assert u["accepted"] + u["rejected"] + u["candidates"] == u["n_outliers"]
    assert u["accepted"] >= 2  # outliers really reach the graph (not all gated out)
    assert outlier_usage(clean, dets)["n_outliers"] == 0
    end = lambda r: r.metrics["smoother"]["ate_rmse_m"]  # noqa: E731
    assert robust.metrics["graph"]["huber_k"] == 2.0
    assert abs(end(robust) - end(gauss)) > 1e-5  # the kernel reaches the detection factors
    assert end(robust) <= 1.2 * end(clean)  # the goal, on this mission
