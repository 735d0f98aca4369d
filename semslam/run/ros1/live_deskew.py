"""The live node's scans waiting for the navigation after their end before they are deskewed and recognised
(:mod:`semslam.pipeline.deskew`; the offline runner waits the same way, so both deskew a scan alike)."""

from __future__ import annotations

import math
import time
from typing import Any

from ...pipeline.deskew import SMOOTHING_WINDOW_S, NavigationHistory

#: wall-clock seconds a scan waits for the navigation after its end (``SMOOTHING_WINDOW_S`` of stamps) before it is
#: deskewed with what came (:meth:`LiveSlam.poll`): the navigation stopped, or a recording ended
NAVIGATION_WAIT_S = 1.0


class DeskewQueue:
    """Attitude and DVL as they come, and the scan jobs waiting for them (each gets ``job.motion``)."""

    def __init__(self, R_vehicle_dvl: Any) -> None:
        self.R_vehicle_dvl = R_vehicle_dvl
        self.nav = NavigationHistory()
        self.newest_s = -math.inf
        self.waiting: list = []
        self.not_deskewed = 0

    def add_navigation(self, msg: Any) -> None:
        if msg.kind == "attitude":
            self.nav.add_attitude(msg.stamp_s, msg.rpy_rad)
        else:
            self.nav.add_dvl(msg.stamp_s, msg.velocity_mps, msg.valid)
        self.newest_s = max(self.newest_s, msg.stamp_s)

    def ready(self, final: bool) -> list:
        """The jobs whose navigation has come (up to ``SMOOTHING_WINDOW_S`` after their end), that waited
        ``NAVIGATION_WAIT_S`` of wall clock, or all (``final``), with their motion (None: counted in
        ``not_deskewed``), abandoned ones dropped."""
        now = time.monotonic()
        out = [j for j in self.waiting if final or j.end_s + SMOOTHING_WINDOW_S <= self.newest_s
               or now - j.received_wall_s > NAVIGATION_WAIT_S]
        for job in out:
            self.waiting.remove(job)
            job.motion = self.nav.scan_motion(self.R_vehicle_dvl, job.scan.point_stamps_s, job.end_s)
            self.not_deskewed += job.motion is None
        return [j for j in out if not j.abandoned]
