"""A run's scans from their message to their final detections (:class:`ScanFlow`, the :class:`~semslam.run.Runner`'s
recognition side).

A scan waits for the navigation after its end when it is deskewed (:mod:`semslam.pipeline.deskew`), is recognised
(in the caller's thread, or ``lookahead`` scans at once in background threads), and, when the recogniser tracks
border-cut clusters (``PipelineConfig.track_border_cut_m``, :mod:`semslam.pipeline.tracking`), is final only once the
scan after it is recognised: its border-cut clusters are tried as the objects of the scan before (priors given to its
recognition) and of the scan after (an object entering the swath, recognised whole one scan later;
:func:`~semslam.pipeline.dataset_detection.track_from_scan_after`). A scan the filters are about to pass is made final
with what has come: the scan after it waited for when it is in recognition, left out when it has not come. What comes
out depends only on the messages and their order, never on the threads' timing: the same for every ``lookahead``.
"""

from __future__ import annotations

import math
from typing import Any, Callable

from .._memory import TRIM_ABOVE_BYTES, release_free_memory
from ..pipeline.dataset_detection import (detect_scan, final_scan, first_stamp_s, priors_from_scan_before,
                                          track_from_scan_after)
from ..pipeline.deskew import NavigationHistory, deskew_lookahead_s, deskews
from ..pipeline.tracking import SPANS_TO_THE_SCAN_AFTER, follows_closely, tracks
from .messages import Scan

__all__ = ["ScanFlow"]


