"""Leave-one-out evaluation of a classifier on a view database (Himri et al. 2018, Tables 1-2)."""

from __future__ import annotations

import functools

from dataclasses import dataclass
from typing import Any

import numpy as np

from .._progress import progress_steps
from .._validation import as_rng, check_choice, check_int
from ..errors import RecognitionError
from ..recognition import _chi2_kernels
from ..recognition.database import DESCRIPTORS, ViewDatabase
from ..recognition.matching import SvmClassifier

CLASSIFIERS = ("chi2", "svm")

__all__ = ["EvaluationResult", "confusion_matrix", "leave_one_out"]


@dataclass(frozen=True, eq=False)
class EvaluationResult:
    """Outcome of a leave-one-out evaluation.

    Attributes
    ----------
    labels : tuple of str
        Class order of the confusion matrix (sorted).
    confusion : ndarray of int, shape (K, K)
        ``confusion[i, j]`` = views of class ``labels[i]`` (actual, rows) predicted as ``labels[j]`` (columns).
    accuracy : float
        Fraction of views predicted correctly, in [0, 1].
    recall : dict of str to float
        Per class: correct / views of that class.
    actual, predicted, view_ids : ndarray of str, shape (V,)
        Per view, in database order.
    distances : ndarray of float, shape (V,)
        Chi-square distance of every view to its nearest *other* view (any class) on the same descriptor,
        whichever classifier was evaluated (the calibration input of unknown rejection).
    descriptor, classifier : str
    details : dict
        Classifier specifics (for SVM: the (C, gamma) chosen in every fold).
    """

    labels: tuple
    confusion: np.ndarray
    accuracy: float
    recall: dict
    actual: np.ndarray
    predicted: np.ndarray
    view_ids: np.ndarray
    distances: np.ndarray
    descriptor: str
    classifier: str
    details: dict

    @property
    def n_views(self) -> int:
        return len(self.actual)

    @property
    def n_correct(self) -> int:
        return int(np.trace(self.confusion))

    def to_dict(self) -> dict:
        return {
            "descriptor": self.descriptor, "classifier": self.classifier, "n_views": self.n_views,
            "n_correct": self.n_correct, "accuracy": self.accuracy, "labels": list(self.labels),
            "confusion": self.confusion.tolist(), "recall": dict(self.recall),
            "views": [{"label": a, "view_id": v, "predicted": p, "distance": float(d)}
                      for a, v, p, d in zip(self.actual, self.view_ids, self.predicted, self.distances)],
            "details": self.details,
        }

    def format_table(self) -> str:
        """The confusion matrix as a markdown table (rows actual, columns predicted) with recall."""
        names = list(self.labels)
        head = "| actual \\ predicted | " + " | ".join(names) + " | recall |"
        rule = "|---|" + "---:|" * (len(names) + 1)
        rows = [f"| {name} | " + " | ".join(str(int(c)) for c in self.confusion[i])
                + f" | {100 * self.recall[name]:.1f}% |" for i, name in enumerate(names)]
        total = (f"accuracy: {100 * self.accuracy:.2f}% ({self.n_correct}/{self.n_views} views), "
                 f"descriptor {self.descriptor}, classifier {self.classifier}")
        return "\n".join([head, rule, *rows, "", total])


def confusion_matrix(actual: Any, predicted: Any, labels: Any) -> np.ndarray:
    """Counts (K, K) of (actual = labels[i], predicted = labels[j]); predictions outside ``labels`` are ignored."""
    labels = list(labels)
    index = {lab: k for k, lab in enumerate(labels)}
    a = np.array([index.get(x, -1) for x in np.asarray(actual).astype(str)])
    p = np.array([index.get(x, -1) for x in np.asarray(predicted).astype(str)])
    ok = (a >= 0) & (p >= 0)
    out = np.zeros((len(labels), len(labels)), dtype=np.int64)
    np.add.at(out, (a[ok], p[ok]), 1)
    return out


