"""The one streaming runner: a dive's messages in, one SLAM session per mode (all modes in one pass, EKF or graph
backend), every scan through the recogniser on the way, and the run's results out.

Time. Messages come in stamp order (a source's promise; one that comes later than what was already processed is
counted and dropped, never applied at the wrong time). The start waits for the first attitude sample and
``start_window_s`` of data after it (:mod:`semslam.slam.initial`: depth, fixes, velocity from the dive's own
data). A scan's detections are stamped by their points, up to a scan's span before the scan message: navigation
messages wait in a delay line of ``hold_s`` (at least twice the longest scan seen, three times when tracking waits
for the scan after: :class:`~semslam.run.scan_flow.ScanFlow`) so that the detections enter the filter in stamp order
with them. The estimate therefore lags the newest message by ``hold_s``; the live node
publishes the filter's prediction to the newest attitude.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from threadpoolctl import threadpool_limits

from ..detection import Detection
from ..errors import InputError
from ..pipeline.deskew import NavigationHistory
from ..slam import MODES, SlamConfig, SlamResult
from ..slam.initial import InitialState, initial_state
from .sessions import BACKENDS, make_session, with_start
from .messages import ORDER, Scan
from .scan_flow import ScanFlow

#: the shortest delay line (s); it grows to twice the longest scan span seen
MIN_HOLD_S = 2.0
#: attitude samples kept for the scans' up direction (s)
ATTITUDE_MEMORY_S = 5.0
#: scans recognised at once in background threads by `semslam run`, `detect` and the demo (a 2-core vehicle
#: computer: a 100k-point dive 1.4x faster than one scan at a time, measured on bag_stream.py's bag)
LOOKAHEAD = 2


@dataclass
class RunOutcome:
    """What a run produced: per mode its :class:`SlamResult`, the detections kept for SLAM per scan, per-scan
    statistics, the start, and the runner's counts (messages per kind, late or unusable ones)."""

    results: dict[str, SlamResult]
    detections_by_scan: dict[int, list[Detection]]
    scans: list[dict]
    start: InitialState | None
    counts: dict = field(default_factory=dict)

    def detection_summary(self) -> dict:
        from ..pipeline.dataset_detection import detection_summary

        return detection_summary(self.scans, sum(len(v) for v in self.detections_by_scan.values()))


