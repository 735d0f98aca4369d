"""Fixed-interval Rauch-Tung-Striebel smoothing of a :class:`~semslam.slam.ekf.SemanticEkf` run (offline).

The filter's estimate at time ``t`` uses the measurements up to ``t`` only: during the first loop, before the
vehicle comes back to the landmarks it mapped, the filtered trajectory drifts like dead reckoning even though the
loop closure later tells where it really was. The RTS smoother (Rauch, Tung & Striebel 1965; Bar-Shalom, Li &
Kirubarajan 2001, sec. 8.6) gives the estimate at every epoch conditioned on the *whole* mission, for maps,
post-processing and evaluation. It does not change the filter: the online estimate is unchanged.

How. A :class:`RtsRecorder` attached to the filter (``ekf.recorder``) sees every operation that is not a
measurement update (the prediction, the state augmentation of a new landmark, a covariance inflation, the
re-parametrisation of a landmark beyond pitch 90 degrees) as a *transition* ``x' = F x + w`` and composes
consecutive transitions into one; a measurement update or an epoch mark closes the composed transition. A node
is the filter state between two transitions: the recorder keeps its filtered posterior ``(x_j, P_j)``, the prior
``(x_j^-, P_j^-)`` that the composed transition ``F_j`` made of the previous posterior, and then

    C_j = P_{j-1} F_j^T (P_j^-)^+,   x^s_{j-1} = x_{j-1} + C_j (x^s_j - x_j^-),
    P^s_{j-1} = P_{j-1} + C_j (P^s_j - P_j^-) C_j^T,

backwards from the final state (angles of the difference wrapped). The state grows when landmarks are added: the
augmentation is a transition whose ``F`` has more rows than columns, which RTS handles as is. ``(P_j^-)^+`` is a
pseudo-inverse (eigenvalues below ``1e-12`` of the largest dropped): states without process noise, such as the
DVL slope bias over flat ground, make ``P^-`` nearly singular.

Memory. Every node stores two full covariances and the composed transition, ``O(n^2)`` each: ~30 MB for the
default mission (~1,000 nodes of 45 states), ~0.8 GB for a 30-minute dive with four landmarks (~27,000 nodes of
33 states). The first ``ram_bytes`` stay in memory; the rest go to an unnamed temporary file (deleted when closed,
even on a crash) and are read back one node at a time by the backward pass, so resident memory stays flat
however long the dive. The recorder stops, and says so in :attr:`RtsRecorder.status`, when the history would
exceed ``max_bytes`` or the temporary file cannot be written (a full disk).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dpotrf, dpotrs

__all__ = ["NodeStore", "RtsRecorder", "SmoothedStates"]


@dataclass(frozen=True, eq=False)
class SmoothedStates:
    """Smoothed means and covariances of the first ``n_keep`` state entries at the marked epochs.

    ``x`` (K, n_keep), ``P`` (K, n_keep, n_keep).
    """

    x: np.ndarray
    P: np.ndarray


class RtsRecorder:
    """Records a filter run for the RTS smoother; see the module docstring.

    Parameters
    ----------
    n_keep : int
        Leading state entries returned at the marked epochs (the vehicle position and velocity: 6).
    max_bytes : float
        Budget of the stored history (memory and temporary file); beyond it recording stops (``status`` says why)
        and :meth:`smooth` returns None.
    ram_bytes : float
        The part of the history kept in memory; the rest goes to a temporary file.
    """

    def __init__(self, n_keep: int = 6, max_bytes: float = 512e6, ram_bytes: float = 16e6) -> None:
        self.n_keep = int(n_keep)
        self.max_bytes = float(max_bytes)
        self.status = "recording"
        self._bytes = 0
        # node j (j = 0 .. J-1): its posterior x, P and the prior x-, P-, F, angle mask of the next
        self._nodes = NodeStore(ram_bytes)
        self._open: tuple[np.ndarray, np.ndarray] | None = None  # posterior snapshot of the current node
        self._F: np.ndarray | None = None  # composed transition since that snapshot
        self._marks: list[int] = []

    @property
    def active(self) -> bool:
        return self.status == "recording"

    # -------------------------------------------------------------- hooks called by the filter
    def before_transition(self, ekf) -> None:
        """A transition is about to change ``ekf``: snapshot its posterior if this opens a new segment."""
        if not self.active or self._open is not None:
            return
        snap = self._take(ekf)
        if snap is not None:
            self._open = snap
            self._F = np.eye(len(snap[0]))

    def compose(self, F_op: np.ndarray, rows: int | None = None) -> None:
        """Apply the transition Jacobian ``F_op`` to the composed one. ``rows``: ``F_op`` acts on the first
        ``rows`` entries only (identity on the rest), as the prediction does on the vehicle block."""
        if not self.active or self._F is None:
            return
        if rows is None:
            self._F = F_op @ self._F
        else:
            self._F[:rows] = F_op @ self._F[:rows]

    def before_update(self, ekf) -> None:
        """A measurement update is about to change ``ekf``: close the open transition (a new node)."""
        if self.active and self._open is not None:
            self._close(ekf)

    def mark(self, ekf) -> None:
        """Remember the current node as an epoch whose smoothed state :meth:`smooth` returns."""
        if not self.active:
            return
        if self._open is not None:
            self._close(ekf)
        self._marks.append(len(self._nodes))

    def _take(self, ekf) -> tuple[np.ndarray, np.ndarray] | None:
        """A snapshot of ``ekf`` within the memory budget, else None (and recording stops)."""
        x, P = _snapshot(ekf)
        self._bytes += P.nbytes
        if self._bytes > self.max_bytes:
            self._stop(f"skipped: the smoother's covariances would exceed {self.max_bytes / 1e6:.0f} MB "
                       f"(state of {len(x)})")
            return None
        return x, P

    def _close(self, ekf) -> None:
        snap = self._take(ekf)
        if snap is None:
            return
        x, P = snap
        self._bytes += self._F.nbytes
        try:
            self._nodes.append((*self._open, x, P, self._F, _angle_mask(ekf)))
        except OSError as err:  # the temporary file cannot be written (a full disk): no smoothing, said
            self._stop(f"skipped: the smoother's history could not be written to a temporary file ({err})")
            return
        self._open, self._F = None, None

    def _stop(self, why: str) -> None:
        self.status = why
        self._nodes.close()
        self._nodes, self._marks = NodeStore(0), []
        self._open, self._F = None, None

    # -------------------------------------------------------------- the backward pass
    def smooth(self, ekf) -> SmoothedStates | None:
        """Run the backward pass from ``ekf``'s final state; None if recording stopped (see ``status``)."""
        if not self.active:
            return None
        xs, Ps = _snapshot(ekf)
        J = len(self._nodes)
        k = self.n_keep
        out_x = np.empty((len(self._marks), k))
        out_P = np.empty((len(self._marks), k, k))
        marks = np.asarray(self._marks, dtype=np.intp)
        order = np.argsort(-marks, kind="stable")
        m = 0
        for j in range(J, -1, -1):
            while m < len(order) and marks[order[m]] == j:
                out_x[order[m]] = xs[:k]
                out_P[order[m]] = Ps[:k, :k]
                m += 1
            if j == 0:
                break
            x_po, P_po, x_pr, P_pr, F, ang = self._nodes[j - 1]
            d = xs - x_pr
            d[ang] = (d[ang] + np.pi) % (2.0 * np.pi) - np.pi
            C = _gain(P_po @ F.T, P_pr)
            xs = x_po + C @ d
            Ps = P_po + C @ (Ps - P_pr) @ C.T
            Ps = 0.5 * (Ps + Ps.T)
        self.status = "ok"
        self._nodes.close()
        return SmoothedStates(out_x, out_P)


