"""Does a model's mesh have the symmetry declared for it? (``semslam db build --models``, ``demo --models``)

A declared symmetry the part does not have hides real pose errors; a symmetry the part has but nobody declared
makes its twin poses look like an ambiguity (flagged unreliable, never mapped) and counts them as wrong in the
evaluation. Both are easy to get wrong by eye: the shared wheel valve's handwheel has five spokes.

The check turns surface samples of the mesh (object frame, about axes through the object origin) and measures how
far they land from the surface: the 99th percentile of the nearest-sample distance, minus the same statistic of
the unturned samples (the sampling floor), as a fraction of the bounding-box diagonal (the *excess*). A turn is a
symmetry when its excess is below :data:`HOLDS_EXCESS` (measured: 0.000-0.0022 for every symmetry declared on the
shared, catalogue, unseen and DAVE models, 0.008 for the small handwheel valve's 8 spokes around a square stem),
and clearly not one above :data:`BROKEN_EXCESS` (0.016 and more for turns that are not symmetries, measured up to
:data:`CAP_EXCESS`; 0.006-0.007 for a flange turned face for face, whose raised face is 2-3 mm).
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from ..symmetry import Symmetry, _axis_angle_matrices

__all__ = ["BROKEN_EXCESS", "HOLDS_EXCESS", "ModelSymmetryWarning", "check_declared_symmetry", "measured_symmetry",
           "symmetry_text", "turn_excess"]

#: A turn whose excess (see the module docstring) is below this is a symmetry of the mesh.
HOLDS_EXCESS = 0.0025
#: A declared symmetry whose generator's excess is above this does not hold.
BROKEN_EXCESS = 0.015
#: Distances are measured up to this fraction of the diagonal (the excess saturates near it).
CAP_EXCESS = 0.05
#: Angles (rad) that test a continuous symmetry: not fractions of a turn a discrete symmetry would pass.
CONTINUOUS_TEST_ANGLES = (0.37, 1.23, 2.71)
#: Orders of discrete symmetry looked for, largest first.
ORDERS = (12, 10, 8, 6, 5, 4, 3, 2)
#: The object axes a ``models.toml`` symmetry names (``parse_symmetry`` reads them, :func:`symmetry_text` writes them).
OBJECT_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


class ModelSymmetryWarning(UserWarning):
    """A class's declared symmetry and its mesh disagree (see :func:`check_declared_symmetry`)."""


def turn_excess(mesh: trimesh.Trimesh, rotations: np.ndarray, *, n_samples: int = 2000, n_reference: int = 30000,
                seed: int = 0) -> np.ndarray:
    """Excess (fraction of the bounding-box diagonal, see the module docstring) of each rotation ``(K, 3, 3)``
    (object frame, about the origin) of ``mesh``'s surface; shape ``(K,)``."""
    reference, _ = trimesh.sample.sample_surface(mesh, n_reference, seed=seed)
    points, _ = trimesh.sample.sample_surface(mesh, n_samples, seed=seed + 1)
    tree = cKDTree(reference)
    diagonal = float(np.linalg.norm(np.ptp(mesh.bounds, axis=0)))
    floor = float(np.percentile(tree.query(points)[0], 99))
    R = np.asarray(rotations, dtype=float).reshape(-1, 3, 3)
    cap = CAP_EXCESS * diagonal  # a far point's exact distance does not matter, and finding it is slow
    distances = np.minimum(tree.query(np.einsum("kij,nj->kni", R, points), distance_upper_bound=cap)[0], cap)
    return np.maximum(np.percentile(distances, 99, axis=1) - floor, 0.0) / diagonal


def _generators(symmetry: Symmetry) -> np.ndarray:
    """Rotations whose being symmetries makes the whole declared group one (a cyclic group: its first turn)."""
    a = symmetry.axis_object
    if symmetry.kind == "discrete":
        turns = _axis_angle_matrices(a, np.array([2.0 * np.pi / symmetry.order]))
    else:
        turns = _axis_angle_matrices(a, np.array(CONTINUOUS_TEST_ANGLES))
    if symmetry.flip:
        turns = np.concatenate([turns, symmetry.flip_rotation[None]])
    return turns