class Runner:
    """Feed it a dive's messages (:meth:`feed`), then :meth:`finish`.

    Parameters
    ----------
    vehicle : VehicleDescription
    modes : sequence of {"dr", "position", "pose", "pose+heading"}
    recognizer : ScanRecognizer, optional
        Recognises every scan (None: scans are skipped, counted; give ``detections_by_scan`` instead).
    detections_by_scan : dict, optional
        Detections already made (``{scan_id: [Detection]}``: a detections file, the simulator's truth-based
        ones), fed at their stamps.
    config : SlamConfig, optional
    symmetries : dict, optional
    backend : {"ekf", "isam2", "batch"}
    survey : Survey, optional
        Landmarks known before the run (a survey file, an earlier map).
    seed : int
        Scan ``k`` is recognised with seed ``seed * 100003 + k``.
    keep_unreliable, up_from_attitude : bool
        As :func:`semslam.pipeline.dataset_detection.detect_dataset`.
    on_scan : callable, optional
        ``on_scan(scan_message, kept_detections, stats, result)`` after each recognised scan.
    lookahead : int
        Scans recognised at once in background threads while the following messages are read and the filters run
        (0: each scan in the caller's thread as it comes). The filters take a scan's detections before any message
        after the scan's start, so the result is the same for every ``lookahead`` (bit for bit); only the wall
        time changes (the compiled kernels release the GIL).
    """

    def __init__(self, vehicle, *, modes=("pose",), recognizer=None, detections_by_scan=None,
                 config: SlamConfig | None = None, symmetries=None, backend: str = "ekf", huber_k=None, survey=None,
                 seed: int = 0, keep_unreliable: bool = False, up_from_attitude: bool = False,
                 on_scan: Callable | None = None, lookahead: int = 0) -> None:
        modes = tuple(modes)
        if not modes or any(m not in MODES for m in modes):
            raise InputError(f"The 'modes' of a run must be some of {MODES}. Got {modes!r} instead.")
        if backend not in BACKENDS:
            raise InputError(f"The 'backend' of a run must be one of {BACKENDS}. Got {backend!r} instead.")
        self.vehicle, self.modes, self.recognizer = vehicle, modes, recognizer
        self.given = None if detections_by_scan is None else dict(detections_by_scan)
        self.cfg = SlamConfig() if config is None else config
        self.symmetries, self.backend, self.huber_k, self.survey = symmetries, backend, huber_k, survey
        self.seed, self.keep_unreliable, self.up_from_attitude = seed, keep_unreliable, up_from_attitude
        if not isinstance(lookahead, int) or isinstance(lookahead, bool) or not 0 <= lookahead <= 64:
            raise InputError(f"The 'lookahead' of a run must be an integer from 0 to 64 (scans recognised at once). "
                             f"Got {lookahead!r} instead.")
        self.on_scan, self.lookahead = on_scan, lookahead
        self.sessions: dict = {}
        self.start: InitialState | None = None
        self.detections_by_scan: dict[int, list[Detection]] = {}
        self.scans: list[dict] = []
        self.counts: dict = {"late_dropped": {}, "scans_not_recognised": 0}
        self._boot: list = []       # messages before the start is known
        self._t_first_att: float | None = None
        self._heap: list = []
        self._seq = 0
        self._newest = -math.inf
        self._released = -math.inf
        self._hold = MIN_HOLD_S
        self._nav = NavigationHistory(ATTITUDE_MEMORY_S)  # recent attitude and DVL: the scans' up and deskewing
        self._flow = None if recognizer is None else ScanFlow(
            recognizer, vehicle, self._nav, self._recognised, self.counts, seed=seed, keep_unreliable=keep_unreliable,
            up_from_attitude=up_from_attitude, lookahead=lookahead, before_pool=self._limit_blas)
        self._finished = False
        self._blas = None
        if self.given is not None and recognizer is None:  # known in advance: fed at their stamps, scans unused
            for sid, dets in self.given.items():
                self._detections(sid, dets)

    # ------------------------------------------------------------------ input
    def feed(self, msg) -> None:
        """One message of :mod:`semslam.run.messages` (in stamp order)."""
        if self._finished:
            raise InputError("The run is finished: no more messages.")
        t = float(msg.stamp_s)
        if not math.isfinite(t):
            self._count_late(msg.kind, "non_finite_stamp")
            return
        if t < self._released:
            self._count_late(msg.kind)
            return
        self._newest = max(self._newest, t)
        if msg.kind == "attitude":
            self._nav.add_attitude(t, msg.rpy_rad)
        elif msg.kind == "dvl":
            self._nav.add_dvl(t, msg.velocity_mps, msg.valid)
        if msg.kind == "scan":
            self._scan(msg)
            return
        if self._flow is not None:
            self._flow.navigation_came(t)
        self._push(t, msg.kind, msg)
        if self.start is None:
            self._try_start(final=False)
        if self.start is not None:
            self._release(final=False)

    def _count_late(self, kind: str, key: str = "late_dropped") -> None:
        d = self.counts.setdefault(key, {})
        d[kind] = d.get(kind, 0) + 1

    def _push(self, t: float, kind: str, payload) -> None:
        heapq.heappush(self._heap, (t, ORDER[kind], self._seq, kind, payload))
        self._seq += 1
        if kind == "attitude" and self._t_first_att is None:
            self._t_first_att = t

    # ------------------------------------------------------------------ scans
    def _scan(self, msg: Scan) -> None:
        self._hold = max(self._hold, 2.0 * (msg.end_stamp_s - msg.start_stamp_s))
        if self._flow is None:
            if self.given is None:
                self.counts["scans_not_recognised"] += 1
            return
        # (a scan deskewed, or waiting for the scan after it, is final later: the filters stay behind it)
        self._hold = max(self._hold, self._flow.hold_s(msg))
        self._flow.add(msg, self._newest)

    def _recognised(self, msg: Scan, dets, stats, result) -> None:
        """A scan's final detections (:class:`ScanFlow`, in stream order)."""
        self.scans.append(stats)
        if self.on_scan is not None:
            self.on_scan(msg, dets, stats, result)
        self._detections(msg.scan_id, dets)

    def add_scan_detections(self, scan_id: int, detections: list[Detection], stats: dict | None = None) -> None:
        """Detections of a scan recognised elsewhere (the live node's worker thread): fed at their stamps; those
        older than what the filter already processed are counted (``late_dropped["detections"]``) and dropped."""
        if stats is not None:
            self.scans.append(stats)
        self._detections(scan_id, list(detections))
        if self.start is not None:
            self._release(final=False)

    def replace_scan_detections(self, scan_id: int, detections: list[Detection], stats: dict | None = None) -> None:
        """A scan's detections made final after they were fed (the live node makes the scan before final from the
        one after it): those no longer among ``detections`` withdrawn from the delay line (the node holds the
        filter behind the scan until then), the new ones fed as :meth:`add_scan_detections` does, the scan's record
        (and its ``stats``, when given) replaced."""
        final = list(detections)
        old = self.detections_by_scan.get(scan_id, [])
        gone = {id(d) for d in old} - {id(d) for d in final}
        if gone:
            for entry in self._heap:
                if entry[3] == "detections":
                    entry[4][:] = [d for d in entry[4] if id(d) not in gone]
            self._heap = [e for e in self._heap if e[3] != "detections" or e[4]]
            heapq.heapify(self._heap)
        if stats is not None:
            self.scans = [stats if st.get("scan_id") == scan_id else st for st in self.scans]
        known = {id(d) for d in old}
        self._detections(scan_id, [d for d in final if id(d) not in known])
        if final:
            self.detections_by_scan[scan_id] = final
        else:
            self.detections_by_scan.pop(scan_id, None)
        if self.start is not None:
            self._release(final=False)

    def estimate(self, mode: str):
        """The current :class:`~semslam.slam.SlamEstimate` of ``mode`` (None before the start): the filter at the
        last released message, ``hold_s`` behind the newest one."""
        s = self.sessions.get(mode)
        return None if s is None or s.ekf is None else s.estimate()

    @property
    def hold_s(self) -> float:
        return self._hold

    def _detections(self, scan_id: int, dets: list[Detection]) -> None:
        if not dets:
            return
        self.detections_by_scan[scan_id] = list(dets)
        groups: dict = {}
        for d in dets:
            st = float(d.stamp_s)
            if not math.isfinite(st):
                raise InputError(f"Every detection needs a finite 'stamp_s'. Got {d.stamp_s!r} in scan {scan_id}.")
            groups.setdefault(st, []).append(d)
        for st, group in groups.items():
            if st < self._released:
                self._count_late("detections")
                continue
            self._push(st, "detections", group)

    # ------------------------------------------------------------------ start and release
    def _try_start(self, final: bool) -> None:
        t0 = self._t_first_att
        if t0 is None:
            return
        window = self.cfg.initialisation.start_window_s
        if not final and self._newest < t0 + window:
            return
        items = sorted(self._heap)
        dep = [(t, p.depth_m) for t, _, _, k, p in items if k == "depth"]
        fix = [(t, p) for t, _, _, k, p in items if k == "fix"]
        fix = [(t, p) for t, p in fix if np.isfinite(p.position_ne_m).all() and _usable_cov(p.covariance_ne_m2)]
        dvl = [(t, p) for t, _, _, k, p in items if k == "dvl"]
        self.start = initial_state(
            t0,
            depth_stamps_s=[t for t, _ in dep],
            depth_m=[z for _, z in dep],
            depth_noise_m=self.vehicle.depth.noise_m,
            fix_stamps_s=[t for t, _ in fix],
            fix_positions_ne_m=[p.position_ne_m for _, p in fix],
            fix_covariances_ne_m2=[p.covariance_ne_m2 for _, p in fix],
            dvl_stamps_s=[t for t, _ in dvl],
            dvl_velocities_mps=[p.velocity_mps for _, p in dvl],
            dvl_valid=[p.valid for _, p in dvl],
            config=self.cfg,
        )
        for mode in self.modes:
            s = make_session(self.vehicle, self.start, mode=mode, config=self.cfg, symmetries=self.symmetries,
                             backend=self.backend, huber_k=self.huber_k)
            if self.survey is not None:
                self.survey.add_to(s)
            self.sessions[mode] = s

    def _release(self, final: bool) -> None:
        limit = math.inf if final else self._newest - self._hold
        if not self._heap or self._heap[0][0] > limit:
            return
        if self._flow is not None:  # the filters take a scan's detections before passing its start
            self._flow.before(limit)
        self._limit_blas()
        while self._heap and self._heap[0][0] <= limit:
            t, _, _, kind, p = heapq.heappop(self._heap)
            self._released = t
            for mode, s in self.sessions.items():
                _feed(s, mode, kind, t, p)

    def _limit_blas(self) -> None:
        if self._blas is None:  # the filter's matrices are small: BLAS threads only spin on them (6x slower, measured)
            self._blas = threadpool_limits(limits=1, user_api="blas")

    def close(self) -> None:
        """Stop the recognition threads (waiting for the scans in recognition), then give BLAS its thread count
        back. :meth:`finish` does it; call it when a run is abandoned (an exception, Ctrl-C) so that no worker is
        left inside BLAS while the caller's own limits are restored."""
        if self._flow is not None:
            self._flow.close()
        if self._blas is not None:
            self._blas.restore_original_limits()
            self._blas = None

    # ------------------------------------------------------------------ output
    def finish(self) -> RunOutcome:
        """Process what is pending and return the :class:`RunOutcome` (no evaluation: that is
        :func:`semslam.evaluation.slam_run.evaluate_results`, after the run, by whoever holds a reference)."""
        if self._finished:
            raise InputError("Runner.finish was already called.")
        self._finished = True
        try:
            if self._flow is not None:
                self._flow.finish()
        except BaseException:
            self.close()
            raise
        if self._flow is not None:
            self._flow.close()
        if self.start is None:
            self._try_start(final=True)
        if self.start is None:
            self.close()
            raise InputError("The dive has no attitude sample: the filter needs the attitude as input.")
        try:
            self._release(final=True)
            results = {}
            with threadpool_limits(limits=1, user_api="blas"):
                for mode, s in self.sessions.items():
                    results[mode] = with_start(s.finish(), self.start)
        finally:
            self.close()
        return RunOutcome(results, self.detections_by_scan, self.scans, self.start, self.counts)