class NodeStore:
    """Append-only list of tuples of arrays: in memory up to ``ram_bytes``, the rest in an unnamed temporary file
    (``tempfile.TemporaryFile``: gone when closed or when the process ends), read back by offset."""

    def __init__(self, ram_bytes: float) -> None:
        self.ram_bytes = float(ram_bytes)
        self._mem: list[tuple] = []
        self._ram = 0
        self._file = None
        self._index: list[tuple[int, tuple]] = []  # node len(_mem) + k: (file offset, (shape, dtype) per array)

    def __len__(self) -> int:
        return len(self._mem) + len(self._index)

    def append(self, arrays: tuple) -> None:
        size = sum(a.nbytes for a in arrays)
        if self._file is None and self._ram + size <= self.ram_bytes:
            self._mem.append(arrays)
            self._ram += size
            return
        if self._file is None:
            import tempfile

            self._file = tempfile.TemporaryFile(prefix="semslam-smoother-")
        self._file.seek(0, 2)
        self._index.append((self._file.tell(), tuple((a.shape, a.dtype.str) for a in arrays)))
        for a in arrays:  # raw bytes: the index keeps shapes and types (np.save's headers cost ~1 ms a node)
            self._file.write(np.ascontiguousarray(a).tobytes())

    def __getitem__(self, j: int) -> tuple:
        if j < len(self._mem):
            return self._mem[j]
        offset, layout = self._index[j - len(self._mem)]
        self._file.seek(offset)
        out = []
        for shape, dtype in layout:
            buf = bytearray(int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize)
            if self._file.readinto(buf) != len(buf):
                raise OSError("The smoother's temporary file ended early.")
            out.append(np.frombuffer(buf, dtype=dtype).reshape(shape))  # writable: the bytearray is its own
        return tuple(out)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
        self._mem, self._index = [], []


