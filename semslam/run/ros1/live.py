"""The node's one piece of wiring: decoded messages in, the one streaming runner's estimate out (no rospy here).

:class:`LiveSlam` turns the node's decoded messages into :mod:`semslam.run.messages` objects (as
:mod:`semslam.run.sources` does for a bag: scan ids in arrival order, empty scans skipped, fixes placed about the
topic map's ``[origin]``, a prior map's, or the first usable fix) and feeds them to one
:class:`semslam.run.runner.Runner`: the start from the dive's own data, fixes as gated updates, a prior map, all
modes in one pass, the delay line (``hold_s``) that puts the detections in stamp order, and the late messages
counted (``counts["late_dropped"]``) are the runner's, exactly as in ``semslam run``.

Only three things are the node's own:

0. **The source's reorder window** (``reorder_window_s``, :class:`~semslam.run.ros1.timing.ReorderBuffer`): the
   runner takes messages in stamp order (a source's promise; a bag source reorders within 2 s), topics arrive with
   their transport delays. Older than what was released: dropped, counted (``dropped_late``, with the runner's).
1. **Recognition off the dispatcher thread.** A scan goes to a worker as it arrives, ahead of the reorder window,
   through a keep-newest slot of size one (a scan waiting when a newer one comes is dropped, counted); its
   detections enter through :meth:`Runner.add_scan_detections`. The runner's delay line is in message time,
   recognition takes wall time: a navigation message whose feeding would release the filter past the start of a
   scan still in recognition (``stamp - hold_s > scan start``; tracking: past the first stamp of the scan before
   it, which may gain from it) waits here, at most ``max_hold_s`` of message time,
   then that scan is given up (``scans_late``; its detections are counted late by the runner). With nothing given
   up or dropped, the runner receives what ``semslam run`` gives it: the same estimate. (Tracking,
   ``track_border_cut_m``, follows objects from the scan the worker recognised before; a scan it makes final from
   the scan after is published again once the scan after is out, the filter waiting for it;
   ``tracked_from_scan_after`` counts what it gained.)
2. **The low-latency prediction** (:meth:`LiveSlam.predict_to`): the published mode's filter state carried to each
   attitude sample as it arrives, through the attitude samples received since the filter's time.

Callbacks: ``on_estimate(live)`` after each batch that moved the filter (``/semslam/odometry/filtered``),
``on_prediction(live, prediction)`` on every attitude sample (both with the lock held: keep them short),
``on_detections(job, result, latency_s)`` after each recognised scan (worker thread, without the lock).
"""

from __future__ import annotations

import bisect
import math
import threading
import time
from typing import Any, Callable

import numpy as np

from ..._memory import TRIM_ABOVE_BYTES, release_free_memory
from ...errors import SemslamError, SlamError
from ...pipeline.deskew import deskew_lookahead_s, deskews
from ..messages import Attitude, Depth, Dvl, Scan
from .live_deskew import DeskewQueue, ScanJob, recognise_job, tracked_back
from .live_health import LogTally, live_health
from .live_prediction import Prediction, carry_forward, session_attitude
from .timing import FifoSlot, LatestSlot, ReorderBuffer

__all__ = ["LiveSlam", "Prediction", "ScanJob", "live_health"]

_KINDS = ("attitude", "dvl", "depth", "fix", "scan")


