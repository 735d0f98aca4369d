"""Recognise one segmented cluster against a view database: class (or ``"unknown"``) and matched view.

The matched view is what pose estimation aligns to the cluster (Himri et al. 2019, II.A.5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validation import check_choice
from ..cloud import PointCloud
from ..errors import InputError, RecognitionError
from .database import DESCRIPTORS, ViewDatabase, ViewDescriptors, combine_descriptors
from .matching import Chi2NearestNeighbor, chi2_distances
from .rejection import UNKNOWN_LABEL

__all__ = ["Match", "Recognizer"]


@dataclass(frozen=True)
class Match:
    """Result of matching one cluster.

    Attributes
    ----------
    label : str
        Class of the nearest view, or ``"unknown"`` when rejected.
    view_index : int
        Index of the nearest database view (also when rejected, for diagnostics).
    nearest_label : str
        Class of that view.
    distance : float
        Chi-square distance to it.
    threshold : float
        Rejection threshold applied (``inf`` when rejection is off).
    descriptors : ViewDescriptors
        The cluster's ESF and VFH.
    """

    label: str
    view_index: int
    nearest_label: str
    distance: float
    threshold: float
    descriptors: ViewDescriptors

    @property
    def accepted(self) -> bool:
        return self.label != UNKNOWN_LABEL

    def to_dict(self) -> dict:
        return {"label": self.label, "view_index": self.view_index, "nearest_label": self.nearest_label,
                "distance": self.distance, "threshold": self.threshold, "accepted": self.accepted}


class Recognizer:
    """Chi-square nearest-view recognition with unknown rejection calibrated on the database.

    Parameters
    ----------
    db : ViewDatabase
    descriptor : {"esf", "vfh", "esf+vfh"}, default "esf"
    rejection : {"global", "per_class", "none"}, default "global"
    reject_quantile, reject_margin : float
        See :mod:`semslam.recognition.rejection`.
    """

    def __init__(self, db: ViewDatabase, *, descriptor: str = "esf", rejection: str = "global",
                 reject_quantile: float = 0.95, reject_margin: float = 1.0) -> None:
        if not isinstance(db, ViewDatabase):
            raise RecognitionError(
                f"The 'db' argument of Recognizer must be a ViewDatabase. Got {type(db).__name__} instead."
            )
        self.db = db
        self.descriptor = check_choice("descriptor", descriptor, DESCRIPTORS, caller="Recognizer")
        self.classifier = Chi2NearestNeighbor(rejection=rejection, reject_quantile=reject_quantile,
                                              reject_margin=reject_margin).fit(db.features(descriptor), db.labels,
                                                                               view_directions=db.view_directions())

    @property
    def thresholds(self):
        """The calibrated :class:`RejectionThresholds` (None without rejection)."""
        return self.classifier.rejection_

    def match_descriptors(self, descriptors: ViewDescriptors) -> Match:
        """Match precomputed descriptors (as :meth:`ViewDatabase.describe` returns)."""
        x = combine_descriptors(self.descriptor, descriptors.esf, descriptors.vfh)
        labels, dist = self.classifier.predict_with_distance(x)
        _, idx = self.classifier.kneighbors(x, 1)
        i = int(idx[0, 0])
        nearest = str(self.db.labels[i])
        thr = self.classifier.rejection_
        threshold = float("inf") if thr is None else thr.threshold_of(nearest)
        return Match(str(labels[0]), i, nearest, float(dist[0]), threshold, descriptors)

    def class_match(self, descriptors: ViewDescriptors, label: str) -> Match:
        """The nearest view of class ``label`` to ``descriptors``, whether or not the rejection accepts it (a cluster
        tracked from an earlier scan: :mod:`semslam.pipeline.tracking`)."""
        dist, labels = self._view_distances(descriptors)
        rows = np.flatnonzero(labels == label)
        if not len(rows):
            raise InputError(f"The 'label' argument of Recognizer.class_match must be a class of the database "
                             f"{sorted(set(labels))}. Got {label!r} instead.")
        i = int(rows[np.argmin(dist[rows])])
        thr = self.classifier.rejection_
        return Match(label, i, label, float(dist[i]), float("inf") if thr is None else thr.threshold_of(label),
                     descriptors)

    def _view_distances(self, descriptors: ViewDescriptors) -> tuple[np.ndarray, np.ndarray]:
        """The chi-square distance of ``descriptors`` to every database view (n_views,) and the views' labels."""
        x = combine_descriptors(self.descriptor, descriptors.esf, descriptors.vfh)
        return chi2_distances(x, self.classifier.X_fit_)[0], np.asarray(self.db.labels).astype(str)

    def match(self, cloud: PointCloud, *, seed: int | np.random.Generator = 0) -> Match:
        """Describe ``cloud`` (any frame, viewpoint = sensor origin) as the database's views and match it."""
        return self.match_descriptors(self.db.describe(cloud, seed=seed))

    def other_classes(self, descriptors: ViewDescriptors, exclude: str) -> list[Match]:
        """The nearest view of every class but ``exclude`` that the rejection would accept, nearest first: the
        classes a cluster could be when ``exclude``'s hypothesis fails verification
        (``PipelineConfig.verify_next_classes``). Each is an accepted :class:`Match` of that class (its distance
        within that class's threshold)."""
        dist, labels = self._view_distances(descriptors)
        thr = self.classifier.rejection_
        found = []
        for label in np.unique(labels):
            if label == exclude:
                continue
            rows = np.flatnonzero(labels == label)
            i = int(rows[np.argmin(dist[rows])])
            threshold = float("inf") if thr is None else thr.threshold_of(label)
            if dist[i] <= threshold:
                found.append(Match(str(label), i, str(label), float(dist[i]), threshold, descriptors))
        return sorted(found, key=lambda m: (m.distance, m.view_index))
