"""Exact pre-integration of the navigation measurements between two keyframes (square-root information form).

Between keyframes ``k`` and ``k + 1`` the filter predicts in steps of at most ``max_predict_dt_s`` and takes DVL and
depth updates at their own stamps. Giving every such instant a graph variable would multiply the graph's size by
~20; instead the intermediate vehicle states are eliminated as they are passed. The accumulator keeps whitened
linear rows ``A_k X_k + A_c X_c = b`` on the keyframe state ``X_k`` and the current state ``X_c``:

* a prediction ``X_n = F X_c + u + w``, ``w ~ N(0, Q)`` appends ``Q^-1/2 (X_n - F X_c - u)`` and eliminates ``X_c``
  (QR on the columns ordered ``[X_c | X_k, X_n]``: the rows below the ``X_c`` block are the marginal factor);
* a measurement ``z = H X_c + n`` (linearised by the filter: ``H X_c = nu + H x_lin``) appends ``R^-1/2`` rows.

At the next keyframe the rows are one between-factor on ``(X_k, X_k+1)``: exactly the information of every
prediction and measurement of the segment, for a linear-Gaussian model (the EKF's linearisation otherwise: the DVL
without calibration and the depth are linear; the process model is linear but for the yaw-bias rotation). Process
noise that is exactly zero in some direction (DVL scale factor, misalignment, the slope bias over flat ground) is
floored at a variance of ``1e-12`` per step (a random walk of 1e-6 per step, negligible against those states' prior
sigmas), which keeps the whitening finite and the graph well conditioned (a relative floor alone gave iSAM2 an
indeterminate system).
"""

from __future__ import annotations

import numpy as np

_REL_FLOOR = 1e-12
#: absolute floor (variance) of a whitened direction: a 1e-6 random walk per step on a state without process noise
_ABS_FLOOR = 1e-12


def whitener(C: np.ndarray) -> np.ndarray:
    """``W`` with ``W^T W = C^-1`` (eigenvalues floored at ``1e-12`` of the largest and at ``1e-12``)."""
    C = 0.5 * (C + C.T)
    w, V = np.linalg.eigh(C)
    top = max(float(w.max()), 1e-300)
    w = np.maximum(w, max(_REL_FLOOR * top, _ABS_FLOOR))
    return (V / np.sqrt(w)).T


def _compress(M: np.ndarray, keep_from: int = 0) -> np.ndarray:
    """Upper-triangular rows of ``M`` (QR), rows from ``keep_from``, numerically zero rows dropped."""
    R = np.linalg.qr(M, mode="r")
    R = R[keep_from:]
    A = R[:, :-1]
    scale = max(float(np.abs(A).max()) if A.size else 0.0, 1e-300)
    return R[np.abs(A).max(axis=1) > 1e-13 * scale] if A.size else R[:0]


class SegmentAccumulator:
    """Rows on ``[X_k, X_c]`` (see the module docstring); ``n`` the vehicle state's size."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.reset()

    def reset(self) -> None:
        n = self.n
        self.rows = np.zeros((0, 2 * n + 1))  # [A_k | A_c | b]
        self.cur_is_k = True  # no prediction yet: the current state is the keyframe's
        self.n_steps = 0

    def predict(self, F: np.ndarray, u: np.ndarray, Q: np.ndarray) -> None:
        n = self.n
        W = whitener(Q)
        if self.cur_is_k:
            new = np.hstack([-W @ F, W, (W @ u)[:, None]])
            old = self.rows.copy()
            old[:, n:2 * n] = 0.0  # rows on X_k only (their X_c columns are the X_k columns: fold)
            old[:, :n] += self.rows[:, n:2 * n]
            self.rows = np.vstack([old, new])
            self.cur_is_k = False
        else:
            r = len(self.rows)
            # columns [X_c | X_k | X_n | b]
            M = np.zeros((r + n, 3 * n + 1))
            M[:r, 0:n] = self.rows[:, n:2 * n]
            M[:r, n:2 * n] = self.rows[:, 0:n]
            M[:r, -1] = self.rows[:, -1]
            M[r:, 0:n] = -W @ F
            M[r:, 2 * n:3 * n] = W
            M[r:, -1] = W @ u
            self.rows = _compress(M, keep_from=n)[:, n:]
        self.n_steps += 1

    def measure(self, H: np.ndarray, z_eff: np.ndarray, Rn: np.ndarray) -> None:
        """Rows ``R^-1/2 H X_c = R^-1/2 z_eff`` (``H`` on the vehicle state)."""
        n = self.n
        W = whitener(np.atleast_2d(Rn))
        rows = np.zeros((len(z_eff), 2 * n + 1))
        cols = slice(0, n) if self.cur_is_k else slice(n, 2 * n)
        rows[:, cols] = W @ H
        rows[:, -1] = W @ z_eff
        self.rows = np.vstack([self.rows, rows])

    def close(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        """``(A_k, A_c, b, unary)`` compressed, then reset; ``unary``: no prediction happened (rows on X_k only)."""
        n = self.n
        unary = self.cur_is_k
        rows = self.rows
        if len(rows):
            rows = _compress(rows)
        out = (rows[:, 0:n].copy(), rows[:, n:2 * n].copy(), rows[:, -1].copy(), unary)
        self.reset()
        return out
