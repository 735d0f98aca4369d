"""Ensemble of Shape Functions (ESF, 640 bins), as PCL 1.13's ``ESFEstimation``."""

from __future__ import annotations

import numpy as np

from .._validation import as_float_array, as_rng, check_choice, check_int
from ..errors import DescriptorError
from . import _esf_kernels as K
from ._glibc_rand_kernels import glibc_rand_fill, glibc_srand

ESF_SIZE = 640
#: Give up after this many candidate triangles per requested sample (PCL would loop forever).
MAX_DRAWS_PER_SAMPLE = 50


def compute_esf(
    points_xyz_m: np.ndarray,
    *,
    n_samples: int = 20000,
    seed: int | np.random.Generator | None = None,
    sampler: str = "numpy",
) -> np.ndarray:
    """ESF global descriptor of a cloud, PCL 1.13's algorithm in float32.

    The cloud is centred on its centroid and scaled into a sphere of radius 32 voxels, a 64^3
    occupancy grid marks the 3x3x3 block around every point, and ``n_samples`` random point triples
    (non-degenerate triangles) fill ten 64-bin histograms: A3 angles, D3 square-rooted areas and D2
    distances split by whether the connecting lines run inside, outside or across the surface, plus
    the in/out ratio of mixed lines. Layout: [A3 in, out, mix | D3 in, out, mix | D2 in, out, mix |
    D2 ratio], each block weighted as PCL, and the whole summing to 1.

    Parameters
    ----------
    points_xyz_m : array-like of shape (N, 3)
        Points (m) in any frame (ESF is translation and scale invariant, not rotation invariant);
        finite, at least 3 points not all collinear. They are rounded to float32 (as PCL's PointXYZ).
    n_samples : int
        Number of accepted triangles (PCL: 20000).
    seed : int or numpy Generator, optional
        Randomness. With ``sampler="pcl"`` it must be an int: the value PCL's ``time(NULL)`` would
        return (PCL seeds with ``srand(time(NULL))``); None then means 0, as ``srand(0)``.
    sampler : {"numpy", "pcl"}
        "numpy" (default): indices from a seeded numpy Generator (no modulo bias, faster);
        statistically indistinguishable from PCL. "pcl": glibc ``rand() % N`` after
        ``srand(seed)``, which reproduces PCL 1.13 bit for bit.

    Returns
    -------
    ndarray of shape (640,), float32
        Sums to 1 (float32 rounding), never NaN.

    Raises
    ------
    DescriptorError
        NaN/infinite points, fewer than 3 points, all points coincident, or no non-degenerate
        triangle found after ``MAX_DRAWS_PER_SAMPLE * n_samples`` draws (collinear cloud), where PCL
        would loop forever.
    """
    caller = "compute_esf"
    pts = as_float_array("points_xyz_m", points_xyz_m, (None, 3), caller=caller, error=DescriptorError)
    n_samples = check_int("n_samples", n_samples, caller=caller, minimum=1)
    check_choice("sampler", sampler, ("numpy", "pcl"), caller=caller)
    n = len(pts)
    if n < 3:
        raise DescriptorError(f"The 'points_xyz_m' argument of {caller} must have at least 3 points. Got {n} instead.")
    pts32 = np.ascontiguousarray(pts, dtype=np.float32)
    if not np.isfinite(pts32).all():
        raise DescriptorError(f"The 'points_xyz_m' argument of {caller} must fit in float32. Got values beyond 3.4e38.")
    local, vox, lut, maxd = K.esf_prepare(pts32)
    if not maxd > 0:
        raise DescriptorError(
            f"The 'points_xyz_m' argument of {caller} must hold distinct points. Got {n} identical points."
        )
    draw = _sampler(sampler, seed, n, caller)
    out_i, out_f, end = _evaluated_samples(local, vox, lut, draw, n_samples, caller)
    return K.esf_histogram(out_i, out_f, end)


def _evaluated_samples(local, vox, lut, draw, n_samples: int, caller: str) -> tuple[np.ndarray, np.ndarray, int]:
    """Draw and evaluate candidate triples in chunks until ``n_samples`` are accepted: every candidate's results in
    draw order (``K.esf_evaluate``'s integer and float rows) and the row after the last accepted sample counted."""
    accepted = 0
    drawn = 0
    end = -1
    # Every candidate triple's results, in draw order (rows 0..drawn-1); usually one chunk is enough.
    out_i = np.empty((0, 11), dtype=np.int16)  # small integers: bins < 64, voxel counts <= 65
    out_f = np.empty((0, 8), dtype=np.float32)
    max_draws = MAX_DRAWS_PER_SAMPLE * n_samples
    while end < 0:
        if drawn >= max_draws:
            raise DescriptorError(
                f"The 'points_xyz_m' argument of {caller} must span a surface (not all collinear). "
                f"Got only {accepted} non-degenerate triangles in {drawn} random draws."
            )
        # Candidates for the missing samples at the acceptance rate seen so far (+ a margin).
        rate = max(accepted / drawn, 0.01) if drawn else 0.95
        chunk = int(min(max_draws - drawn, (n_samples - accepted) / rate * 1.03 + 64))
        triples = draw(chunk)
        if len(out_i) < drawn + chunk:
            out_i = _grown(out_i, drawn + chunk)
            out_f = _grown(out_f, drawn + chunk)
        # Both cores evaluate the triples; the histograms count the first n_samples accepted in draw order.
        K.esf_evaluate(local, vox, lut, triples, out_i[drawn:], out_f[drawn:])
        got, stop = K.esf_cutoff(out_i, drawn, drawn + chunk, n_samples - accepted)
        accepted += got
        drawn += chunk
        if accepted == n_samples:
            end = stop
    return out_i, out_f, end


def _grown(a: np.ndarray, rows: int) -> np.ndarray:
    out = np.empty((rows, a.shape[1]), dtype=a.dtype)
    out[: len(a)] = a
    return out


def glibc_rand(seed: int, n: int) -> np.ndarray:
    """The first ``n`` values of glibc's ``rand()`` after ``srand(seed)`` (int64 array)."""
    seed = check_int("seed", seed, caller="glibc_rand", minimum=0, maximum=2**32 - 1)
    out = np.empty(check_int("n", n, caller="glibc_rand", minimum=0), dtype=np.int64)
    glibc_rand_fill(glibc_srand(seed), out)
    return out


def _sampler(sampler, seed, n, caller):
    if sampler == "pcl":
        if seed is None:
            seed = 0
        seed = check_int("seed", seed, caller=caller + ' (sampler="pcl")', minimum=0, maximum=2**32 - 1)
        state = glibc_srand(seed)

        def draw(m: int) -> np.ndarray:
            out = np.empty(3 * m, dtype=np.int64)
            glibc_rand_fill(state, out)  # one rand() per index, i1 i2 i3 in order, as PCL
            return (out % n).reshape(m, 3)

        return draw
    rng = as_rng(seed, caller=caller)
    return lambda m: rng.integers(0, n, size=(m, 3), dtype=np.int64)
