"""The choice among the grid search's refined hypotheses (:func:`.estimate._grid_search`): the best by the final
score, admissible when a test is given (an object cannot lie inside the seabed it rests on), and the score margin
and alternatives of the chosen one (the covariance's spread).

A refined hypothesis is ``(score, fit, vis, T_object_scanner, Hypothesis)``."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..symmetry import Symmetry
from .search import DEPTH_TWIN_MIN_M, rotation_distances

__all__ = ["admissible_alternative", "choose_hypothesis", "margin_and_alternatives"]


def choose_hypothesis(refined: list) -> tuple:
    """The chosen hypothesis of the ``refined`` ones (sorted by score): the best that is not a depth twin
    (:func:`.search._depth_twin` only widens the covariance)."""
    return next((r for r in refined if not r[4].depth_twin), refined[0])


def admissible_alternative(refined: list, best: tuple, admissible: Callable[[np.ndarray], bool]) -> tuple | None:
    """When ``best``'s final pose fails ``admissible`` (a test of ``T_scanner_object`` (4, 4)): the best-scoring
    other refined hypothesis that passes it, a depth twin included (the depth ambiguity of a border-cut cluster,
    settled by the floor), and the ones it is judged against: those that pass (the others are physically
    impossible: neither in the margin nor in the spread). None when no other passes."""
    ok = [r for r in refined if r is not best and admissible(np.linalg.inv(r[3]))]
    return (ok[0], ok) if ok else None


def margin_and_alternatives(refined: list, best: tuple, sym: Symmetry) -> tuple[float, list]:
    """The score margin of ``best`` among the ``refined`` hypotheses: the least score difference to one not
    equivalent to it (> 10 degrees modulo the symmetry or > 1 cm away; inf when none), and those hypotheses as
    ``(score difference, T_object_scanner)`` pairs, the covariance's spread. A depth twin more than
    :data:`~.search.DEPTH_TWIN_MIN_M` away is in the spread (its difference at least 0), not the margin."""
    Tb = best[3]
    margin = float("inf")
    distinct = []
    for other in refined:
        To = other[3]
        if other is best:
            continue
        rot = rotation_distances(Tb[:3, :3], To[None, :3, :3], sym)[0]
        # positions of the object origin in the scanner frame
        dt = np.linalg.norm(Tb[:3, :3].T @ Tb[:3, 3] - To[:3, :3].T @ To[:3, 3])
        if other[4].depth_twin and dt > DEPTH_TWIN_MIN_M:
            distinct.append((max(float(other[0] - best[0]), 0.0), To))
        elif rot > np.radians(10.0) or dt > 0.01:
            margin = min(margin, other[0] - best[0])
            distinct.append((float(other[0] - best[0]), To))
    return margin, distinct