def _usable_cov(C) -> bool:
    C = np.asarray(C, dtype=float)
    return bool(C.shape == (2, 2) and np.isfinite(C).all() and C[0, 0] > 0 and np.linalg.det(C) > 0
                and abs(C[0, 1] - C[1, 0]) <= 1e-9 * abs(C).max())


def _feed(session, mode: str, kind: str, t: float, p) -> None:
    if kind == "attitude":
        session.add_attitude(t, p.rpy_rad)
    elif kind == "dvl":
        session.add_dvl(t, p.velocity_mps, valid=p.valid, beam_range_m=p.beam_range_m)
    elif kind == "depth":
        session.add_depth(t, p.depth_m)
    elif kind == "fix":
        session.add_position_fix(t, p.position_ne_m, p.covariance_ne_m2)
    elif mode != "dr":
        session.add_detections(t, p)


def run_stream(dive, **runner_kw) -> RunOutcome:
    """Every message of an opened dive (:func:`semslam.run.open_dive`) through a :class:`Runner`. Not evaluated:
    :func:`semslam.evaluation.slam_run.evaluate_results` does that after the run, against a reference it loads."""
    runner = Runner(dive.vehicle, **runner_kw)
    try:
        for msg in dive.messages():
            runner.feed(msg)
    except BaseException:  # an error or Ctrl-C: no recognition thread outlives the run
        runner.close()
        raise
    out = runner.finish()
    out.counts["source"] = dict(dive.counts)
    if dive.geodetic_origin is not None:
        for r in out.results.values():
            r.metrics["geodetic_origin"] = dive.geodetic_origin.as_dict()
    return out