def _snapshot(ekf) -> tuple[np.ndarray, np.ndarray]:
    """Copy of the whole ``(x, P)``; a compressed filter is flushed first (exact), an uncompressed one is only
    read, so that recording leaves the filter's arrays untouched."""
    if ekf.compressed:
        return ekf.full_state()
    A = ekf.active_indices
    if len(A) == ekf.n and (not len(A) or (A[0] == 0 and bool(np.all(A[1:] > A[:-1])))):  # every state, in order
        return np.array(ekf.xa, dtype=float), np.array(ekf.Paa, dtype=float)
    x = np.empty(ekf.n)
    x[A] = ekf.xa
    P = np.empty((ekf.n, ekf.n))
    P[np.ix_(A, A)] = ekf.Paa
    return x, P


def _angle_mask(ekf) -> np.ndarray:
    """Boolean mask of the angle entries of ``ekf``'s state (landmark roll/pitch/yaw, the yaw bias)."""
    mask = np.zeros(ekf.n, dtype=bool)
    for lm in ekf.landmarks:
        mask[lm.offset + 3:lm.offset + 6] = True
    if ekf.yaw_bias:
        mask[ekf.i_yaw] = True
    return mask


def _gain(PFt: np.ndarray, P_pr: np.ndarray) -> np.ndarray:
    """``PFt (P_pr)^-1``: a Cholesky solve on the correlation form of ``P_pr`` (its diagonal scaled to one), the
    pseudo-inverse when that is not positive definite (states with no variance left)."""
    d = np.sqrt(np.diagonal(P_pr))
    if d.min() > 1e-9 * d.max():
        # LAPACK's potrf/potrs as scipy's cho_factor/cho_solve call them (the same numbers), without their argument
        # checks: ~0.1 ms of a ~0.3 ms backward step, at every node of the dive
        c, info = dpotrf(P_pr / np.outer(d, d), lower=0, clean=0)
        if info == 0:
            x, info = dpotrs(c, (PFt / d).T, lower=0)
            if info == 0:
                return (x / d[:, None]).T
    return PFt @ _pinv_psd(P_pr)


def _pinv_psd(P: np.ndarray) -> np.ndarray:
    """Pseudo-inverse of a symmetric positive semi-definite matrix (eigenvalues < 1e-12 of the largest dropped)."""
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    keep = w > 1e-12 * max(float(w[-1]), 1e-300)
    return (V[:, keep] / w[keep]) @ V[:, keep].T
