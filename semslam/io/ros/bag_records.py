"""What a bag gives: its topics (:class:`TopicRecord`) and its messages (:class:`BagMessage`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

__all__ = ["BagMessage", "TopicRecord"]


@dataclass(frozen=True)
class TopicRecord:
    """One topic of a bag. Stamps are bag receive times in integer nanoseconds (None without messages)."""

    topic: str
    msgtype: str
    count: int
    first_stamp_ns: int | None = None
    last_stamp_ns: int | None = None

    @property
    def rate_hz(self) -> float | None:
        """Mean message rate, ``(count - 1) / (last - first)``; None with fewer than two distinct stamps."""
        if self.count < 2 or self.first_stamp_ns is None or self.last_stamp_ns in (None, self.first_stamp_ns):
            return None
        return (self.count - 1) / ((self.last_stamp_ns - self.first_stamp_ns) * 1e-9)


class BagMessage(NamedTuple):
    """A deserialized message: topic, rosbags type name, bag receive time (ns) and the message object."""

    topic: str
    msgtype: str
    stamp_ns: int
    msg: Any
