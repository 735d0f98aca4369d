"""The live node's scans waiting for the navigation after their end before they are deskewed and recognised
(:mod:`semslam.pipeline.deskew`; the offline runner waits the same way, so both deskew a scan alike)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

from ...pipeline.deskew import SMOOTHING_WINDOW_S, NavigationHistory
from ..messages import Scan

#: wall-clock seconds without a message of one navigation kind (attitude, DVL) after which the scans still waiting
#: for it are deskewed without waiting for that kind any longer (:meth:`LiveSlam.poll`): it stopped, or a recording
#: ended. While each kind keeps coming, however slowly (a loaded machine), a scan waits for its own, so a replay
#: gives the offline detections
NAVIGATION_WAIT_S = 1.0

_NAV_KINDS = ("attitude", "dvl")


@dataclass
class ScanJob:
    """A scan waiting for, or in, recognition."""

    scan: Scan
    received_wall_s: float
    up_scanner: Any = None
    abandoned: bool = False
    motion: Any = None
    navigation: Any = None  # the navigation held when it was ready (tracking from the scan before)
    meta: dict = field(default_factory=dict)

    @property
    def scan_id(self) -> int:
        return self.scan.scan_id

    @property
    def start_s(self) -> float:
        return self.scan.start_stamp_s

    @property
    def end_s(self) -> float:
        return self.scan.end_stamp_s


class DeskewQueue:
    """Attitude and DVL as they come, and the scan jobs waiting for them (each gets ``job.motion``)."""

    def __init__(self, R_vehicle_dvl: Any, lookahead_s: float = SMOOTHING_WINDOW_S) -> None:
        self.R_vehicle_dvl = R_vehicle_dvl
        self.lookahead_s = float(lookahead_s)  # PipelineConfig.deskew_lookahead_s
        self.nav = NavigationHistory()
        # per kind: each topic comes on its own connection, so one may run ahead of the other (measured: a loaded
        # CI machine deskewed a scan before the DVL samples of its window had come, the attitude being past it)
        self.newest_s = {k: -math.inf for k in _NAV_KINDS}
        self.last_wall_s = {k: -math.inf for k in _NAV_KINDS}  # when its last message came (time.monotonic())
        self.waiting: list = []
        self.not_deskewed = 0

    def add_navigation(self, msg: Any) -> None:
        if msg.kind == "attitude":
            self.nav.add_attitude(msg.stamp_s, msg.rpy_rad)
        else:
            self.nav.add_dvl(msg.stamp_s, msg.velocity_mps, msg.valid)
        kind = "attitude" if msg.kind == "attitude" else "dvl"
        self.newest_s[kind] = max(self.newest_s[kind], msg.stamp_s)
        self.last_wall_s[kind] = time.monotonic()

    def _has_come(self, job: Any, now: float) -> bool:
        """Has every navigation kind come up to ``lookahead_s`` after the job's end, or stopped? A kind has stopped
        when none of it came for ``NAVIGATION_WAIT_S`` of wall clock (a DVL silent through an outage is not waited
        for); one that never came is waited for that long after the job's arrival (the node has just started)."""
        due = job.end_s + self.lookahead_s
        for k in _NAV_KINDS:
            if self.newest_s[k] >= due:
                continue
            since = job.received_wall_s if self.last_wall_s[k] == -math.inf else self.last_wall_s[k]
            if now - since <= NAVIGATION_WAIT_S:
                return False
        return True

    def ready(self, final: bool) -> list:
        """The jobs whose navigation has come (:meth:`_has_come`), or all (``final``), with their motion (None:
        counted in ``not_deskewed``), abandoned ones dropped."""
        now = time.monotonic()
        out = [j for j in self.waiting if final or self._has_come(j, now)]
        for job in out:
            self.waiting.remove(job)
            job.motion = self.nav.scan_motion(self.R_vehicle_dvl, job.scan.point_stamps_s, job.end_s,
                                              lookahead_s=self.lookahead_s)
            job.navigation = self.nav.copy()  # the worker's motion since the scan before (tracking) reads it
            self.not_deskewed += job.motion is None
        return [j for j in out if not j.abandoned]


def recognise_job(live: Any, job: Any) -> tuple:
    """The worker's step for ``job`` (:class:`~semslam.run.ros1.live.LiveSlam` ``live``): its scan recognised with
    the objects of the scan the worker recognised before as priors (``live._before``: its output, first point's
    stamp and job), and that scan made final from this one's objects when this one follows closely
    (:mod:`semslam.pipeline.tracking`; the motion between from the navigation held when the job was ready):
    ``(detect_scan output, None or a function giving the scan before's final output)``: the worker calls it after
    publishing this scan."""
    from ...pipeline.dataset_detection import detect_scan, priors_from_scan_before, track_from_scan_after
    from ...pipeline.tracking import follows_closely, tracks

    sc, before, T_vs = job.scan, live._before, live.vehicle.scanner.T_vehicle_scanner
    nav = getattr(job, "navigation", None)
    motion = None
    if before is not None and nav is not None and tracks(live.recognizer):
        motion = nav.motion(live.vehicle.dvl.T_vehicle_dvl.rotation, before[1], job.end_s,
                            lookahead_s=live._deskew.lookahead_s)
    priors = None if motion is None else priors_from_scan_before(before[0][2].detections, motion, T_vs, job.end_s)
    out = detect_scan(live.recognizer, sc.cloud, scan_id=sc.scan_id, start_stamp_s=sc.start_stamp_s,
                      end_stamp_s=sc.end_stamp_s, point_stamps_s=sc.point_stamps_s, seed=live.seed,
                      keep_unreliable=live.keep_unreliable, up_scanner=job.up_scanner, motion=job.motion,
                      T_vehicle_scanner=T_vs, priors=priors)
    bsc = None if motion is None else before[2].scan
    if bsc is None or not follows_closely(before[1], bsc.start_stamp_s, bsc.end_stamp_s, sc.end_stamp_s):
        return out, None
    return out, lambda: track_from_scan_after(live.recognizer, before[0], out[2].detections, motion, T_vs,
                                              live.keep_unreliable)


def tracked_back(live: Any, before: tuple, before_final: tuple | None) -> bool:
    """The scan before (``before``: its output, first stamp and job) made final (``before_final``, or None): its new
    detections counted (``live.stats["tracked_from_scan_after"]``), its kept detections in the runner made the final
    ones (a cluster tracked as another class replaces what it was alone) with ``live.lock`` held. Did it gain any?"""
    if before_final is None:
        return False
    old = {id(d) for d in before[0][2].detections}
    new = [d for d in before_final[2].detections if id(d) not in old]
    live.stats["tracked_from_scan_after"] += len(new)
    if new:
        live.runner.replace_scan_detections(before[2].scan.scan_id, before_final[0], before_final[1])
    return bool(new)
