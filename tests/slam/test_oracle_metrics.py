"""Oracle tests of the consistency metrics and chi-square gates (issue 20, item 1).

Every expected value is computed here independently (scipy.stats, closed forms, hand arithmetic), never by
calling the function under test twice.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2, norm

from semslam.slam import _ekf_kernels as kern
from semslam.slam.association import GateThresholds
from semslam.evaluation.metrics import anees, chi2_band, nees, trajectory_metrics
from semslam.slam.consistency import nis_summary


# ---------------------------------------------------------------------------------------------- chi2_band
@pytest.mark.parametrize("dof", [1, 2, 3, 6])
@pytest.mark.parametrize("n", [1, 7, 50])
@pytest.mark.parametrize("probability", [0.95, 0.99])
def test_chi2_band_matches_scipy(dof, n, probability):
    """Catches a band built with the wrong dof (``dof`` instead of ``dof * n``), a missing ``/ n``, one-sided
    tails (``1 - p`` instead of ``(1 - p) / 2``) or swapped limits: the band of the mean of ``n`` chi2(dof)
    variables is ``[chi2.ppf(a/2, n dof) / n, chi2.ppf(1 - a/2, n dof) / n]`` with ``a = 1 - p``."""
    a = 1.0 - probability
    lo, hi = chi2_band(dof, n, probability)
    assert lo == pytest.approx(chi2.ppf(a / 2, dof * n) / n, rel=1e-12)
    assert hi == pytest.approx(chi2.ppf(1 - a / 2, dof * n) / n, rel=1e-12)
    assert lo < dof < hi  # the mean of a chi2(dof) is dof


def test_chi2_band_hand_values():
    """Catches any mistake in the band against printed chi-square tables and closed forms: chi2(3) 95 %
    interval [0.2158, 9.348]; chi2(2) has CDF ``1 - exp(-x/2)`` so its quantiles are ``-2 ln(1 - q)``;
    chi2(1) quantiles are squared normal quantiles; the band narrows towards ``dof`` as ``n`` grows."""
    lo, hi = chi2_band(3, 1)
    assert lo == pytest.approx(0.2158, abs=1e-4) and hi == pytest.approx(9.3484, abs=1e-4)
    lo, hi = chi2_band(2, 1, 0.95)
    assert lo == pytest.approx(-2.0 * math.log(1.0 - 0.025), rel=1e-10)
    assert hi == pytest.approx(-2.0 * math.log(0.025), rel=1e-10)
    lo, hi = chi2_band(1, 1, 0.90)
    assert lo == pytest.approx(norm.ppf(0.525) ** 2, rel=1e-8)
    assert hi == pytest.approx(norm.ppf(0.975) ** 2, rel=1e-8)  # 1.96^2
    assert hi == pytest.approx(1.959964**2, rel=1e-6)
    # 50 runs of a 3-dof NEES: the ANEES band [2.36, 3.72]
    lo, hi = chi2_band(3, 50)
    assert lo == pytest.approx(2.3597, abs=1e-3) and hi == pytest.approx(3.7160, abs=1e-3)
    widths = [np.diff(chi2_band(3, n))[0] for n in (1, 10, 100, 1000)]
    assert all(w1 > w2 for w1, w2 in zip(widths, widths[1:]))


# ------------------------------------------------------------------------------------------ gates
@pytest.mark.parametrize("probability", [0.9, 0.95, 0.99, 0.999])
def test_gate_threshold_is_chi2_quantile(probability):
    """Catches a gate at the wrong tail (``ppf(1 - p)``), the wrong dof (off by one) or a gate on the
    Mahalanobis distance instead of its square: ``threshold(d) == chi2.ppf(p, d)`` for d = 1..6."""
    gate = GateThresholds(probability)
    for d in range(1, 7):
        assert gate.threshold(d) == pytest.approx(chi2.ppf(probability, d), rel=1e-12)
    # closed forms: d = 2 is an exponential, d = 1 a squared normal
    assert gate.threshold(2) == pytest.approx(-2.0 * math.log(1.0 - probability), rel=1e-10)
    assert gate.threshold(1) == pytest.approx(norm.ppf(0.5 + probability / 2) ** 2, rel=1e-8)


def test_gate_threshold_table_values():
    """Catches a wrong default probability: the default gate is the 99 % chi-square table."""
    table = [6.635, 9.210, 11.345, 13.277, 15.086, 16.812]
    gate = GateThresholds()
    for d, t in enumerate(table, start=1):
        assert gate.threshold(d) == pytest.approx(t, abs=1e-3)


# ------------------------------------------------------------------------------------------ mahalanobis2
def _random_spd(rng, d, cond):
    Q, _ = np.linalg.qr(rng.normal(size=(d, d)))
    w = np.logspace(0.0, -math.log10(cond), d) * rng.uniform(0.5, 2.0)
    return (Q * w) @ Q.T


@pytest.mark.parametrize("cond", [1.0, 1e3, 1e8, 1e11])
def test_mahalanobis2_matches_dense_inverse(cond):
    """Catches a distance without the inverse (``nu @ S @ nu``), a Cholesky factor used the wrong way round
    (``L^T`` solve), a square root (``|L^-1 nu|`` instead of its square) or a sign error: compared with
    ``nu @ inv(S) @ nu`` on seeded random SPD matrices up to condition number 1e11."""
    rng = np.random.default_rng(int(math.log10(cond)) + 17)
    for d in range(1, 7):
        for _ in range(20):
            S = _random_spd(rng, d, cond) if d > 1 else np.array([[rng.uniform(0.01, 10.0)]])
            nu = rng.normal(size=d) * np.sqrt(np.diag(S))
            expected = float(nu @ np.linalg.inv(S) @ nu)
            got = kern.mahalanobis2(nu, S)
            # relative accuracy of a solve is ~cond * eps
            assert got == pytest.approx(expected, rel=max(1e-10, cond * 1e-14)), (d, cond)


def test_mahalanobis2_hand_values_and_non_spd():
    """Catches a 1-D shortcut without the division, a diagonal-only distance (correlation ignored), and a
    non-positive-definite ``S`` silently giving a finite (gate-passing) distance."""
    assert kern.mahalanobis2(np.array([3.0]), np.array([[4.0]])) == pytest.approx(9.0 / 4.0)
    assert kern.mahalanobis2(np.array([1.0, 2.0]), np.diag([1.0, 4.0])) == pytest.approx(2.0)
    # correlated: S = [[1, .9], [.9, 1]], nu = (1, -1): nu^T S^-1 nu = 2 / (1 - .9) = 20
    assert kern.mahalanobis2(np.array([1.0, -1.0]), np.array([[1.0, 0.9], [0.9, 1.0]])) == pytest.approx(20.0)
    # ... and along the correlation: (1, 1) -> 2 / 1.9
    assert kern.mahalanobis2(np.array([1.0, 1.0]), np.array([[1.0, 0.9], [0.9, 1.0]])) == pytest.approx(2.0 / 1.9)
    assert kern.mahalanobis2(np.array([1.0, 0.0]), np.diag([1.0, -1.0])) == math.inf
    assert kern.mahalanobis2(np.array([1.0]), np.array([[0.0]])) == math.inf
    assert kern.mahalanobis2(np.array([1.0]), np.array([[-2.0]])) == math.inf


# ------------------------------------------------------------------------------------------ NEES / ANEES
def test_nees_matches_dense_inverse():
    """Catches NEES computed with ``P`` instead of ``P^-1``, with the diagonal only, or summed over the wrong
    axis: per-epoch ``e_k^T P_k^-1 e_k`` on random correlated covariances."""
    rng = np.random.default_rng(3)
    K = 25
    covs = np.array([_random_spd(rng, 3, 100.0) for _ in range(K)])
    errs = rng.normal(size=(K, 3))
    expected = np.array([e @ np.linalg.inv(P) @ e for e, P in zip(errs, covs)])
    np.testing.assert_allclose(nees(errs, covs), expected, rtol=1e-10)


def test_anees_against_hand_computation():
    """Catches an ANEES averaged over epochs instead of runs, a band with the wrong ``n`` (epochs instead of
    runs, or no ``/ n``) and a wrong in-band fraction."""
    runs = np.array([[1.0, 2.0, 9.0, 3.0],
                     [2.0, 4.0, 11.0, 3.0],
                     [3.0, 3.0, 10.0, 3.0]])  # N = 3 runs, K = 4 epochs
    out = anees(runs, dof=3)
    np.testing.assert_allclose(out["anees"], [2.0, 3.0, 10.0, 3.0])
    lo, hi = chi2.ppf(0.025, 9) / 3, chi2.ppf(0.975, 9) / 3  # 0.9004 .. 6.3410
    assert out["band"][0] == pytest.approx(lo) and out["band"][1] == pytest.approx(hi)
    assert out["band"][0] == pytest.approx(0.9005, abs=1e-3) and out["band"][1] == pytest.approx(6.341, abs=1e-3)
    assert out["fraction_in_band"] == pytest.approx(0.75)  # 10.0 is outside
    assert out["anees_mean"] == pytest.approx(4.5)


def test_anees_of_a_consistent_monte_carlo_is_in_band():
    """Catches a NEES/ANEES pipeline that is biased (e.g. a covariance used un-inverted or a wrong dof): errors
    drawn from the stated covariances give an ANEES near the dof, inside the band at ~95 % of the epochs, and
    errors from a 2x too small covariance are flagged."""
    rng = np.random.default_rng(8)
    N, K = 40, 200
    covs = np.array([_random_spd(rng, 3, 10.0) for _ in range(K)])
    L = np.linalg.cholesky(covs)
    e = np.einsum("kij,nkj->nki", L, rng.normal(size=(N, K, 3)))
    runs = np.array([nees(e[i], covs) for i in range(N)])
    out = anees(runs)
    assert abs(out["anees_mean"] - 3.0) < 0.1
    assert 0.88 < out["fraction_in_band"] <= 1.0
    over = anees(np.array([nees(e[i], covs / 2.0) for i in range(N)]))  # overconfident filter
    assert over["fraction_in_band"] < 0.1 and over["anees_mean"] == pytest.approx(6.0, abs=0.2)


def test_nis_summary_against_hand_computation():
    """Catches a NIS summary with the band of one sample instead of ``len(values)`` samples, or the wrong dof."""
    out = nis_summary({"dvl": ([1.0, 2.0, 3.0, 6.0], 3), "depth": ([0.5, 1.5], 1), "empty": ([], 2)})
    assert set(out) == {"dvl", "depth"}
    assert out["dvl"]["n"] == 4 and out["dvl"]["dof"] == 3 and out["dvl"]["mean"] == pytest.approx(3.0)
    np.testing.assert_allclose(out["dvl"]["band"], [chi2.ppf(0.025, 12) / 4, chi2.ppf(0.975, 12) / 4])
    np.testing.assert_allclose(out["depth"]["band"], [chi2.ppf(0.025, 2) / 2, chi2.ppf(0.975, 2) / 2])


# ------------------------------------------------------------------------------------------ trajectory
def test_trajectory_metrics_hand_computed():
    """Catches an ATE that is a mean (not RMS) error, a NEES with ``P`` not inverted, 3-sigma figures from the
    variance instead of the standard deviation, and wrong final/max/in-band figures, on a 3-epoch trajectory
    worked out by hand."""
    truth = np.zeros((3, 3))
    est = np.array([[3.0, 4.0, 0.0],      # |e| = 5
                    [0.0, 0.0, 0.0],      # |e| = 0
                    [1.0, 2.0, 2.0]])     # |e| = 3
    covs = np.array([np.diag([1.0, 4.0, 1.0]),   # NEES 9 + 16/4 + 0 = 13
                     np.diag([1.0, 1.0, 1.0]),   # 0
                     np.diag([4.0, 4.0, 1.0])])  # 1/4 + 4/4 + 4/1 = 5.25
    m = trajectory_metrics(est, truth, covs)
    assert m["ate_rmse_m"] == pytest.approx(math.sqrt((25.0 + 0.0 + 9.0) / 3.0))
    assert m["final_position_error_m"] == pytest.approx(3.0)
    assert m["max_position_error_m"] == pytest.approx(5.0)
    assert m["final_3sigma_m"] == pytest.approx(3.0 * 3.0)            # 3 sqrt(trace = 9)
    assert m["max_3sigma_m"] == pytest.approx(3.0 * math.sqrt(9.0))   # traces 6, 3, 9
    assert m["nees_position_mean"] == pytest.approx((13.0 + 0.0 + 5.25) / 3.0)
    np.testing.assert_allclose(m["nees_position_band_of_mean"], [chi2.ppf(0.025, 9) / 3, chi2.ppf(0.975, 9) / 3])
    # per-epoch 95 % interval [0.216, 9.35]: 13 out, 0 out, 5.25 in
    assert m["nees_position_fraction_in_95"] == pytest.approx(1.0 / 3.0)
    # |e_i| <= 3 sigma_i per axis: epoch 0: 3<=3, 4<=6, 0<=3 (3 in); epoch 1: 3 in; epoch 2: 1<=6, 2<=6, 2<=3
    assert m["fraction_within_3sigma"] == pytest.approx(1.0)
    est2 = est.copy()
    est2[0, 0] = 3.5  # 3.5 > 3 sigma_x = 3
    assert trajectory_metrics(est2, truth, covs)["fraction_within_3sigma"] == pytest.approx(8.0 / 9.0)


def test_trajectory_metrics_correlated_covariance():
    """Catches a NEES that ignores the off-diagonal covariance terms (diagonal-only shortcut)."""
    truth = np.array([[10.0, 0.0, -2.0]])
    est = truth + [[1.0, -1.0, 0.0]]
    C = np.array([[[1.0, 0.9, 0.0], [0.9, 1.0, 0.0], [0.0, 0.0, 1.0]]])
    m = trajectory_metrics(est, truth, C)
    assert m["nees_position_mean"] == pytest.approx(20.0)  # 2 / (1 - 0.9)
    assert m["ate_rmse_m"] == pytest.approx(math.sqrt(2.0))
