"""The compressed storage of a large EKF state (Guivant & Nebot 2001): an *active* block ``A`` (the vehicle and the
landmarks near it) updated at ``O(|A|^2)``, the rest ``B`` kept exact through three accumulators and flushed when
the active set changes. See :mod:`semslam.slam.ekf` for the model that uses it."""

from __future__ import annotations

import numpy as np

from . import _ekf_kernels as kern


class CompressedState:
    """State ``x``, covariance ``P`` and the active-set book-keeping (``xa``, ``Paa`` are the active block)."""

    x: np.ndarray
    P: np.ndarray

    @property
    def active_indices(self) -> np.ndarray:
        """Global indices of the active block, in the order of ``xa`` / ``Paa``."""
        return self._A

    def active_index(self, i: int) -> int:
        """Position of global state index ``i`` in the active block (``xa``, ``Paa``); -1 when passive."""
        return int(self._loc[i])

    # ------------------------------------------------------------------ active set / compression
    @property
    def n(self) -> int:
        return len(self.x)

    @property
    def compressed(self) -> bool:
        return len(self._B) > 0

    def _set_active(self, A: np.ndarray) -> None:
        A = np.asarray(A, dtype=np.intp)
        self._A = A
        mask = np.ones(self.n, dtype=bool)
        mask[A] = False
        self._B = np.flatnonzero(mask)
        self._loc = np.full(self.n, -1, dtype=np.intp)
        self._loc[A] = np.arange(len(A))
        self.xa = self.x[A].copy()
        self.Paa = np.ascontiguousarray(self.P[np.ix_(A, A)])
        nA = len(A)
        self._phi = np.eye(nA)
        self._psi = np.zeros((nA, nA))
        self._theta = np.zeros(nA)
        self._dirty = False

    def flush(self) -> None:
        """Write the active block back and apply the deferred update to the passive part (``O(n^2)``)."""
        A, B = self._A, self._B
        if len(B) and self._dirty:
            PAB0 = self.P[np.ix_(A, B)]
            self.x[B] += PAB0.T @ self._theta
            w, V = np.linalg.eigh(0.5 * (self._psi + self._psi.T))
            keep = w > 0
            W = np.zeros((self.n, int(keep.sum())))
            W[B] = PAB0.T @ (V[:, keep] * np.sqrt(w[keep]))
            kern.subtract_outer_inplace(self.P, W)
            PAB = self._phi @ PAB0
            self.P[np.ix_(A, B)] = PAB
            self.P[np.ix_(B, A)] = PAB.T
        self.P[np.ix_(A, A)] = self.Paa
        self.x[A] = self.xa
        self._set_active(A)

    def is_active_index(self, i: int) -> bool:
        return self._loc[i] >= 0

    # ------------------------------------------------------------------ views of the full state
    def mean(self, idx) -> np.ndarray:
        """Current mean of the global state indices ``idx``."""
        idx = np.asarray(idx, dtype=np.intp)
        loc = self._loc[idx]
        out = np.empty(len(idx))
        a = loc >= 0
        if a.all():
            return self.xa[loc]
        out[a] = self.xa[loc[a]]
        if (~a).any():
            b = idx[~a]
            out[~a] = self.x[b] + self.P[np.ix_(self._A, b)].T @ self._theta
        return out

    def cov(self, idx) -> np.ndarray:
        """Current covariance block of the global state indices ``idx`` (exact, also for passive states)."""
        idx = np.asarray(idx, dtype=np.intp)
        loc = self._loc[idx]
        if loc.min() >= 0:
            return self.Paa[np.ix_(loc, loc)]
        a = np.flatnonzero(loc >= 0)
        b = np.flatnonzero(loc < 0)
        C = np.empty((len(idx), len(idx)))
        la = loc[a]
        C[np.ix_(a, a)] = self.Paa[np.ix_(la, la)]
        if len(b):
            gb = idx[b]
            PAb0 = self.P[np.ix_(self._A, gb)]
            C[np.ix_(b, b)] = self.P[np.ix_(gb, gb)] - PAb0.T @ self._psi @ PAb0
            Cab = self._phi[la] @ PAb0
            C[np.ix_(a, b)] = Cab
            C[np.ix_(b, a)] = Cab.T
        return C

    def full_state(self) -> tuple[np.ndarray, np.ndarray]:
        """``(x, P)`` of the whole state (flushes; ``O(n^2)``)."""
        self.flush()
        return self.x.copy(), self.P.copy()