def symmetry_text(symmetry: Symmetry) -> str:
    """The ``models.toml`` spelling of ``symmetry`` (``"discrete:5:x"``), the axis as a vector when it is not one
    of the object's axes."""
    if symmetry.kind == "none":
        return "none"
    a = symmetry.axis_object
    names = [n for n, v in OBJECT_AXES.items() if np.allclose(a, v, atol=1e-9)]
    axis = names[0] if names else "(" + ", ".join(f"{v:.3g}" for v in a) + ")"
    if symmetry.kind == "discrete":
        return f"discrete:{symmetry.order}:{axis}"
    return f"continuous:{axis}" + (":flip" if symmetry.flip else "")


def _candidates() -> list[tuple[int, Symmetry]]:
    """Every symmetry looked for, with its rank (lower: stronger) about its axis."""
    out = []
    for a in OBJECT_AXES.values():
        cands = [Symmetry("continuous", a, flip=True), Symmetry("continuous", a)]
        out += list(enumerate(cands + [Symmetry("discrete", a, n) for n in ORDERS]))
    return out


def _group_excess(mesh: trimesh.Trimesh, symmetries: list[Symmetry], seed: int) -> list[float]:
    """The largest excess of each symmetry's generators, from one sampling of the mesh."""
    gens = [_generators(s) for s in symmetries]
    excess = turn_excess(mesh, np.concatenate(gens), seed=seed)
    bounds = np.cumsum([0] + [len(g) for g in gens])
    return [float(excess[a:b].max()) for a, b in zip(bounds[:-1], bounds[1:])]


def _strongest(candidates: list[tuple[int, Symmetry]], excess: list[float]) -> tuple[Symmetry, float]:
    best = None
    for (rank, s), e in zip(candidates, excess):
        if e < HOLDS_EXCESS and (best is None or rank < best[0]):
            best = (rank, s, e)
    return (best[1], best[2]) if best is not None else (Symmetry("none"), 0.0)


def measured_symmetry(mesh: trimesh.Trimesh, *, seed: int = 0) -> tuple[Symmetry, float]:
    """The strongest symmetry about one of the object's axes that ``mesh`` has (continuous with an end-for-end
    turn, then continuous, then the largest discrete order; ties go to x, y, z in turn), and its largest excess;
    ``(Symmetry("none"), 0.0)`` when no turn holds."""
    candidates = _candidates()
    return _strongest(candidates, _group_excess(mesh, [s for _, s in candidates], seed))


def _weaker(declared: Symmetry, found: Symmetry) -> bool:
    """Whether ``found`` strictly contains ``declared`` (same axis, or ``declared`` none)."""
    if found.kind == "none":
        return False
    if declared.kind == "none":
        return True
    if not np.allclose(declared.axis_object, found.axis_object, atol=1e-9):
        return False
    if declared.kind == "continuous":
        return found.kind == "continuous" and found.flip and not declared.flip
    return found.kind == "continuous" or (found.order > declared.order and found.order % declared.order == 0)


def check_declared_symmetry(mesh: trimesh.Trimesh, declared: Symmetry, *, seed: int = 0) -> str | None:
    """A one-line warning text when ``declared`` and the mesh (object frame, metres) clearly disagree, else None:
    the declared symmetry does not hold (its turn's excess above :data:`BROKEN_EXCESS`), or the mesh has a
    stronger one about the same axis, or any when ``none`` is declared (excess below :data:`HOLDS_EXCESS`)."""
    diagonal_mm = 1000.0 * float(np.linalg.norm(np.ptp(mesh.bounds, axis=0)))
    candidates = _candidates()
    checked = [declared] if declared.kind != "none" else []
    excess = _group_excess(mesh, checked + [s for _, s in candidates], seed)
    found, found_excess = _strongest(candidates, excess[len(checked):])
    if checked and excess[0] > BROKEN_EXCESS:
        hint = f" (its mesh measures as {symmetry_text(found)!r})" if found.kind != "none" else ""
        return (f"the declared symmetry {symmetry_text(declared)!r} does not hold for its mesh: its turn moves "
                f"1 % of the surface by {excess[0] * diagonal_mm:.3g} mm or more ({100 * excess[0]:.2g} % of the "
                f"part's size); a symmetry the part does not have hides real pose errors. Declare the one it has"
                f"{hint}.")
    if _weaker(declared, found):
        return (f"its mesh is the same turned as {symmetry_text(found)!r} describes (within "
                f"{max(found_excess * diagonal_mm, 0.01):.2g} mm), but {symmetry_text(declared)!r} is declared: its "
                f"twin poses will be flagged ambiguous, never mapped, and counted as wrong. Declare "
                f"symmetry = {symmetry_text(found)!r} if the part is symmetric (a mark the mesh lacks may tell the "
                f"twins apart).")
    return None
