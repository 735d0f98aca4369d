"""Numba kernels of glibc's ``rand()`` (TYPE_3, as PCL's ESF draws its samples). Don't call directly; use
:func:`semslam.descriptors.glibc_rand` or :func:`semslam.descriptors.compute_esf` with ``sampler="pcl"``."""

from __future__ import annotations

import numpy as np
from numba import njit


# ---------------------------------------------------------------- glibc rand() (TYPE_3)
@njit(cache=True, nogil=True)
def glibc_srand(seed):  # pragma: no cover - compiled
    """State of glibc's ``random_r`` after ``srand(seed)`` and its 310 discarded outputs.

    Returns an int64 array of 32: the last 31 values r_{i-31..i-1} (mod 2^32) in a ring, and at
    index 31 the position i of the next value.
    """
    r = np.zeros(344, dtype=np.int64)
    word = np.int64(seed) & 0xFFFFFFFF
    if word >= 2**31:
        word -= 2**32  # glibc stores the seed in an int32
    if word == 0:
        word = 1
    r[0] = word
    for i in range(1, 31):
        # Schrage's method, with C's truncating division
        hi = abs(word) // 127773
        lo = abs(word) % 127773
        if word < 0:
            hi = -hi
            lo = -lo
        word = 16807 * lo - 2836 * hi
        if word < 0:
            word += 2147483647
        r[i] = word
    for i in range(31, 34):
        r[i] = r[i - 31]
    for i in range(34, 344):
        r[i] = (r[i - 31] + r[i - 3]) & 0xFFFFFFFF
    state = np.zeros(32, dtype=np.int64)
    for i in range(313, 344):
        state[i % 31] = r[i] & 0xFFFFFFFF
    state[31] = 344
    return state


@njit(cache=True, nogil=True)
def glibc_rand_fill(state, out):  # pragma: no cover - compiled
    """Fill ``out`` (int64) with the next ``rand()`` outputs, advancing ``state`` in place."""
    i = state[31]
    for k in range(len(out)):
        v = (state[(i - 31) % 31] + state[(i - 3) % 31]) & 0xFFFFFFFF
        state[i % 31] = v
        out[k] = v >> 1
        i += 1
    state[31] = i
