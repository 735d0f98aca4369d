"""The live node's scans waiting for the navigation after their end before they are deskewed and recognised
(:mod:`semslam.pipeline.deskew`; the offline runner waits the same way, so both deskew a scan alike)."""

from __future__ import annotations

import math
import time
from typing import Any

from ...pipeline.deskew import SMOOTHING_WINDOW_S, NavigationHistory

#: wall-clock seconds without any navigation message after which the scans still waiting for theirs are deskewed with
#: what came (:meth:`LiveSlam.poll`): the navigation stopped, or a recording ended. While navigation keeps coming,
#: however slowly (a loaded machine), a scan waits for its own, so a replay gives the offline detections
NAVIGATION_WAIT_S = 1.0


class DeskewQueue:
    """Attitude and DVL as they come, and the scan jobs waiting for them (each gets ``job.motion``)."""

    def __init__(self, R_vehicle_dvl: Any, lookahead_s: float = SMOOTHING_WINDOW_S) -> None:
        self.R_vehicle_dvl = R_vehicle_dvl
        self.lookahead_s = float(lookahead_s)  # PipelineConfig.deskew_lookahead_s
        self.nav = NavigationHistory()
        self.newest_s = -math.inf
        self.waiting: list = []
        self.not_deskewed = 0
        self.last_wall_s = -math.inf  # when the last navigation message came (time.monotonic())

    def add_navigation(self, msg: Any) -> None:
        if msg.kind == "attitude":
            self.nav.add_attitude(msg.stamp_s, msg.rpy_rad)
        else:
            self.nav.add_dvl(msg.stamp_s, msg.velocity_mps, msg.valid)
        self.newest_s = max(self.newest_s, msg.stamp_s)
        self.last_wall_s = time.monotonic()

    def ready(self, final: bool) -> list:
        """The jobs whose navigation has come (up to ``lookahead_s`` after their end), all of them when no
        navigation came for ``NAVIGATION_WAIT_S`` of wall clock, or all (``final``), with their motion (None: counted
        in ``not_deskewed``), abandoned ones dropped."""
        now = time.monotonic()
        stopped = now - self.last_wall_s > NAVIGATION_WAIT_S
        out = [j for j in self.waiting if final or j.end_s + self.lookahead_s <= self.newest_s
               or (stopped and now - j.received_wall_s > NAVIGATION_WAIT_S)]
        for job in out:
            self.waiting.remove(job)
            job.motion = self.nav.scan_motion(self.R_vehicle_dvl, job.scan.point_stamps_s, job.end_s,
                                              lookahead_s=self.lookahead_s)
            self.not_deskewed += job.motion is None
        return [j for j in out if not j.abandoned]
