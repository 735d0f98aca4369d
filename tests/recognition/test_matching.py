"""Chi-square nearest neighbour, SVM grid search and unknown rejection against oracles."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.metrics.pairwise import additive_chi2_kernel

from semslam.errors import InputError, RecognitionError
from semslam.recognition import (
    UNKNOWN_LABEL,
    Chi2NearestNeighbor,
    SvmClassifier,
    calibrate_rejection,
    chi2_distances,
    loo_same_class_distances,
)


def brute_chi2(a: np.ndarray, b: np.ndarray) -> float:
    total = 0.0
    for x, y in zip(a, b):
        if x + y > 0:
            total += (x - y) ** 2 / (x + y)
    return total


def histograms(rng, n, d=40, zeros=0.3):
    h = rng.gamma(1.0, size=(n, d))
    h[rng.uniform(size=(n, d)) < zeros] = 0.0  # bins empty in both a and b must be skipped
    return h


def blobs(rng, n_per_class=6, d=30):
    centres = rng.gamma(2.0, size=(3, d)) * (rng.uniform(size=(3, d)) < 0.5)
    X = np.concatenate([c + 0.05 * rng.gamma(1.0, size=(n_per_class, d)) for c in centres])
    y = np.repeat(["a", "b", "c"], n_per_class)
    return X, y


def test_chi2_matches_brute_force_and_sklearn():
    rng = np.random.default_rng(0)
    X, Y = histograms(rng, 7), histograms(rng, 5)
    D = chi2_distances(X, Y)
    brute = np.array([[brute_chi2(a, b) for b in Y] for a in X])
    np.testing.assert_allclose(D, brute, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(D, -additive_chi2_kernel(X, Y), rtol=1e-12, atol=1e-12)
    assert np.all(np.diag(chi2_distances(X, X)) == 0)


def test_chi2_analytic_and_zero_bins():
    # (1-0)^2/1 + (0-0) skipped + (2-1)^2/3 = 1 + 1/3, no 1/2 factor
    assert chi2_distances([[1.0, 0.0, 2.0]], [[0.0, 0.0, 1.0]])[0, 0] == pytest.approx(4 / 3)
    assert chi2_distances([[0.0, 0.0]], [[0.0, 0.0]])[0, 0] == 0.0


def test_chi2_rejects_bad_input():
    with pytest.raises(RecognitionError, match="'X'.*>= 0"):
        chi2_distances([[-1.0, 1.0]], [[1.0, 1.0]])
    with pytest.raises(RecognitionError, match="'Y'.*shape"):
        chi2_distances([[1.0, 1.0]], [[1.0, 1.0, 1.0]])
    with pytest.raises(RecognitionError, match="finite"):
        chi2_distances([[np.nan, 1.0]], [[1.0, 1.0]])


def test_kneighbors_against_brute_force():
    rng = np.random.default_rng(1)
    X, Q = histograms(rng, 20), histograms(rng, 4)
    y = np.array(list("abcd") * 5)
    clf = Chi2NearestNeighbor(n_neighbors=3).fit(X, y)
    assert clf.fit(X, y) is clf
    dist, idx = clf.kneighbors(Q)
    for q in range(len(Q)):
        brute = np.array([brute_chi2(Q[q], x) for x in X])
        order = np.argsort(brute, kind="stable")[:3]
        np.testing.assert_array_equal(idx[q], order)
        np.testing.assert_allclose(dist[q], brute[order], rtol=1e-12)
    # 1-NN prediction = label of the brute-force nearest view
    pred = Chi2NearestNeighbor().fit(X, y).predict(Q)
    expected = [y[np.argmin([brute_chi2(q, x) for x in X])] for q in Q]
    assert list(pred) == expected
    np.testing.assert_array_equal(clf.classes_, ["a", "b", "c", "d"])


def test_knn_vote_and_tie_break():
    X = np.array([[1.0, 0], [1.1, 0], [0, 1.0], [0, 1.2]])
    y = np.array(["a", "b", "b", "a"])
    clf = Chi2NearestNeighbor(n_neighbors=2).fit(X, y)
    # neighbours of [1, 0]: a (0), b (1.1): tie, the nearest (a) wins
    assert clf.predict([[1.0, 0.0]])[0] == "a"
    clf3 = Chi2NearestNeighbor(n_neighbors=3).fit(X, y)
    # neighbours of [1.05, 0]: b (1), a (0), b (2): majority b
    np.testing.assert_array_equal(clf3.kneighbors([[1.05, 0.0]])[1][0], [1, 0, 2])
    assert clf3.predict([[1.05, 0.0]])[0] == "b"


def test_unfitted_and_bad_params():
    with pytest.raises(RecognitionError, match="not fitted"):
        Chi2NearestNeighbor().predict([[1.0]])
    with pytest.raises(InputError, match="n_neighbors"):
        Chi2NearestNeighbor(n_neighbors=0).fit([[1.0]], ["a"])
    with pytest.raises(InputError, match="rejection"):
        Chi2NearestNeighbor(rejection="maybe").fit([[1.0]], ["a"])
    with pytest.raises(RecognitionError, match="not fitted"):
        SvmClassifier().predict([[1.0]])


def test_rejection_calibration_and_unknown():
    rng = np.random.default_rng(2)
    X, y = blobs(rng)
    d = loo_same_class_distances(X, y)
    brute = [min(brute_chi2(X[i], X[j]) for j in range(len(y)) if j != i and y[j] == y[i]) for i in range(len(y))]
    np.testing.assert_allclose(d, brute, rtol=1e-12)
    thr = calibrate_rejection(X, y, quantile=0.9, margin=2.0)
    assert thr.global_threshold == pytest.approx(2.0 * np.quantile(brute, 0.9))
    per = calibrate_rejection(X, y, mode="per_class", min_class_views=4)
    assert set(per.per_class) == {"a", "b", "c"}
    assert per.threshold_of("b") == pytest.approx(1.0 * np.quantile(d[y == "b"], 0.95))
    clf = Chi2NearestNeighbor(rejection="global", reject_quantile=0.9, reject_margin=2.0).fit(X, y)
    # members (slightly perturbed) are accepted, far-away histograms are unknown
    members = X + 0.01 * rng.gamma(1.0, size=X.shape)
    assert (clf.predict(members) == y).all()
    strangers = 10 * rng.gamma(1.0, size=(5, X.shape[1]))
    labels, dist = clf.predict_with_distance(strangers)
    assert (labels == UNKNOWN_LABEL).all()
    assert (dist > thr.global_threshold).all()
    with pytest.raises(RecognitionError, match="reserved"):
        calibrate_rejection(X, np.where(y == "a", "unknown", y))
    with pytest.raises(RecognitionError, match="2 or more views"):
        calibrate_rejection(X[:3], ["a", "b", "c"])


def rings(rng, n_per_class=12):
    """Two concentric rings (non-linear: a small gamma cannot separate them), shifted to >= 0."""
    t = rng.uniform(0, 2 * np.pi, size=2 * n_per_class)
    r = np.repeat([1.0, 3.0], n_per_class) + 0.1 * rng.normal(size=2 * n_per_class)
    X = np.stack([r * np.cos(t), r * np.sin(t)], axis=1) + 4.0
    return X, np.repeat(["inner", "outer"], n_per_class)


def test_svm_grid_search_picks_params_and_classifies():
    rng = np.random.default_rng(3)
    X, y = rings(rng)
    clf = SvmClassifier(c_log2=(-5, 15, 4), gamma_log2=(-15, 3, 3), cv=4, seed=0)
    assert clf.fit(X, y) is clf
    assert clf.cv_accuracy_.shape == (len(clf.C_grid_), len(clf.gamma_grid_)) == (6, 7)
    best = clf.cv_accuracy_.max()
    assert best == 1.0
    # the smoothest corner of the grid cannot separate rings: the search had to move away from it
    assert clf.cv_accuracy_[0, 0] < 0.75
    i_c = int(np.flatnonzero(clf.C_grid_ == clf.C_)[0])
    i_g = int(np.flatnonzero(clf.gamma_grid_ == clf.gamma_)[0])
    # tie rule: the first best in (C, gamma) order, i.e. smallest C then smallest gamma
    assert tuple(np.argwhere(clf.cv_accuracy_ == best)[0]) == (i_c, i_g)
    assert clf.gamma_ > clf.gamma_grid_[0]
    X_test, y_test = rings(np.random.default_rng(33))
    assert np.mean(clf.predict(X_test) == y_test) >= 0.95
    again = SvmClassifier(c_log2=(-5, 15, 4), gamma_log2=(-15, 3, 3), cv=4, seed=0).fit(X, y)
    np.testing.assert_array_equal(again.cv_accuracy_, clf.cv_accuracy_)


def test_svm_cv_accuracy_matches_sklearn_grid_search():
    from sklearn.model_selection import GridSearchCV, StratifiedKFold
    from sklearn.preprocessing import MinMaxScaler
    from sklearn.svm import SVC

    rng = np.random.default_rng(4)
    X, y = blobs(rng, n_per_class=6)
    X = X + 0.6 * rng.gamma(1.0, size=X.shape)  # harder: accuracies differ across the grid
    clf = SvmClassifier(c_log2=(-1, 7, 4), gamma_log2=(-7, 1, 4), cv=3, seed=5).fit(X, y)
    split_seed = int(np.random.default_rng(5).integers(2**31 - 1))
    Xs = MinMaxScaler().fit_transform(X)
    gs = GridSearchCV(SVC(kernel="rbf"), {"C": clf.C_grid_, "gamma": clf.gamma_grid_},
                      cv=StratifiedKFold(3, shuffle=True, random_state=split_seed)).fit(Xs, y)
    ref = gs.cv_results_["mean_test_score"].reshape(len(clf.C_grid_), len(clf.gamma_grid_))
    np.testing.assert_allclose(clf.cv_accuracy_, ref, atol=1e-12)  # equal folds -> same mean accuracy


def test_svm_needs_two_samples_per_class():
    with pytest.raises(RecognitionError, match="at least 2 training samples"):
        SvmClassifier(cv=3).fit([[1.0, 0], [0, 1.0], [0, 1.1]], ["a", "b", "b"])
    with pytest.raises(InputError, match="c_log2"):
        SvmClassifier(c_log2=(3, 1, 1)).fit([[1.0, 0], [0, 1.0]] * 2, ["a", "b"] * 2)


def test_recognizer_matches_and_rejects():
    from semslam.recognition import Recognizer, ViewDescriptors
    from semslam.recognition.database import ViewDatabase
    from semslam.symmetry import Symmetry

    rng = np.random.default_rng(6)
    X, y = blobs(rng, n_per_class=5, d=640)
    n = len(y)
    db = ViewDatabase(y, np.array([f"v{i}" for i in range(n)]), np.arange(0, 3 * n + 1, 3),
                      np.zeros((3 * n, 3), np.float32), np.zeros((n, 3)), X.astype(np.float32),
                      np.ones((n, 308), np.float32),
                      {c: {"symmetry": Symmetry(), "size_xyz_m": np.ones(3)} for c in "abc"})
    rec = Recognizer(db, descriptor="esf")
    m = rec.match_descriptors(ViewDescriptors(db.esf[7] + 0.001, db.vfh[7]))
    assert m.accepted and m.label == "b" and m.view_index == 7 and m.nearest_label == "b"
    assert m.distance < m.threshold == rec.thresholds.global_threshold
    far = rec.match_descriptors(ViewDescriptors(10 * rng.gamma(1.0, size=640), db.vfh[0]))
    assert far.label == UNKNOWN_LABEL and not far.accepted and far.distance > far.threshold
    assert far.nearest_label in "abc" and far.to_dict()["accepted"] is False
    with pytest.raises(RecognitionError, match="'db'"):
        Recognizer("db.npz")


def test_estimators_follow_sklearn_api():
    from sklearn.base import clone

    rng = np.random.default_rng(7)
    X, y = blobs(rng)
    for est in (Chi2NearestNeighbor(n_neighbors=3, rejection="global"),
                SvmClassifier(c_log2=(-1, 3, 2), gamma_log2=(-3, 1, 2), cv=3, seed=1)):
        params = est.get_params()
        twin = clone(est)
        assert twin.get_params() == params and not hasattr(twin, "classes_")
        assert est.fit(X, y) is est
        assert est.score(X, y) == 1.0  # ClassifierMixin.score = accuracy
        assert not hasattr(twin, "classes_")  # clone is independent


def test_algorithm_is_a_speed_switch_only():
    import pickle

    from sklearn.base import clone

    rng = np.random.default_rng(8)
    X, y = blobs(rng, n_per_class=60, d=50)
    Q = X[::7] + 0.02 * rng.gamma(1.0, size=X[::7].shape)
    auto = Chi2NearestNeighbor(n_neighbors=3, rejection="global").fit(X, y)
    assert auto.get_params()["algorithm"] == "auto"
    auto.kneighbors(X[:40])  # 180 views, 40 queries: "auto" builds the index
    assert auto.index_ is not None
    brute = clone(auto).set_params(algorithm="brute").fit(X, y)
    brute.kneighbors(X[:40])
    assert brute.index_ is None
    for a, b in zip(auto.kneighbors(Q), brute.kneighbors(Q)):
        np.testing.assert_array_equal(a, b)  # bit for bit
    np.testing.assert_array_equal(auto.predict_with_distance(Q)[1], brute.predict_with_distance(Q)[1])
    again = pickle.loads(pickle.dumps(auto))
    np.testing.assert_array_equal(again.kneighbors(Q)[1], brute.kneighbors(Q)[1])
