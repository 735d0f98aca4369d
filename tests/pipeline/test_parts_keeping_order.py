"""The part-based stage tries its candidate unions in the order it keeps them, and skips those it could never keep:
the kept unions equal those of trying every candidate (brute force over random candidate sets)."""

from __future__ import annotations

import numpy as np

from semslam.pipeline.parts import kept_unions, tried_in_keeping_order


def _instance(rng: np.random.Generator):
    n = int(rng.integers(1, 14))
    members = [sorted(rng.choice(6, size=int(rng.integers(2, 5)), replace=False).tolist()) for _ in range(n)]
    points = rng.choice([300, 450, 450, 600, 900], size=n).tolist()  # ties in points on purpose
    entries = [None if rng.random() < 0.3 else (points[u], float(rng.choice([0.96, 0.98, 0.98, 1.0])), members[u], u)
               for u in range(n)]
    return points, members, entries


def test_the_same_unions_are_kept_as_when_every_candidate_is_tried():
    """Catches a union kept that the greedy choice over every candidate would not keep, or one lost: ties in points
    and in fitness, overlapping and disjoint candidates, failed ones."""
    rng = np.random.default_rng(11)
    skipped = 0
    for _ in range(500):
        points, members, entries = _instance(rng)
        evaluated = []

        def evaluate(u, entries=entries, evaluated=evaluated):
            evaluated.append(u)
            return entries[u]

        tried = tried_in_keeping_order(points, members, evaluate)
        assert kept_unions(tried) == kept_unions([e for e in entries if e is not None])
        skipped += len(members) - len(evaluated)
    assert skipped > 500  # the point of it: many candidates are never posed


def test_a_union_sharing_a_cluster_with_a_larger_kept_one_is_never_posed():
    """Catches every candidate posed anyway (or one posed before a larger union is kept): clusters 0+1+2 kept
    (900 points), so 0+1 and 1+3 are never evaluated; 3+4 (disjoint) is; 2+5 ties with nothing larger kept."""
    members = [[0, 1], [0, 1, 2], [1, 3], [3, 4], [2, 5]]
    points = [600, 900, 500, 400, 700]
    evaluated = []

    def evaluate(u):
        evaluated.append(u)
        return (points[u], 0.99, members[u], u)

    tried = tried_in_keeping_order(points, members, evaluate)
    assert evaluated == [1, 3]  # 900 first; 2+5 (700), 0+1 (600), 1+3 (500) share a cluster with it
    assert [e[3] for e in kept_unions(tried)] == [1, 3]


def test_unions_of_as_many_points_are_all_evaluated_and_the_best_fitness_kept():
    """Catches the first of two overlapping unions of equal size kept before the other is evaluated."""
    members = [[0, 1], [1, 2]]
    fitness = [0.96, 0.99]
    tried = tried_in_keeping_order([500, 500], members, lambda u: (500, fitness[u], members[u], u))
    assert [e[3] for e in kept_unions(tried)] == [1]
