"""Timing on a busy vehicle computer, without ROS: a reordering window over message stamps and a keep-newest
slot of size one between the callbacks and the recognition worker.

* :class:`ReorderBuffer`: messages are released in stamp order once a message newer by ``window_s`` has come
  (or at :meth:`ReorderBuffer.flush`); a message older than one already released is dropped and counted, never
  a crash. Stamps are the messages' own (``rosbag play`` and ``/clock`` work), never wall time.
* :class:`LatestSlot`: a queue of length one; putting into a full slot replaces (drops) the waiting item and
  says so, so that a slow consumer always gets the newest item and the drops are counted by the caller.
"""

from __future__ import annotations

import heapq
import itertools
import math
import threading
from typing import Any

from ...errors import InputError
from ..messages import ORDER

__all__ = ["KIND_ORDER", "FifoSlot", "LatestSlot", "ReorderBuffer"]

#: processing order at equal stamps (the runner's: :data:`semslam.run.messages.ORDER`)
KIND_ORDER = dict(ORDER)


class ReorderBuffer:
    """Release ``(stamp_s, kind, payload)`` in ``(stamp, kind order, arrival)`` order ``window_s`` behind the
    newest stamp seen. Not thread-safe: the caller holds its lock."""

    def __init__(self, window_s: float) -> None:
        if not (isinstance(window_s, (int, float)) and math.isfinite(window_s) and window_s >= 0):
            raise InputError(f"The 'window_s' argument of ReorderBuffer must be a finite number >= 0 (s). "
                             f"Got {window_s!r} instead.")
        self.window_s = float(window_s)
        self._heap: list[tuple[float, int, int, str, Any]] = []
        self._seq = itertools.count()
        self.newest_s = -math.inf
        self.released_s = -math.inf
        #: messages dropped because they came after a newer one had been released, per kind
        self.dropped_late: dict[str, int] = {}
        self.n_reordered = 0

    def __len__(self) -> int:
        return len(self._heap)

    def push(self, stamp_s: float, kind: str, payload: Any) -> list[tuple[float, str, Any]]:
        """Add a message; return what is now released (possibly empty), oldest first."""
        t = float(stamp_s)
        if not math.isfinite(t):
            raise InputError(f"The 'stamp_s' argument of ReorderBuffer.push must be finite. Got {stamp_s!r} instead.")
        if t < self.released_s:
            self.dropped_late[kind] = self.dropped_late.get(kind, 0) + 1
            return []
        if t < self.newest_s:
            self.n_reordered += 1
        self.newest_s = max(self.newest_s, t)
        heapq.heappush(self._heap, (t, KIND_ORDER.get(kind, 9), next(self._seq), kind, payload))
        return self._release(self.newest_s - self.window_s)

    def flush(self) -> list[tuple[float, str, Any]]:
        """Release everything held."""
        return self._release(math.inf)

    def _release(self, upto_s: float) -> list[tuple[float, str, Any]]:
        out = []
        while self._heap and self._heap[0][0] <= upto_s:
            t, _, _, kind, payload = heapq.heappop(self._heap)
            self.released_s = max(self.released_s, t)
            out.append((t, kind, payload))
        return out


class LatestSlot:
    """A thread-safe queue of length one that keeps the newest item."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: Any = None
        self._full = False
        self._closed = False
        self.n_dropped = 0

    def put(self, item: Any) -> Any:
        """Store ``item``; return the waiting item it replaced (dropped, counted), else None."""
        with self._cond:
            if self._closed:
                raise InputError("LatestSlot.put after close().")
            old = self._item if self._full else None
            if self._full:
                self.n_dropped += 1
            self._item, self._full = item, True
            self._cond.notify_all()
            return old

    def get(self, timeout: float | None = None) -> Any:
        """The waiting item (the slot is then empty); None when closed and empty, or on timeout."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._full or self._closed, timeout):
                return None
            if not self._full:
                return None
            item, self._item, self._full = self._item, None, False
            self._cond.notify_all()
            return item

    def wait_empty(self, timeout: float | None = None) -> bool:
        """Block until a consumer has taken the waiting item (True), or the timeout (False)."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._full, timeout)

    @property
    def full(self) -> bool:
        with self._cond:
            return self._full

    def close(self) -> None:
        """Wake the consumer: :meth:`get` returns what is waiting, then None."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()


class FifoSlot(LatestSlot):
    """The same interface without a length limit: nothing is dropped (replays that must match an offline run)."""

    def __init__(self) -> None:
        super().__init__()
        self._items: list[Any] = []

    def put(self, item: Any) -> Any:
        with self._cond:
            if self._closed:
                raise InputError("FifoSlot.put after close().")
            self._items.append(item)
            self._full = True
            self._cond.notify_all()
            return None

    def get(self, timeout: float | None = None) -> Any:
        with self._cond:
            if not self._cond.wait_for(lambda: self._items or self._closed, timeout) or not self._items:
                return None
            item = self._items.pop(0)
            self._full = bool(self._items)
            self._cond.notify_all()
            return item