def leave_one_out(db: ViewDatabase, *, descriptor: str = "esf", classifier: str | Any = "chi2",
                  seed: int | np.random.Generator = 0, n_jobs: int = 1,
                  progress: Any = None) -> EvaluationResult:
    """Classify every view of ``db`` with a classifier trained on all the other views.

    Parameters
    ----------
    db : ViewDatabase
    descriptor : {"esf", "vfh", "esf+vfh"}
    classifier : {"chi2", "svm"} or an unfitted estimator with ``fit(X, y)`` / ``predict(X)``
        ``"chi2"`` = :class:`Chi2NearestNeighbor` (done in one vectorised pass: the V x V distance matrix
        with its diagonal excluded); ``"svm"`` = :class:`SvmClassifier` with the full Hsu et al. grid,
        whose grid search is rerun inside every fold (nested, so the estimate is unbiased). An estimator
        instance is cloned (``sklearn.base.clone``) and fitted in every fold. Predictions of ``"unknown"``
        (an estimator with rejection) count as errors and appear in no column of the confusion matrix.
    seed : int or Generator
        Seeds the SVM cross-validation folds.
    n_jobs : int
        Processes fitting the folds of a trained classifier in parallel (joblib; -1 = every core). The result
        does not depend on it: every fold's estimator and seed are fixed before any is fitted.
    progress : bool or callable, optional
        A bar, or ``progress(n_done, n_folds)`` after every fitted fold (:mod:`semslam._progress`).
    """
    if not isinstance(db, ViewDatabase):
        raise RecognitionError(
            f"The 'db' argument of leave_one_out must be a ViewDatabase. Got {type(db).__name__} instead."
        )
    check_choice("descriptor", descriptor, DESCRIPTORS, caller="leave_one_out")
    if isinstance(classifier, str):
        check_choice("classifier", classifier, CLASSIFIERS, caller="leave_one_out")
    rng = as_rng(seed, caller="leave_one_out")
    if db.n_views < 2:
        raise RecognitionError(f"leave_one_out needs at least 2 views. Got {db.n_views} view(s).")
    X = db.features(descriptor)
    y = db.labels.astype(str)
    D = _chi2_kernels.chi2_distance_matrix(X, X)
    np.fill_diagonal(D, np.inf)
    nearest = np.argmin(D, axis=1)  # first index on ties, like Chi2NearestNeighbor
    distances = D[np.arange(len(y)), nearest]
    details: dict = {}
    if classifier == "chi2":
        predicted = y[nearest]
        name = "chi2"
    else:
        from .._workers import parallel_map

        check_int("n_jobs", n_jobs, caller="leave_one_out", minimum=-1)
        estimators = []
        for _ in range(len(y)):  # one fit per fold: inherent to leave-one-out; seeds drawn in fold order
            estimators.append(SvmClassifier(seed=int(rng.integers(2**31 - 1))) if classifier == "svm"
                              else _fresh(classifier))
        jobs = parallel_map(functools.partial(_fit_predict_fold_args, X=X, y=y), list(enumerate(estimators)),
                            n_jobs or 1)
        folds = []
        with progress_steps(progress, len(estimators), "leave-one-out", "fold") as step:
            for fold in jobs:  # in fold order
                folds.append(fold)
                step()
        predicted = np.array([p for p, _ in folds], dtype=object)
        chosen = [c for _, c in folds if c is not None]
        predicted = predicted.astype(str)
        name = classifier if isinstance(classifier, str) else type(classifier).__name__
        if chosen:
            details["svm_params_per_fold"] = chosen
    labels = tuple(sorted(db.class_infos))
    confusion = confusion_matrix(y, predicted, labels)
    totals = confusion.sum(axis=1)
    recall = {lab: float(confusion[k, k] / totals[k]) if totals[k] else float("nan") for k, lab in enumerate(labels)}
    return EvaluationResult(labels, confusion, float(np.mean(predicted == y)), recall, y, predicted,
                            db.view_ids.astype(str), distances, descriptor, name, details)


def _fit_predict_fold_args(item: tuple, *, X: np.ndarray, y: np.ndarray) -> tuple[str, dict | None]:
    i, est = item
    return _fit_predict_fold(est, X, y, i)


def _fit_predict_fold(est: Any, X: np.ndarray, y: np.ndarray, i: int) -> tuple[str, dict | None]:
    """Fit ``est`` on every row but ``i`` and predict row ``i``; also the SVM's chosen parameters."""
    train = np.arange(len(y)) != i
    est.fit(X[train], y[train])
    chosen = {"C": est.C_, "gamma": est.gamma_} if hasattr(est, "C_") else None
    return str(np.asarray(est.predict(X[i:i + 1]))[0]), chosen


def _fresh(estimator: Any) -> Any:
    """An unfitted copy (``sklearn.base.clone``), or the estimator itself if it cannot be cloned."""
    from sklearn.base import clone

    try:
        return clone(estimator)
    except TypeError:
        return estimator
