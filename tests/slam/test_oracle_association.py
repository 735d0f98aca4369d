"""Oracle tests of data association (issue 20, item 1-2): global nearest neighbour against brute force,
JCBB on constructed scenes whose jointly compatible answer is known, and the innovation's gate distance
against a dense recomputation."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from semslam.detection import Detection
from semslam.geometry import RigidTransform, rotation_from_rpy
from semslam.slam.association import (GateThresholds, associate, associate_jcbb, innovation,
                                      measurement_from_detection)
from semslam.slam.ekf import SemanticEkf

GATE3 = GateThresholds(0.99).threshold(3)


# ------------------------------------------------------------------------------ associate (GNN)
def test_two_detections_near_one_landmark_nearest_wins():
    """Catches an association that gives one landmark to two detections, or keeps the farther one: two
    detections gate with the only landmark, the nearer (smaller d2) gets it and the other stays free."""
    d2 = np.array([[3.0], [0.4]])
    gate = d2 <= GATE3
    assert associate(d2, gate) == [(1, 0)]


def test_missing_landmark_and_clutter():
    """Catches clutter (a detection outside every gate) being forced onto a landmark, and a missing
    (unobserved) landmark receiving a detection: meas 0 -> lm 2, meas 1 -> lm 0, meas 2 is clutter, lm 1 unseen."""
    d2 = np.array([[40.0, 30.0, 0.5],
                   [1.2, 25.0, 60.0],
                   [900.0, 800.0, 700.0]])
    gate = d2 <= GATE3
    assert not gate[2].any()
    assert sorted(associate(d2, gate)) == [(0, 2), (1, 0)]
    assert associate(np.zeros((0, 3)), np.zeros((0, 3), dtype=bool)) == []
    # a pair outside the gate is never returned even when it is the only possibility
    assert associate(np.array([[50.0]]), np.array([[False]])) == []


def test_global_not_greedy_assignment():
    """Catches a greedy nearest-neighbour association in place of the global one: greedily meas 0 takes lm 0
    (d2 1.0) and meas 1 is left with lm 1 (d2 9.0, total 10); the global optimum is the crossed pairing (4)."""
    d2 = np.array([[1.0, 2.0],
                   [2.0, 9.0]])
    gate = d2 <= GATE3
    assert sorted(associate(d2, gate)) == [(0, 1), (1, 0)]


def _brute_force(d2, gate):
    """Every partial matching of gated pairs: most pairs first, then the smallest summed d2."""
    n, m = d2.shape
    best = (0, 0.0, [])
    for perm in itertools.permutations(range(max(n, m)), n):
        pairs = [(i, j) for i, j in enumerate(perm) if j < m and gate[i, j]]
        cost = sum(d2[i, j] for i, j in pairs)
        if len(pairs) > best[0] or (len(pairs) == best[0] and cost < best[1] - 1e-12):
            best = (len(pairs), cost, sorted(pairs))
    return best


def test_associate_matches_brute_force_on_random_scenes():
    """Catches any deviation from "most gated pairs, then the least summed squared Mahalanobis distance" (e.g.
    the 1e12 out-of-gate cost too small, gated pairs dropped, or an un-gated pair kept), against exhaustive
    enumeration on 300 seeded random scenes of up to 4 x 4."""
    rng = np.random.default_rng(20)
    for _ in range(300):
        n, m = rng.integers(1, 5, size=2)
        d2 = rng.chisquare(3, size=(n, m)) * rng.uniform(0.5, 4.0)
        gate = d2 <= GATE3
        got = associate(d2, gate)
        n_best, cost_best, _ = _brute_force(d2, gate)
        assert all(gate[i, j] for i, j in got)
        assert len({i for i, _ in got}) == len(got) == len({j for _, j in got})
        assert len(got) == n_best
        assert sum(d2[i, j] for i, j in got) == pytest.approx(cost_best, rel=1e-12, abs=1e-12)


# ------------------------------------------------------------------------------ JCBB on a real filter
def _scene(landmarks_x, vehicle_sigma=1.0, landmark_sigma=0.02):
    """A filter whose vehicle position is poorly known (sigma 1 m) and three surveyed landmarks on the x axis
    known to 2 cm (their relative positions are precise, the vehicle's is not)."""
    P0 = np.diag([vehicle_sigma**2] * 3 + [0.01] * 3)
    ekf = SemanticEkf(np.zeros(3), np.zeros(3), P0)
    poses = np.array([[x, 0.0, 0.0, 0.0, 0.0, 0.0] for x in landmarks_x])
    covs = np.array([np.diag([landmark_sigma**2] * 3 + [0.01] * 3)] * len(poses))
    ekf.add_prior_landmarks(poses, covs, ["valve"] * len(poses))
    return ekf


def _measure(p_vehicle_object, sigma=0.01):
    cov = np.diag([sigma**2] * 3 + [0.05**2] * 3)
    det = Detection("valve", 0.0, RigidTransform.from_rotation_translation(np.eye(3), p_vehicle_object), cov)
    return measurement_from_detection(det, RigidTransform.identity())


def _innovations(ekf, meas):
    inns, d2 = {}, np.full((len(meas), len(ekf.landmarks)), np.inf)
    for i, z in enumerate(meas):
        for j in range(len(ekf.landmarks)):
            inn = innovation(ekf, j, z, np.eye(3), None)
            inns[(i, j)] = inn
            d2[i, j] = inn.d2_position
    return inns, d2


def test_jcbb_finds_the_jointly_compatible_set_where_nearest_neighbour_fails():
    """Catches a JCBB that tests the pairs individually (no joint covariance: the shared vehicle error is
    ignored) or that prefers the smallest summed individual d2: the vehicle is 1.2 m off in x; landmarks at
    x = 0, 2, 3 are seen at 1.2 and 3.2. Individually nearest: meas 0 -> lm 1 (0.8 m), meas 1 -> lm 2 (0.2 m),
    also what GNN picks, but their innovations (-0.8 and +0.2 m) disagree by 1 m while the landmarks' relative
    positions are known to 3 cm. The only jointly compatible pairing is meas 0 -> lm 0, meas 1 -> lm 1
    (both innovations +1.2 m: one common vehicle error)."""
    ekf = _scene([0.0, 2.0, 3.0])
    meas = [_measure([1.2, 0.0, 0.0]), _measure([3.2, 0.0, 0.0])]
    inns, d2 = _innovations(ekf, meas)
    gate = d2 <= GATE3
    nearest = [(i, int(np.argmin(d2[i]))) for i in range(len(meas))]
    assert nearest == [(0, 1), (1, 2)]
    assert sorted(associate(d2, gate)) == [(0, 1), (1, 2)]  # GNN falls for it too
    jc = associate_jcbb(inns, ekf, len(meas), gate, 0.99)
    assert sorted(jc) == [(0, 0), (1, 1)]
    # the oracle's own joint test: the NN hypothesis is jointly incompatible, the JCBB one compatible
    assert _joint_d2(ekf, inns, [(0, 1), (1, 2)]) > GateThresholds(0.99).threshold(6)
    assert _joint_d2(ekf, inns, [(0, 0), (1, 1)]) < GateThresholds(0.99).threshold(6)


def _joint_d2(ekf, inns, pairs):
    """Stacked position innovation against its dense joint covariance (built here from the full state)."""
    x, P = ekf.full_state()
    H = np.zeros((3 * len(pairs), len(x)))
    nu, blocks = [], []
    for r, p in enumerate(pairs):
        H[3 * r:3 * r + 3, inns[p].idx] = inns[p].H[:3]
        nu.append(inns[p].nu[:3])
        blocks.append(inns[p].R[:3, :3])
    R = np.zeros((len(H), len(H)))
    for r, b in enumerate(blocks):
        R[3 * r:3 * r + 3, 3 * r:3 * r + 3] = b
    nu = np.concatenate(nu)
    return float(nu @ np.linalg.solve(H @ P @ H.T + R, nu))


def test_jcbb_rejects_clutter_and_leaves_missing_landmark():
    """Catches JCBB pairing a clutter detection (in no gate) or inventing a pairing for a landmark that was not
    seen: landmarks at x = 0, 2, 3, vehicle 0.3 m off; detections of lm 0 and lm 2 plus one far clutter."""
    ekf = _scene([0.0, 2.0, 3.0])
    meas = [_measure([0.3, 0.0, 0.0]), _measure([3.3, 0.0, 0.0]), _measure([0.0, 9.0, 4.0])]
    inns, d2 = _innovations(ekf, meas)
    gate = d2 <= GATE3
    assert not gate[2].any()
    jc = associate_jcbb(inns, ekf, len(meas), gate, 0.99)
    assert sorted(jc) == [(0, 0), (1, 2)]
    assert sorted(associate(d2, gate)) == [(0, 0), (1, 2)]


def test_jcbb_drops_clutter_that_passes_its_individual_gate():
    """Catches a JCBB without the joint chi-square test (or with it at the wrong dof), which would maximise the
    number of pairings with individually gated ones: the vehicle is 1.2 m off in x, landmarks at x = 0, 2, 5;
    lm 0 and lm 1 are seen at 1.2 and 3.2, and a clutter detection at 4.0 gates individually with lm 2
    (innovation -1 m against a 1 m vehicle sigma) but contradicts the common +1.2 m shift. The answer keeps
    two pairs and leaves the clutter out."""
    ekf = _scene([0.0, 2.0, 5.0])
    meas = [_measure([1.2, 0.0, 0.0]), _measure([3.2, 0.0, 0.0]), _measure([4.0, 0.0, 0.0])]
    inns, d2 = _innovations(ekf, meas)
    gate = d2 <= GATE3
    assert gate[2, 2]  # individually compatible
    assert _joint_d2(ekf, inns, [(0, 0), (1, 1), (2, 2)]) > GateThresholds(0.99).threshold(9)
    assert sorted(associate_jcbb(inns, ekf, len(meas), gate, 0.99)) == [(0, 0), (1, 1)]


def test_jcbb_two_detections_of_one_landmark():
    """Catches JCBB assigning one landmark twice: two detections 5 cm apart of the one landmark in range,
    the nearer one (joint d2 smallest) is kept."""
    ekf = _scene([0.0, 6.0, 12.0])
    meas = [_measure([0.10, 0.0, 0.0]), _measure([0.05, 0.0, 0.0])]
    inns, d2 = _innovations(ekf, meas)
    gate = d2 <= GATE3
    assert gate[:, 0].all() and not gate[:, 1:].any()
    assert associate_jcbb(inns, ekf, len(meas), gate, 0.99) == [(1, 0)]
    assert associate(d2, gate) == [(1, 0)]


def test_jcbb_matches_brute_force_joint_compatibility():
    """Catches a branch-and-bound that prunes a better hypothesis: on seeded random scenes (5 landmarks, 3
    detections, a shared vehicle offset) the returned set has the most pairs among jointly compatible
    hypotheses (joint test at 99 %, recomputed densely here), then the least joint d2."""
    rng = np.random.default_rng(4)
    n_gnn_wrong = 0
    for trial in range(12):
        xs = np.sort(rng.uniform(-3.0, 3.0, 5))
        ekf = _scene(xs, vehicle_sigma=0.7)
        offset = rng.normal(0.0, 0.7, 3)
        seen = rng.choice(5, 3, replace=False)
        meas = [_measure(np.array([xs[j], 0.0, 0.0]) - offset + rng.normal(0.0, 0.02, 3)) for j in seen]
        inns, d2 = _innovations(ekf, meas)
        gate = d2 <= GATE3
        got = associate_jcbb(inns, ekf, len(meas), gate, 0.99)
        best = (0, np.inf, [])
        for choice in itertools.product(*[[None] + list(np.flatnonzero(gate[i])) for i in range(len(meas))]):
            pairs = [(i, int(j)) for i, j in enumerate(choice) if j is not None]
            if len({j for _, j in pairs}) < len(pairs):
                continue
            jd2 = _joint_d2(ekf, inns, pairs) if pairs else 0.0
            if pairs and jd2 > GateThresholds(0.99).threshold(3 * len(pairs)):
                continue
            if len(pairs) > best[0] or (len(pairs) == best[0] and jd2 < best[1]):
                best = (len(pairs), jd2, sorted(pairs))
        assert sorted(got) == best[2], trial
        assert best[0] == 3  # every detection is of a real landmark: all found
        assert sorted(got) == [(i, int(j)) for i, j in enumerate(seen)], trial  # and here it is the truth
        n_gnn_wrong += sorted(associate(d2, gate)) != sorted(got)
    assert n_gnn_wrong >= 4  # the scenes are ambiguous enough that individual gating alone goes wrong


# ------------------------------------------------------------------------------ innovation and its d2
def test_innovation_position_rows_against_dense_formula():
    """Catches a wrong position measurement model or Jacobian (``R`` instead of ``R^T``, a sign) and a gate
    distance computed with the wrong ``S``: ``nu = z - R^T (l - p)``, ``H = [-R^T, 0, R^T]``, and
    ``d2 = nu^T (H P H^T + N)^-1 nu`` against the full dense covariance; the Jacobian against finite differences."""
    rng = np.random.default_rng(9)
    A = rng.normal(size=(6, 6)) * 0.2
    ekf = SemanticEkf([1.0, -2.0, 3.0], [0.3, 0.1, 0.0], A @ A.T + 0.01 * np.eye(6))
    G = np.zeros((6, 6))
    G[0:3, 0:3] = np.eye(3)
    ekf.add_landmark(np.r_[4.0, 1.0, 5.0, 0.1, -0.2, 0.3], G, np.diag([0.04] * 3 + [0.01] * 3), label="valve",
                     stamp_s=0.0)
    R_wv = rotation_from_rpy(0.1, -0.05, 2.0)
    z = np.array([1.5, -0.7, 2.1])
    cov = np.diag([1e-3] * 3 + [1e-3] * 3)
    det = Detection("valve", 0.0, RigidTransform.from_rotation_translation(rotation_from_rpy(0.1, -0.2, 0.3), z), cov)
    meas = measurement_from_detection(det, RigidTransform.identity())
    inn = innovation(ekf, 0, meas, R_wv, None)
    x, P = ekf.full_state()
    p, l = x[0:3], x[6:9]
    np.testing.assert_allclose(inn.nu[:3], z - R_wv.T @ (l - p), atol=1e-12)

    def h(xx):
        return R_wv.T @ (xx[6:9] - xx[0:3])

    J = np.zeros((3, len(x)))
    for k in range(len(x)):
        e = np.zeros(len(x))
        e[k] = 1e-6
        J[:, k] = (h(x + e) - h(x - e)) / 2e-6
    Hfull = np.zeros((inn.H.shape[0], len(x)))
    Hfull[:, inn.idx] = inn.H
    np.testing.assert_allclose(Hfull[:3], J, atol=1e-8)
    S3 = J @ P @ J.T + inn.R[:3, :3]
    assert inn.d2_position == pytest.approx(float(inn.nu[:3] @ np.linalg.inv(S3) @ inn.nu[:3]), rel=1e-9)
    S = Hfull @ P @ Hfull.T + inn.R
    np.testing.assert_allclose(inn.S, S, rtol=1e-12, atol=1e-14)
    assert inn.d2_pose == pytest.approx(float(inn.nu @ np.linalg.inv(S) @ inn.nu), rel=1e-9)
    np.testing.assert_allclose(inn.R[:3, :3], cov[:3, :3], atol=1e-15)  # identity mount, no AHRS noise
