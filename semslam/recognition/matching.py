"""Classifiers of global descriptors, scikit-learn style.

* :class:`Chi2NearestNeighbor`: the nearest stored view in chi-square distance wins (Himri et al. 2018,
  sec. 2.1.4.1; PCL's vfh_recognition tutorial), with optional rejection of unknown objects
  (:mod:`semslam.recognition.rejection`).
* :class:`SvmClassifier`: an RBF support-vector machine whose (C, gamma) are chosen by the cross-validated
  grid search of Hsu, Chang & Lin, "A practical guide to support vector classification" (features scaled to
  [0, 1] first), as in Himri et al. 2018, sec. 2.1.4.2.

Both are scikit-learn estimators (``BaseEstimator`` + ``ClassifierMixin``: ``get_params``, ``clone``,
``score``): ``__init__`` only stores parameters, ``fit`` returns ``self``, learned attributes end in ``_``
and ``classes_`` holds the sorted class labels. Bad input raises :class:`~semslam.errors.RecognitionError`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import inspect

from .._validation import as_float_array, as_rng, check_choice, check_int
from ..errors import InputError, RecognitionError
from . import _chi2_kernels
from ._chi2_index import Chi2Index
from .rejection import UNKNOWN_LABEL, RejectionThresholds, calibrate_rejection

__all__ = ["Chi2NearestNeighbor", "SvmClassifier", "chi2_distances"]

#: ``Chi2NearestNeighbor(algorithm="auto")`` builds the index from this many stored views on (the index answers
#: faster from ~100 views, ``benchmarks/matching_query.py``)...
AUTO_INDEX_MIN_VIEWS = 128
#: ... once it has answered this many queries by the linear scan: a build costs about as much as 50-150 linear
#: scans, so a classifier fitted for one query (leave-one-out folds) never pays for one.
AUTO_INDEX_AFTER_QUERIES = 32


class _Estimator:
    """The scikit-learn estimator protocol (``get_params``/``set_params``, accuracy ``score``), written out so that
    importing the recognition stage does not import scikit-learn (1-2 s of start-up); ``sklearn.base.clone``,
    ``GridSearchCV`` and friends work with it as with any estimator."""

    _estimator_type = "classifier"

    @classmethod
    def _param_names(cls) -> list[str]:
        sig = inspect.signature(cls.__init__)
        return sorted(p.name for p in sig.parameters.values() if p.name != "self" and p.kind != p.VAR_KEYWORD)

    def get_params(self, deep: bool = True) -> dict:
        return {name: getattr(self, name) for name in self._param_names()}

    def set_params(self, **params: Any):
        valid = set(self._param_names())
        for name, value in params.items():
            if name not in valid:
                raise InputError(f"{type(self).__name__} has no parameter {name!r}. Valid ones: {sorted(valid)}.")
            setattr(self, name, value)
        return self

    def score(self, X: Any, y: Any) -> float:
        """Mean accuracy of ``predict(X)`` against ``y``."""
        return float(np.mean(np.asarray(self.predict(X)).astype(str) == np.asarray(y).astype(str)))

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"


def _as_histograms(name: str, X: Any, caller: str, n_features: int | None = None) -> np.ndarray:
    arr = as_float_array(name, X, (None, n_features), caller=caller, error=RecognitionError)
    if len(arr) == 0:
        raise RecognitionError(f"The {name!r} argument of {caller} must hold at least one row. Got 0 rows instead.")
    if (arr < 0).any():
        raise RecognitionError(
            f"The {name!r} argument of {caller} must hold histograms (values >= 0). "
            f"Got a minimum of {arr.min():.6g} instead."
        )
    return arr


def _as_labels(y: Any, n: int, caller: str) -> np.ndarray:
    labels = np.asarray(y)
    if labels.shape != (n,):
        raise RecognitionError(f"The 'y' argument of {caller} must have shape ({n},). Got {labels.shape} instead.")
    return labels.astype(str)


def chi2_distances(X: Any, Y: Any) -> np.ndarray:
    """Chi-square distances between histograms, as FLANN / PCL's vfh_recognition tutorial.

    ``d(a, b) = sum_k (a_k - b_k)^2 / (a_k + b_k)`` over the bins with ``a_k + b_k > 0`` (no 1/2
    factor); equal to ``-sklearn.metrics.pairwise.additive_chi2_kernel(X, Y)``.

    Parameters
    ----------
    X : array-like of shape (n, d)
        Non-negative histograms (ESF, VFH, ...).
    Y : array-like of shape (m, d)
        Non-negative histograms with the same number of bins.

    Returns
    -------
    ndarray of shape (n, m)
        ``D[i, j] = d(X[i], Y[j])``, >= 0.
    """
    Xa = _as_histograms("X", X, "chi2_distances")
    Ya = _as_histograms("Y", Y, "chi2_distances", Xa.shape[1])
    return _chi2_kernels.chi2_distance_matrix(Xa, Ya)


class Chi2NearestNeighbor(_Estimator):
    """Nearest-neighbour classifier in chi-square distance, with optional unknown-object rejection.

    Parameters
    ----------
    n_neighbors : int, default 1
        Neighbours that vote; 1 reproduces the papers (the nearest stored view wins). With more, the
        majority wins and a tie goes to the class of the nearest of the tied neighbours.
    rejection : {"none", "global", "per_class"}, default "none"
        Whether ``predict`` may answer ``"unknown"``: a query whose distance to its nearest view exceeds
        the threshold of the predicted class is rejected. Thresholds are calibrated in ``fit`` from the
        training set's own leave-one-out distances (see :func:`~semslam.recognition.calibrate_rejection`).
    reject_quantile, reject_margin : float
        Threshold = ``reject_margin * quantile(LOO same-class distances, reject_quantile)``.
    algorithm : {"auto", "index", "brute"}, default "auto"
        How the nearest views are searched; all three give the same neighbours and the same distances, bit
        for bit (ties to the lower row), so this is a speed switch only. "brute": the distance to every stored
        view (linear scan). "index": an exact index built by ``fit`` (:class:`~._chi2_index.Chi2Index`: the
        square root of the chi-square distance is a metric, so clusters of views and views far from the
        query in distance to their cluster's centre are skipped by the triangle inequality, and the other
        distances are abandoned once their partial sum exceeds the best so far): 0.1-0.6 ms instead of
        ~10 ms per query at 10,000 views, for a build of ~1 s and at most 50 % more memory with float32 histograms.
        "auto": the linear scan, until ``AUTO_INDEX_AFTER_QUERIES`` (32) queries have been answered with
        ``AUTO_INDEX_MIN_VIEWS`` (128) or more stored views; then the index is built (once) and used.

    Attributes
    ----------
    classes_ : ndarray of str, shape (n_classes,)
    X_fit_ : ndarray of shape (n_views, n_bins)
        The stored histograms (float64).
    y_fit_ : ndarray of str, shape (n_views,)
    rejection_ : RejectionThresholds or None
    index_ : Chi2Index or None
        The search index: built by ``fit`` with "index", by the query that passes the "auto" threshold;
        None while the linear scan answers.
    """

    def __init__(self, n_neighbors: int = 1, *, rejection: str = "none", reject_quantile: float = 0.95,
                 reject_margin: float = 1.0, algorithm: str = "auto") -> None:
        self.n_neighbors = n_neighbors
        self.rejection = rejection
        self.reject_quantile = reject_quantile
        self.reject_margin = reject_margin
        self.algorithm = algorithm

    def fit(self, X: Any, y: Any, view_directions: Any = None) -> Chi2NearestNeighbor:
        """Store the histograms ``X`` (n_views, n_bins) with their labels ``y`` (n_views,).

        ``view_directions`` (n_views, 3), optional: the views' viewing directions in the object frame, so
        that the rejection is calibrated leaving one viewpoint out (:func:`calibrate_rejection`)."""
        caller = "Chi2NearestNeighbor.fit"
        check_int("n_neighbors", self.n_neighbors, caller=caller, minimum=1)
        check_choice("rejection", self.rejection, ("none", "global", "per_class"), caller=caller)
        check_choice("algorithm", self.algorithm, ("auto", "index", "brute"), caller=caller)
        self.X_fit_ = _as_histograms("X", X, caller)
        self.y_fit_ = _as_labels(y, len(self.X_fit_), caller)
        self.classes_ = np.unique(self.y_fit_)
        self.n_features_in_ = self.X_fit_.shape[1]
        self.index_: Chi2Index | None = Chi2Index(self.X_fit_) if self.algorithm == "index" else None
        self._n_scanned = 0  # queries answered by the linear scan ("auto" builds the index after a few)
        self.rejection_: RejectionThresholds | None = None
        if self.rejection != "none":
            self.rejection_ = calibrate_rejection(
                self.X_fit_, self.y_fit_, quantile=self.reject_quantile, margin=self.reject_margin,
                mode=self.rejection, view_directions=view_directions)
        return self

    def _check_fitted(self, caller: str) -> None:
        if not hasattr(self, "X_fit_"):
            raise RecognitionError(f"{caller} was called before fit: this Chi2NearestNeighbor is not fitted yet.")

    def kneighbors(self, X: Any, n_neighbors: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The nearest stored views of each query.

        Parameters
        ----------
        X : array-like of shape (n_queries, n_bins)
        n_neighbors : int, optional
            Defaults to the constructor's ``n_neighbors``; at most the number of stored views.

        Returns
        -------
        distances : ndarray of shape (n_queries, n_neighbors)
            Chi-square distances, ascending.
        indices : ndarray of int, shape (n_queries, n_neighbors)
            Rows of the training set (ties: lower index first).
        """
        self._check_fitted("Chi2NearestNeighbor.kneighbors")
        k = self.n_neighbors if n_neighbors is None else n_neighbors
        check_int("n_neighbors", k, caller="Chi2NearestNeighbor.kneighbors", minimum=1, maximum=len(self.X_fit_))
        Q = _as_histograms("X", X, "Chi2NearestNeighbor.kneighbors", self.n_features_in_)
        index = getattr(self, "index_", None)
        n_scanned = getattr(self, "_n_scanned", 0) + len(Q)
        if (index is None and self.algorithm == "auto" and len(self.X_fit_) >= AUTO_INDEX_MIN_VIEWS
                and n_scanned >= AUTO_INDEX_AFTER_QUERIES):
            index = self.index_ = Chi2Index(self.X_fit_)
        if index is not None:
            return index.knn(Q, k)
        self._n_scanned = n_scanned
        return _chi2_kernels.smallest_k(_chi2_kernels.chi2_distance_matrix(Q, self.X_fit_), k)

    def predict(self, X: Any) -> np.ndarray:
        """Class label of each query (``"unknown"`` when rejected), an array of str of shape (n_queries,)."""
        labels, _ = self._predict_with_distance(X)
        return labels

    def predict_with_distance(self, X: Any) -> tuple[np.ndarray, np.ndarray]:
        """Labels as :meth:`predict` and the chi-square distance to the nearest stored view (n_queries,)."""
        return self._predict_with_distance(X)

    def _predict_with_distance(self, X: Any) -> tuple[np.ndarray, np.ndarray]:
        k = min(self.n_neighbors, len(self.X_fit_)) if hasattr(self, "X_fit_") else self.n_neighbors
        dist, idx = self.kneighbors(X, k)
        neighbour_labels = self.y_fit_[idx]
        if k == 1:
            labels = neighbour_labels[:, 0].astype(object)
        else:
            labels = np.array([_vote(row) for row in neighbour_labels], dtype=object)
        if self.rejection_ is not None:
            thresholds = self.rejection_.thresholds_for(labels)
            labels[dist[:, 0] > thresholds] = UNKNOWN_LABEL
        return labels.astype(str), dist[:, 0]