class ScanFlow:
    """Scans in (:meth:`add`), final detections out (``on_final(msg, kept, stats, result)``, in stream order).

    Parameters
    ----------
    recognizer : ScanRecognizer
    vehicle : VehicleDescription
    nav : NavigationHistory
        The run's recent attitude and DVL (the caller adds to it): deskewing and tracking read it.
    on_final : callable
    counts : dict
        The run's counts (``scans_not_deskewed`` is added to it).
    seed, keep_unreliable, up_from_attitude, lookahead
        As :class:`~semslam.run.Runner`.
    before_pool : callable, optional
        Called once before the first background thread starts (the runner limits BLAS's threads there).
    """

    def __init__(self, recognizer: Any, vehicle: Any, nav: NavigationHistory, on_final: Callable, counts: dict, *,
                 seed: int = 0, keep_unreliable: bool = False, up_from_attitude: bool = False, lookahead: int = 0,
                 before_pool: Callable | None = None) -> None:
        self.recognizer, self.vehicle, self.nav, self.on_final, self.counts = recognizer, vehicle, nav, on_final, counts
        self.seed, self.keep_unreliable, self.up_from_attitude = seed, keep_unreliable, up_from_attitude
        self.lookahead, self.before_pool = lookahead, before_pool
        self.lookahead_s = deskew_lookahead_s(recognizer)  # navigation a scan waits for after its end
        self.tracking = tracks(recognizer)
        self.in_flight: list = []  # scans in recognition, in stream order: (first point's stamp, message, future)
        self.waiting: list = []    # scans to deskew, waiting for the navigation after their end: (msg, up, first stamp)
        self.pending = None        # the last scan recognised, not final: (message, first stamp, detect_scan output)
        self._before = None        # the last scan submitted: (a callable giving its output, its first stamp, message)
        self._pool = None
        self._newest = -math.inf

    def hold_s(self, msg: Scan) -> float:
        """How far behind the newest message the filters must stay for ``msg``'s detections to be final before they
        pass its first point: its span twice (:data:`~semslam.pipeline.tracking.SPANS_TO_THE_SCAN_AFTER` times when
        the scan after it is waited for: tracking), plus the navigation it waits for when deskewed."""
        span = msg.end_stamp_s - msg.start_stamp_s
        hold = (max(2.0, SPANS_TO_THE_SCAN_AFTER) if self.tracking else 2.0) * span
        return hold + (self.lookahead_s if deskews(self.recognizer, msg.point_stamps_s) else 0.0)

    def add(self, msg: Scan, newest_s: float) -> None:
        """A scan message (``newest_s``: the newest stamp of the run so far)."""
        from ..pipeline.dataset_detection import up_from_attitude_samples

        self._newest = max(self._newest, newest_s)
        up = None
        if self.up_from_attitude and self.nav.attitude:
            ts, rpy = self.nav.attitude_arrays()
            up = up_from_attitude_samples(ts, rpy, self.vehicle.scanner.T_vehicle_scanner,
                                          0.5 * (msg.start_stamp_s + msg.end_stamp_s))
        first_s = first_stamp_s(msg.point_stamps_s, msg.start_stamp_s)
        if deskews(self.recognizer, msg.point_stamps_s):  # recognised once the navigation after its end has come
            self.waiting.append((msg, up, first_s))
            self.submit_waiting(final=False)
            return
        self._submit(msg, up, None, first_s)

    def navigation_came(self, newest_s: float) -> None:
        """A navigation message at ``newest_s`` came: the scans waiting for it are recognised."""
        self._newest = max(self._newest, newest_s)
        if self.waiting:
            self.submit_waiting(final=False)

    def before(self, limit_s: float) -> None:
        """Every scan starting at or before ``limit_s`` made final (the filters are about to pass it)."""
        if self.waiting:  # (never before its navigation has come, with the hold lengthened by the wait)
            self.submit_waiting(final=False, before_s=limit_s)
        self.collect(block_over=self.lookahead, before_s=limit_s)

    def finish(self) -> None:
        """Every scan recognised and made final."""
        self.submit_waiting(final=True)
        self.collect(block_over=0, before_s=math.inf)

    def submit_waiting(self, final: bool, before_s: float = -math.inf) -> None:
        """Recognise the scans waiting for navigation: those whose end is ``lookahead_s`` behind the newest stamp
        (every navigation sample up to there has come), those starting before ``before_s`` (the filters are about to
        pass them), or all of them (``final``)."""
        while self.waiting:
            msg, up, first_s = self.waiting[0]
            if not (final or msg.end_stamp_s + self.lookahead_s <= self._newest or first_s <= before_s):
                return
            self.waiting.pop(0)
            self._submit(msg, up, self._scan_motion(msg), first_s)

    def _submit(self, msg: Scan, up, motion, first_s: float) -> None:
        T_vs = self.vehicle.scanner.T_vehicle_scanner
        link = self._motion_since_before(msg)
        kw = dict(scan_id=msg.scan_id, start_stamp_s=msg.start_stamp_s, end_stamp_s=msg.end_stamp_s,
                  point_stamps_s=msg.point_stamps_s, seed=self.seed, keep_unreliable=self.keep_unreliable,
                  up_scanner=up, motion=motion, T_vehicle_scanner=T_vs)
        back = None
        if link is not None:
            get_before, before_first_s, bmsg = self._before
            kw["priors"] = priors_from_scan_before(lambda: get_before()[2].detections, link, T_vs, msg.end_stamp_s)
            if follows_closely(before_first_s, bmsg.start_stamp_s, bmsg.end_stamp_s, msg.end_stamp_s):

                def back(out):  # the scan before, tracked from this one's objects
                    return track_from_scan_after(self.recognizer, get_before(), out[2].detections, link, T_vs,
                                                 self.keep_unreliable)
        if not self.lookahead:
            out = detect_scan(self.recognizer, msg.cloud, **kw)
            self._before = ((lambda: out), first_s, msg)
            self._recognised(msg, first_s, out, None if back is None else back(out))
            return
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor

            if self.before_pool is not None:  # (the runner limits BLAS's threads before any worker runs: changing
                self.before_pool()                # OpenBLAS's thread count while a thread is inside BLAS can crash)
            self._pool = ThreadPoolExecutor(self.lookahead, thread_name_prefix="semslam-recognition")
        fut = self._pool.submit(_detect_and_trim, self.recognizer, msg.cloud, back, **kw)
        self.in_flight.append((first_s, msg, fut))
        # (the next scan's worker waits for this one's output: submitted first, it never waits on the next)
        self._before = ((lambda: fut.result()[0]), first_s, msg)
        self.collect(block_over=self.lookahead)

    def _motion_since_before(self, msg: Scan):
        """The vehicle's motion from the scan before's first point to ``msg``'s end, from the navigation held
        (None: tracking off, no scan before, or no navigation)."""
        if self._before is None or not self.tracking:
            return None
        return self.nav.motion(self.vehicle.dvl.T_vehicle_dvl.rotation, self._before[1], msg.end_stamp_s,
                               lookahead_s=self.lookahead_s)

    def _scan_motion(self, msg: Scan):
        """The vehicle's motion over a scan from the navigation held (None: no navigation over the scan, counted
        in ``counts["scans_not_deskewed"]``)."""
        motion = self.nav.scan_motion(self.vehicle.dvl.T_vehicle_dvl.rotation, msg.point_stamps_s, msg.end_stamp_s,
                                      lookahead_s=self.lookahead_s)
        if motion is None:
            self.counts["scans_not_deskewed"] = self.counts.get("scans_not_deskewed", 0) + 1
        return motion

    def _recognised(self, msg: Scan, first_s: float, out, before_final) -> None:
        """Scan ``msg`` recognised (``out``), and the scan before made final from it (``before_final``; None: not
        tracked): the scan before final, this one pending (final at once without tracking)."""
        if not self.lookahead:  # a scan's arrays freed: the heap's free pages back to the system (semslam._memory)
            release_free_memory(TRIM_ABOVE_BYTES)
        if self.pending is not None:
            pmsg, _, pout = self.pending
            self.pending = None
            self.on_final(pmsg, *(before_final if before_final is not None else final_scan(pout)))
        if self.tracking:
            self.pending = (msg, first_s, out)
        else:
            self.on_final(msg, *out)

    def collect(self, block_over: int, before_s: float = -math.inf) -> None:
        """Take the recognised scans in stream order: those done, and (waiting for them) those beyond
        ``block_over`` in flight, starting before ``before_s``, or after a pending scan starting before it; then
        the pending scan made final if it starts before ``before_s`` (no scan after it in recognition)."""
        while self.in_flight:
            first_s, msg, fut = self.in_flight[0]
            due = first_s <= before_s or (self.pending is not None and self.pending[1] <= before_s)
            if not (fut.done() or len(self.in_flight) > block_over or due):
                break
            self.in_flight.pop(0)
            self._recognised(msg, first_s, *fut.result())
        if self.pending is not None and self.pending[1] <= before_s and not self.in_flight:
            pmsg, _, pout = self.pending
            self.pending = None
            self.on_final(pmsg, *final_scan(pout))

    def close(self) -> None:
        """Cancel the scans not yet started and wait for those in recognition (they hold no lock: short)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        self.in_flight, self.waiting, self.pending = [], [], None


def _detect_and_trim(recognizer, cloud, back, **kw):
    """:func:`detect_scan` in a worker thread, the scan before made final from it (``back``, or None), then the
    heap's free pages back to the system (off the thread that reads the dive and runs the filters)."""
    out = detect_scan(recognizer, cloud, **kw)
    before_final = None if back is None else back(out)
    release_free_memory(TRIM_ABOVE_BYTES)
    return out, before_final
