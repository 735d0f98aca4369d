"""Leave-one-out evaluation: exact confusion matrices on constructed databases, brute-force agreement."""

from __future__ import annotations

import numpy as np
import pytest

from semslam.errors import InputError, RecognitionError
from semslam.recognition import Chi2NearestNeighbor, SvmClassifier, ViewDatabase
from semslam.evaluation.classifier import confusion_matrix, leave_one_out
from semslam.symmetry import Symmetry


def make_db(esf: np.ndarray, labels: list[str], vfh: np.ndarray | None = None) -> ViewDatabase:
    """A database straight from descriptor rows (one 3-point view each)."""
    n = len(labels)
    vfh = np.ones((n, 308), np.float32) if vfh is None else vfh
    ids = [f"v{i}" for i in range(n)]
    classes = {c: {"symmetry": Symmetry(), "size_xyz_m": np.ones(3)} for c in set(labels)}
    return ViewDatabase(np.array(labels), np.array(ids), np.arange(0, 3 * n + 1, 3), np.zeros((3 * n, 3), np.float32),
                        np.zeros((n, 3)), np.asarray(esf, np.float32), np.asarray(vfh, np.float32), classes)


def separable(n_per_class=8, seed=0):
    """Three classes whose ESF rows live on disjoint bin ranges, with jitter."""
    rng = np.random.default_rng(seed)
    esf = np.zeros((3 * n_per_class, 640))
    for c in range(3):
        rows = slice(c * n_per_class, (c + 1) * n_per_class)
        esf[rows, c * 200:(c + 1) * 200] = rng.uniform(0.5, 1.5, size=(n_per_class, 200))
    labels = ["elbow"] * n_per_class + ["tee"] * n_per_class + ["valve"] * n_per_class
    return esf, labels


def test_loo_chi2_separable_is_perfect():
    esf, labels = separable()
    res = leave_one_out(make_db(esf, labels), descriptor="esf", classifier="chi2")
    assert res.accuracy == 1.0 and res.n_correct == 24
    np.testing.assert_array_equal(res.confusion, np.diag([8, 8, 8]))
    assert res.labels == ("elbow", "tee", "valve")
    assert res.recall == {"elbow": 1.0, "tee": 1.0, "valve": 1.0}
    assert res.distances.shape == (24,) and (res.distances > 0).all()


def test_loo_chi2_exact_confusion_with_planted_errors():
    # class c fills bins [200c, 200c + 200) with 1; every view also has its own bin 600 + i:
    # same-class views are exactly 2 apart, different classes 402 apart
    labels = ["elbow"] * 4 + ["tee"] * 4 + ["valve"] * 4
    esf = np.zeros((12, 640))
    for i, c in enumerate([0] * 4 + [1] * 4 + [2] * 4):
        esf[i, 200 * c:200 * c + 200] = 1.0
        esf[i, 600 + i] = 1.0
    # planted: elbow view 1 looks like a tee, valve view 9 like an elbow (x1.5: 22 from that class)
    esf[1, :600] = 0.0
    esf[1, 200:400] = 1.5
    esf[9, :600] = 0.0
    esf[9, 0:200] = 1.5
    res = leave_one_out(make_db(esf, labels), descriptor="esf", classifier="chi2")
    np.testing.assert_array_equal(res.confusion, [[3, 1, 0], [0, 4, 0], [1, 0, 3]])
    assert res.accuracy == pytest.approx(10 / 12)
    assert res.recall == pytest.approx({"elbow": 0.75, "tee": 1.0, "valve": 0.75})
    assert res.predicted[1] == "tee" and res.predicted[9] == "elbow"
    expected_d = np.full(12, 2.0)
    expected_d[[1, 9]] = 200 * 0.5**2 / 2.5 + 2  # 20 + 2
    np.testing.assert_allclose(res.distances, expected_d, rtol=1e-6)


def test_loo_chi2_equals_refitting_per_fold():
    rng = np.random.default_rng(5)
    esf = rng.gamma(1.0, size=(15, 640))
    labels = list("abc" * 5)
    db = make_db(esf, labels)
    res = leave_one_out(db, descriptor="esf", classifier="chi2")
    X = db.features("esf")
    y = np.array(labels)
    brute = []
    for i in range(len(y)):
        keep = np.arange(len(y)) != i
        brute.append(Chi2NearestNeighbor().fit(X[keep], y[keep]).predict(X[i:i + 1])[0])
    assert list(res.predicted) == brute
    # the generic-estimator path gives the same answer as the vectorised one
    res2 = leave_one_out(db, descriptor="esf", classifier=Chi2NearestNeighbor())
    assert list(res2.predicted) == brute
    np.testing.assert_array_equal(res.confusion, confusion_matrix(y, brute, res.labels))


def test_loo_svm_small_grid():
    esf, labels = separable(n_per_class=6)
    vfh = np.zeros((18, 308))
    vfh[:, :10] = np.random.default_rng(1).uniform(size=(18, 10))  # vfh is noise: esf carries the classes
    db = make_db(esf, labels, vfh)
    svm = SvmClassifier(c_log2=(-1, 7, 4), gamma_log2=(-9, -1, 4), cv=3, seed=0)
    res = leave_one_out(db, descriptor="esf+vfh", classifier=svm, seed=0)
    assert res.accuracy == 1.0
    np.testing.assert_array_equal(res.confusion, np.diag([6, 6, 6]))
    assert len(res.details["svm_params_per_fold"]) == 18
    assert res.classifier == "SvmClassifier"
    d = res.to_dict()
    assert d["confusion"] == [[6, 0, 0], [0, 6, 0], [0, 0, 6]] and len(d["views"]) == 18
    assert "| elbow | 6 | 0 | 0 | 100.0% |" in res.format_table()


def test_loo_errors():
    esf, labels = separable(n_per_class=2)
    db = make_db(esf, labels)
    with pytest.raises(InputError, match="'descriptor'"):
        leave_one_out(db, descriptor="shot")
    with pytest.raises(InputError, match="'classifier'"):
        leave_one_out(db, classifier="knn")
    with pytest.raises(RecognitionError, match="at least 2 views"):
        leave_one_out(db.subset([0]))
    with pytest.raises(RecognitionError, match="'db'"):
        leave_one_out("db.npz")


def test_parallel_folds_give_the_same_result():
    """n_jobs changes the speed only: every fold's seed is drawn before any fold is fitted."""
    esf, labels = separable(n_per_class=5, seed=3)
    esf[0] = esf[12]  # a planted confusion, so that the comparison covers a wrong prediction too
    db = make_db(esf, labels)
    svm = SvmClassifier(c_log2=(-1, 7, 4), gamma_log2=(-9, -1, 4), cv=3, seed=0)
    a = leave_one_out(db, descriptor="esf", classifier=svm, seed=1, n_jobs=1)
    b = leave_one_out(db, descriptor="esf", classifier=svm, seed=1, n_jobs=2)
    assert a.accuracy < 1.0
    np.testing.assert_array_equal(a.predicted, b.predicted)
    np.testing.assert_array_equal(a.confusion, b.confusion)
    assert a.details == b.details