def _vote(row: np.ndarray) -> str:
    """Majority label of neighbours sorted by distance; a tie goes to the nearest tied class."""
    values, counts = np.unique(row, return_counts=True)
    best = set(values[counts == counts.max()])
    return next(lab for lab in row if lab in best)


class SvmClassifier(_Estimator):
    """RBF SVM with the grid search of Hsu, Chang & Lin (2003).

    Features are scaled to [0, 1] per bin (min-max on the training set, applied unchanged to queries).
    The grid is ``C = 2**c`` for ``c`` in ``range(*c_log2)`` (inclusive stop) and ``gamma = 2**g`` for ``g``
    in ``range(*gamma_log2)``; every pair is scored by stratified k-fold cross-validation accuracy
    (shuffled with ``seed``); the best pair wins, ties going to the smaller C then the smaller gamma (the
    smoother model). The final SVC is refitted on all the training data.

    Parameters
    ----------
    c_log2 : (start, stop, step), default (-5, 15, 2)
        Exponents of C, stop inclusive: 2^-5, 2^-3, ..., 2^15 as in Hsu et al.
    gamma_log2 : (start, stop, step), default (-15, 3, 2)
        Exponents of gamma, stop inclusive: 2^-15, ..., 2^3.
    cv : int, default 5
        Folds of the cross-validation (reduced to the smallest class size when that is smaller, >= 2).
    seed : int or numpy Generator, default 0
        Shuffles the folds.

    Attributes
    ----------
    classes_ : ndarray of str
    C_, gamma_ : float
        The chosen parameters.
    cv_accuracy_ : ndarray of shape (n_C, n_gamma)
        Mean cross-validated accuracy of every grid point (NaN when the grid was skipped: one class).
    C_grid_, gamma_grid_ : ndarray
    scaler_ : sklearn.preprocessing.MinMaxScaler
    svc_ : sklearn.svm.SVC
    """

    def __init__(self, *, c_log2: tuple[int, int, int] = (-5, 15, 2),
                 gamma_log2: tuple[int, int, int] = (-15, 3, 2), cv: int = 5,
                 seed: int | np.random.Generator = 0) -> None:
        self.c_log2 = c_log2
        self.gamma_log2 = gamma_log2
        self.cv = cv
        self.seed = seed

    def fit(self, X: Any, y: Any) -> SvmClassifier:
        """Scale, grid-search (C, gamma) by cross-validation and fit the final SVC."""
        from sklearn.preprocessing import MinMaxScaler
        from sklearn.svm import SVC

        caller = "SvmClassifier.fit"
        Xa = as_float_array("X", X, (None, None), caller=caller, error=RecognitionError)
        if len(Xa) == 0:
            raise RecognitionError(f"The 'X' argument of {caller} must hold at least one row. Got 0 rows instead.")
        labels = _as_labels(y, len(Xa), caller)
        self.C_grid_ = 2.0 ** _log2_grid("c_log2", self.c_log2, caller)
        self.gamma_grid_ = 2.0 ** _log2_grid("gamma_log2", self.gamma_log2, caller)
        check_int("cv", self.cv, caller=caller, minimum=2)
        rng = as_rng(self.seed, caller=caller)
        self.classes_, counts = np.unique(labels, return_counts=True)
        self.n_features_in_ = Xa.shape[1]
        self.scaler_ = MinMaxScaler().fit(Xa)
        Xs = self.scaler_.transform(Xa)
        self.cv_accuracy_ = np.full((len(self.C_grid_), len(self.gamma_grid_)), np.nan)
        if len(self.classes_) == 1:
            self.C_, self.gamma_ = float(self.C_grid_[0]), float(self.gamma_grid_[0])
            self.svc_ = None
            return self
        n_splits = min(self.cv, int(counts.min()))
        if n_splits < 2:
            raise RecognitionError(
                f"SvmClassifier.fit needs at least 2 training samples of every class for its cross-validation. "
                f"Got {int(counts.min())} for class {self.classes_[np.argmin(counts)]!r}."
            )
        self.cv_accuracy_ = _grid_cv_accuracy(Xs, labels, self.C_grid_, self.gamma_grid_, n_splits,
                                              int(rng.integers(2**31 - 1)))
        best = np.flatnonzero(self.cv_accuracy_.ravel() == self.cv_accuracy_.max())[0]
        i_c, i_g = np.unravel_index(best, self.cv_accuracy_.shape)
        self.C_, self.gamma_ = float(self.C_grid_[i_c]), float(self.gamma_grid_[i_g])
        self.svc_ = SVC(C=self.C_, kernel="rbf", gamma=self.gamma_).fit(Xs, labels)
        return self

    def predict(self, X: Any) -> np.ndarray:
        """Class label of each query, an array of str of shape (n_queries,)."""
        if not hasattr(self, "scaler_"):
            raise RecognitionError("SvmClassifier.predict was called before fit: this SvmClassifier is not fitted yet.")
        Q = as_float_array("X", X, (None, self.n_features_in_), caller="SvmClassifier.predict",
                           error=RecognitionError)
        if self.svc_ is None:
            return np.full(len(Q), self.classes_[0]).astype(str)
        return self.svc_.predict(self.scaler_.transform(Q)).astype(str)


