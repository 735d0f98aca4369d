"""Object recognition from global descriptors: the view database, chi-square and SVM matching,
leave-one-out evaluation and unknown-object rejection.

>>> from semslam.recognition import load_database, Recognizer
>>> db = load_database("objects.npz")                                    # doctest: +SKIP
>>> match = Recognizer(db, descriptor="esf").match(cluster_cloud)        # doctest: +SKIP
>>> match.label, match.view_index, db.view_points(match.view_index).shape  # doctest: +SKIP
('ball_valve', 27, (4407, 3))
"""

from .build import build_database, build_database_from_folder
from .database import FORMAT_NAME, FORMAT_VERSION, ClassInfo, ViewDatabase
from .storage import load_database, save_database
from .view_descriptors import ViewDescriptors, combine_descriptors, compute_view_descriptors
from .matching import Chi2NearestNeighbor, SvmClassifier, chi2_distances
from .preprocessing import ViewPreprocessing
from .recognizer import Match, Recognizer
from .rejection import (
    UNKNOWN_LABEL,
    RejectionThresholds,
    calibrate_rejection,
    loo_same_class_distances,
)

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "UNKNOWN_LABEL",
    "Chi2NearestNeighbor",
    "ClassInfo",
    "Match",
    "Recognizer",
    "RejectionThresholds",
    "SvmClassifier",
    "ViewDatabase",
    "ViewDescriptors",
    "ViewPreprocessing",
    "build_database",
    "build_database_from_folder",
    "calibrate_rejection",
    "chi2_distances",
    "combine_descriptors",
    "compute_view_descriptors",
    "load_database",
    "loo_same_class_distances",
    "save_database",
]