class LiveSlam:
    """Messages in (any thread), the runner's estimate out. See the module docstring.

    Parameters
    ----------
    vehicle : VehicleDescription
    recognizer : ScanRecognizer or None
        None: navigation only (scans only lengthen the runner's delay line).
    mode : str
        The published mode (its filter gives the odometry).
    modes : sequence of str, optional
        Every mode run in the one pass (default: ``(mode,)``); ``mode`` must be one of them.
    config, symmetries, backend, survey, seed, keep_unreliable, up_from_attitude
        As :class:`~semslam.run.runner.Runner` (scan ``k`` is recognised with seed ``scan_seed(seed, k)``).
    reorder_window_s : float
        Messages are released to the runner this far (message time) behind the newest; it must exceed the spread
        of the sensors' transport delays (a scan published at its end: its sweep duration).
    geodetic_origin : GeodeticOrigin, optional
        The world frame's origin (the topic map's ``[origin]``, a prior map's); None: the first usable fix.
    max_hold_s : float
        At most this much navigation (message time) waits behind a scan in recognition.
    scan_queue : {"newest", "all"}
        "newest" (on a vehicle): a keep-newest slot of size one, drops counted; "all": every scan is recognised,
        however late (replays that must give the offline result; use a large ``max_hold_s``).
    """

    def __init__(self, vehicle, recognizer=None, *, mode: str = "pose", modes=None, config=None, symmetries=None,
                 backend: str = "ekf", survey=None, seed: int = 0, keep_unreliable: bool = False,
                 up_from_attitude: bool = False, geodetic_origin=None, reorder_window_s: float = 0.5,
                 max_hold_s: float = 5.0, scan_queue: str = "newest",
                 on_estimate: Callable[["LiveSlam"], None] | None = None,
                 on_prediction: Callable[["LiveSlam", "Prediction"], None] | None = None,
                 on_detections: Callable[[ScanJob, Any, float], None] | None = None) -> None:
        from ..runner import Runner

        modes = (mode,) if modes is None else tuple(modes)
        if mode not in modes:
            raise SlamError(f"The 'mode' argument of LiveSlam (the published mode) must be one of the run's modes "
                            f"{modes}. Got {mode!r} instead.")
        if not (isinstance(max_hold_s, (int, float)) and math.isfinite(max_hold_s) and max_hold_s > 0):
            raise SlamError(f"The 'max_hold_s' argument of LiveSlam must be a positive number (s). Got {max_hold_s!r}.")
        if scan_queue not in ("newest", "all"):
            raise SlamError(f"The 'scan_queue' argument of LiveSlam must be 'newest' or 'all'. Got {scan_queue!r}.")
        # detections_by_scan={}: the scans' detections come from the worker (add_scan_detections), not the runner
        self.runner = Runner(vehicle, modes=modes, recognizer=None, detections_by_scan={}, config=config,
                             symmetries=symmetries, backend=backend, survey=survey, seed=seed,
                             keep_unreliable=keep_unreliable)
        self.vehicle, self.recognizer, self.mode, self.seed = vehicle, recognizer, mode, int(seed)
        self.keep_unreliable, self.up_from_attitude = bool(keep_unreliable), bool(up_from_attitude)
        self.geodetic_origin = geodetic_origin
        self.geodetic_origin_from = None if geodetic_origin is None else "given"
        self.max_hold_s = float(max_hold_s)
        self.on_estimate, self.on_detections, self.on_prediction = on_estimate, on_detections, on_prediction
        self.recognise = recognizer is not None and any(m != "dr" for m in modes)
        self.lock = threading.RLock()
        self.buffer = ReorderBuffer(reorder_window_s)
        self.slot = LatestSlot() if scan_queue == "newest" else FifoSlot()
        self._recent_attitude: list[tuple[float, np.ndarray]] = []  # arrived, newer than the filter's time
        self._recent_dvl: list[tuple[float, np.ndarray]] = []  # valid DVL samples, newer than the filter's time
        self._held: list = []        # navigation waiting behind a scan in recognition: (message, wall)
        self._deskew = DeskewQueue(vehicle.dvl.T_vehicle_dvl.rotation,  # scans waiting for the navigation
                                   deskew_lookahead_s(recognizer))
        self._pending: list[ScanJob] = []  # scans waiting for or in recognition, in stamp order
        self._n_scans, self._before = 0, None  # the worker's scan before: (its output, first stamp, job)
        # tracking (_advance): first stamps of the scan the worker recognised last and of the one it makes final
        self._last_first_s = self._tracking_back = math.inf
        #: when the message last given to the runner was received (``time.monotonic()``): latency statistics
        self.fed_wall_s = math.nan
        self._filter_t = -math.inf
        self.stats: dict[str, Any] = {"messages": {k: 0 for k in _KINDS}, "scans_recognised": 0, "scans_dropped": 0,
                                      "scans_late": 0, "empty_scans": 0, "recognition_errors": 0,
                                      "navigation_errors": 0, "last_error": "", "scan_latency_s": [], "held_max": 0,
                                      "tracked_from_scan_after": 0}
        self._closed = self._finished = False
        self.health_tally = LogTally()  # live_health's running tally of the session's log
        self._worker = threading.Thread(target=self._work, name="semslam-recognition", daemon=True)
        self._worker.start()

    def warm_up(self, seconds: float | None = None) -> None:
        """Run a throwaway runner (same vehicle, modes, settings; no prior map) over synthetic messages of a vehicle
        at rest, through its start and a finish: the filter's lazy imports and compiled kernels are loaded before
        the first real message (on the node, the first start cost a ~1-3 s stall of the odometry: measured)."""
        from ..runner import Runner

        r = self.runner
        warm = Runner(self.vehicle, modes=r.modes, recognizer=None, detections_by_scan={}, config=r.cfg,
                      symmetries=r.symmetries, backend=r.backend)
        span = r.cfg.initialisation.start_window_s + 1.0 if seconds is None else float(seconds)
        for k in range(int(span * 10) + 1):
            t = 0.1 * k
            warm.feed(Attitude(t, np.zeros(3)))
            if k % 2 == 0:
                warm.feed(Dvl(t, np.zeros(3), True))
                warm.feed(Depth(t, 5.0))
        warm.finish()

    # ------------------------------------------------------------------ input (any thread)
    def add(self, stamp_s: float, kind: str, payload: Any, received_wall_s: float | None = None) -> None:
        """One decoded message (``kind``: attitude, dvl, depth, fix, scan; payloads as
        :func:`semslam.dataset.rosbag.stream_bag` yields them), received at ``received_wall_s``
        (``time.monotonic()``; default now: for the latency statistics only)."""
        wall = time.monotonic() if received_wall_s is None else float(received_wall_s)
        with self.lock:
            if self._closed:
                return
            msg = self._message(float(stamp_s), kind, payload)
            if msg is None:
                return
            self.stats["messages"][kind] = self.stats["messages"].get(kind, 0) + 1
            if kind == "attitude":
                self._recent_attitude.append((msg.stamp_s, np.asarray(msg.rpy_rad, dtype=float)))
            elif kind == "dvl" and msg.valid and np.isfinite(msg.velocity_mps).all():
                self._recent_dvl.append((msg.stamp_s, msg.velocity_mps))
            if kind in ("attitude", "dvl"):  # every sample, valid or not, for the scans' deskewing
                self._deskew.add_navigation(msg)
                self._deskew_ready(final=False)
            if kind == "scan" and msg.stamp_s >= self.buffer.released_s:
                # recognition starts as the scan arrives (it needs no other message): only its entry into the
                # filter waits for the reorder window (a scan the window will drop as late is not recognised)
                self._scan(msg, wall)
            for _, _, (m, w) in self.buffer.push(msg.stamp_s, kind, (msg, wall)):
                self._released(m, w)
            self._advance()
            if kind == "attitude" and self.on_prediction is not None and self.session is not None:
                pred = self.predict_to(msg.stamp_s)
                if pred is not None:
                    self.on_prediction(self, pred)

    def _message(self, t: float, kind: str, payload: Any):
        """A decoded payload as a :mod:`semslam.run.messages` object (None: an empty scan, counted)."""
        if kind == "attitude":
            return Attitude(t, np.asarray(payload, dtype=float))
        if kind == "dvl":
            return Dvl(t, np.asarray(payload[0], dtype=float), bool(payload[1]), payload[2])
        if kind == "depth":
            return Depth(t, float(payload))
        from ..sources import _fix_message, _origin_from_fix, _scan_message

        if kind == "fix":
            if self.geodetic_origin is None:
                self.geodetic_origin = _origin_from_fix(payload)
                if self.geodetic_origin is not None:
                    self.geodetic_origin_from = "the first usable fix"
            return _fix_message(payload, t, self.geodetic_origin)
        if kind == "scan":
            if not payload.points_xyz_m.shape[0]:
                self.stats["empty_scans"] += 1
                return None
            msg = _scan_message(payload, t, self._n_scans)
            self._n_scans += 1
            return msg
        raise SlamError(f"LiveSlam.add: unknown message kind {kind!r} (expected one of {_KINDS}).")

    @property
    def session(self):
        """The published mode's session (None before the start)."""
        return self.runner.sessions.get(self.mode)

    @property
    def dropped_late(self) -> dict[str, int]:
        """Messages dropped as later than what was released (the reorder window) or processed (the runner), per
        kind."""
        out = dict(self.buffer.dropped_late)
        for k, v in self.runner.counts.get("late_dropped", {}).items():
            if v:
                out[k] = out.get(k, 0) + v
        return out

    def _released(self, msg, wall: float) -> None:
        # every message (a scan too: the runner lengthens its delay line to the scan's span) enters the runner in
        # stamp order, behind the scans still in recognition: the runner's newest stamp, hence what it releases,
        # never runs ahead of them
        self._held.append((msg, wall))

    def _scan(self, msg: Scan, wall: float) -> None:
        """To the recognition worker (the keep-newest slot)."""
        if not self.recognise:
            return
        up = None
        if self.up_from_attitude and self._recent_attitude:
            from ...pipeline.dataset_detection import up_from_attitude_samples

            ts, rpy = zip(*self._recent_attitude)
            up = up_from_attitude_samples(np.array(ts), np.array(rpy), self.vehicle.scanner.T_vehicle_scanner,
                                          0.5 * (msg.start_stamp_s + msg.end_stamp_s))
        job = ScanJob(msg, wall, up)
        bisect.insort(self._pending, job, key=lambda j: j.start_s)  # arrival order need not be stamp order
        if deskews(self.recognizer, msg.point_stamps_s):
            self._deskew.waiting.append(job)  # recognised once the navigation after its end has come
            self._deskew_ready(final=False)
            return
        self._to_slot(job)

    def _deskew_ready(self, final: bool) -> None:
        """The scans whose navigation has come to the recognition worker (:class:`DeskewQueue`)."""
        for job in self._deskew.ready(final):
            self._to_slot(job)
        self.stats["scans_not_deskewed"] = self._deskew.not_deskewed

    def poll(self) -> None:
        """Give the recognition worker the scans still waiting for their navigation when none has come for
        ``NAVIGATION_WAIT_S`` of wall clock (the navigation stopped, or the dive ended): deskewed with what came."""
        with self.lock:
            if self._deskew.waiting and not self._closed:
                self._deskew_ready(final=False)
                self._advance()

    def _to_slot(self, job: ScanJob) -> None:
        old = self.slot.put(job)
        if old is not None:
            old.abandoned = True
            self._pending.remove(old)
            self.stats["scans_dropped"] += 1

    def _advance(self) -> None:
        """Feed the held navigation while that keeps the filter behind the oldest scan in recognition (giving that
        scan up when the held navigation is more than ``max_hold_s`` past it)."""
        hold = self.runner.hold_s
        while self._pending and self._held and \
                self._held[-1][0].stamp_s - hold - self._pending[0].start_s > self.max_hold_s:
            job = self._pending.pop(0)
            job.abandoned = True
            self.stats["scans_late"] += 1
        self.stats["held_max"] = max(self.stats["held_max"], len(self._held))
        # and, tracking, behind the first stamp of the scan recognised before it (which may gain from it), and of
        # the scan the worker is making final
        boundary = min(self._pending[0].start_s, self._last_first_s) if self._pending else math.inf
        boundary = min(boundary, self._tracking_back)
        n = 0
        while n < len(self._held) and self._held[n][0].stamp_s - hold <= boundary:
            n += 1
        feed, self._held = self._held[:n], self._held[n:]
        for msg, wall in feed:
            self._feed(msg, wall)
        self._estimate_if_moved()

    def _feed(self, msg, wall: float) -> None:
        self.fed_wall_s = wall
        try:
            self.runner.feed(msg)
        except SemslamError as err:  # a message the filter refuses (a corrupt stamp): counted, the node goes on
            self.stats["navigation_errors"] += 1
            self.stats["last_error"] = f"{msg.kind} at {msg.stamp_s:.3f} s: {err}"

    def _estimate_if_moved(self) -> None:
        s = self.session
        if s is None or s.ekf is None or s.t <= self._filter_t:
            return
        self._filter_t = s.t
        if self.on_estimate is not None:  # once per batch: a catch-up burst stays short
            self.on_estimate(self)

    # ------------------------------------------------------------------ recognition (worker thread)
    def _work(self) -> None:
        from ...pipeline.dataset_detection import first_stamp_s
        from ...pipeline.tracking import tracks

        while True:
            job = self.slot.get()
            if job is None:
                return
            sc, err_text, before, back = job.scan, "", self._before, None
            try:
                (kept, stats, result), back = recognise_job(self, job)
                self._before = ((kept, stats, result), first_stamp_s(sc.point_stamps_s, sc.start_stamp_s), job)
            except SemslamError as err:  # a scan the pipeline refuses: counted, navigation goes on
                kept, stats, result, err_text = [], None, None, f"scan {sc.scan_id}: {err}"
            except Exception as err:  # noqa: BLE001 - a bug must not stop the navigation: counted and reported
                kept, stats, result = [], None, None
                err_text = f"scan {sc.scan_id}: {type(err).__name__}: {err}"
            latency = time.monotonic() - job.received_wall_s
            release_free_memory(TRIM_ABOVE_BYTES)  # the scan's arrays freed: free heap pages back (semslam._memory)
            with self.lock:
                if self._finished:  # close() gave this scan up after its timeout
                    return
                if job in self._pending:
                    self._pending.remove(job)
                if result is None:
                    self.stats["recognition_errors"] += 1
                    self.stats["last_error"] = err_text
                else:
                    self.stats["scans_recognised"] += 1
                    self.stats["scan_latency_s"].append(latency)
                    if len(self.stats["scan_latency_s"]) > 1000:
                        del self.stats["scan_latency_s"][:500]
                    # a scan given up still enters: the runner counts its detections older than its time as late
                    self.runner.add_scan_detections(sc.scan_id, kept, stats)
                    if back is not None:  # the filter waits for what the scan before gains (its first stamp)
                        self._tracking_back = before[1]
                    if tracks(self.recognizer):
                        self._last_first_s = self._before[1]
                self._advance()
            if result is not None and self.on_detections is not None:  # publishing needs no lock: outside it
                self.on_detections(job, result, latency)
            if result is not None and back is not None:
                self._track_back(before, back)

    def _track_back(self, before, back: Callable) -> None:
        """The scan before made final from the one just published (``back()``: its detections went out first):
        what it gained fed to the runner, which waited for it (``_tracking_back``), and the scan published again."""
        before_final, err_text = None, ""
        try:
            before_final = back()
        except SemslamError as err:
            err_text = f"scan {before[2].scan_id}: {err}"
        except Exception as err:  # noqa: BLE001 - as in _work
            err_text = f"scan {before[2].scan_id}: {type(err).__name__}: {err}"
        with self.lock:
            self._tracking_back = math.inf
            if self._finished:
                return
            if err_text:
                self.stats["recognition_errors"] += 1
                self.stats["last_error"] = err_text
            added = tracked_back(self, before, before_final)
            self._advance()
        if added and self.on_detections is not None:
            self.on_detections(before[2], before_final[2], time.monotonic() - before[2].received_wall_s)

    # ------------------------------------------------------------------ outputs
    def predict_to(self, t: float) -> "Prediction | None":
        """The published mode's filter state carried forward to ``t`` (None when ``t`` is before the filter's time):
        the position integrates the body velocity through the attitude samples received after the filter's time
        (the AHRS is the filter's input): the filter's velocity, replaced by each valid DVL sample received since
        (in the body frame through the DVL's mounting; dead reckoning over the runner's delay line), the covariance
        grows by ``dt^2`` times the rotated filter velocity covariance. No depth, fix or landmark update after the
        filter's time is in it: they come with the filter's state
        (:func:`~semslam.run.ros1.live_prediction.carry_forward`)."""
        s = self.session
        if s is None or s.ekf is None:
            return None
        ts = float(s.t)
        self._recent_attitude = [a for a in self._recent_attitude if a[0] > ts - 1e-9]
        self._recent_dvl = [d for d in self._recent_dvl if d[0] > ts - 1e-9]
        if t < ts:
            return None
        return carry_forward(s, t, self._recent_attitude, self._recent_dvl)

    def estimate(self):
        """The runner's :class:`~semslam.slam.results.SlamEstimate` of the published mode (None before the start)."""
        with self.lock:
            return self.runner.estimate(self.mode)

    def attitude_now(self) -> tuple[np.ndarray, np.ndarray | None]:
        """The published filter's attitude (rpy NED, yaw-bias corrected) at its current time and its world
        covariance."""
        return session_attitude(self.session)

    def queue_state(self) -> dict:
        """Scans waiting or in recognition, navigation held behind them, the reorder buffer's length, the runner's
        delay line (s)."""
        with self.lock:
            return {"scans_pending": len(self._pending), "navigation_held": len(self._held),
                    "reorder_buffered": len(self.buffer), "hold_s": self.runner.hold_s}

    def close(self, timeout_s: float = 120.0):
        """Stop taking messages, let the worker finish the scans still queued (at most ``timeout_s``), feed what is
        held and finish the runner. Returns its :class:`~semslam.run.runner.RunOutcome` (None when no attitude
        sample ever came: nothing to estimate)."""
        with self.lock:
            if self._closed:
                raise SlamError("LiveSlam.close was already called.")
            self._closed = True
            for _, _, (m, w) in self.buffer.flush():
                self._released(m, w)
            self._deskew_ready(final=True)
            self._advance()
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if not self._pending and self._tracking_back == math.inf:
                    break
            time.sleep(0.01)
        self.slot.close()
        self._worker.join(max(0.0, deadline - time.monotonic()))
        with self.lock:
            for job in self._pending:
                job.abandoned = True
                self.stats["scans_late"] += 1
            self._pending = []
            self._advance()
            self._finished = True
            if not self.stats["messages"]["attitude"]:
                return None
            return self.runner.finish()