def _log2_grid(name: str, spec: Any, caller: str) -> np.ndarray:
    try:
        start, stop, step = (int(v) for v in spec)
    except (TypeError, ValueError):
        raise InputError(
            f"The {name!r} argument of {caller} must be (start, stop, step) integers. Got {spec!r} instead."
        ) from None
    if step <= 0 or stop < start:
        raise InputError(
            f"The {name!r} argument of {caller} must have step > 0 and stop >= start. Got {spec!r} instead."
        )
    return np.arange(start, stop + 1, step, dtype=float)


def _grid_cv_accuracy(Xs: np.ndarray, y: np.ndarray, C_grid: np.ndarray, gamma_grid: np.ndarray,
                      n_splits: int, random_state: int) -> np.ndarray:
    """Mean k-fold accuracy of every (C, gamma): RBF kernels precomputed once per fold and gamma."""
    from scipy.spatial.distance import cdist
    from sklearn.model_selection import StratifiedKFold
    from sklearn.svm import SVC

    sq = cdist(Xs, Xs, "sqeuclidean")
    correct = np.zeros((len(C_grid), len(gamma_grid)))
    folds = StratifiedKFold(n_splits=n_splits, shuffle=True, random_state=random_state)
    for train, test in folds.split(Xs, y):
        for j, gamma in enumerate(gamma_grid):
            K_train = np.exp(-gamma * sq[np.ix_(train, train)])
            K_test = np.exp(-gamma * sq[np.ix_(test, train)])
            for i, C in enumerate(C_grid):
                pred = SVC(C=C, kernel="precomputed").fit(K_train, y[train]).predict(K_test)
                correct[i, j] += np.count_nonzero(pred == y[test])
    return correct / len(y)
