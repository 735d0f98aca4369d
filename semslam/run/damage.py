"""Damaged recordings are reported, not hidden: what a bag lost on the way to the filter, per topic, and the health
verdict's checks about it.

A bag read by :func:`semslam.run.open_dive` counts (``Dive.counts["damage"]``, from
:meth:`semslam.io.ros.Bag.messages` and :func:`semslam.dataset.rosbag.stream_bag` with ``on_damage="count"``):

- ``undecodable``: records that could not be read or deserialized (a chunk that does not decompress, a record that
  is not the message its index names, a payload that does not parse);
- ``invalid``: messages that decode but hold a value outside its plausible range (:mod:`semslam.limits`) or a
  payload that does not parse (a PointCloud2 whose layout lies); ``first_error`` keeps the first one's message;
- ``unread``: messages the bag's index declares but that were never read (a zeroed block inside an MCAP chunk, a
  chunk skipped, a stream that ended early);
- ``stamp_ahead`` / ``stamp_before_start``: messages whose header stamp lies outside the dive (after their receive
  time, before the bag's start: see :data:`~semslam.dataset.rosbag.STAMP_AHEAD_LIMIT_S`);
- ``chunks_skipped``, and ``stream_ended`` (why a reader that cannot go on stopped).

``Dive.counts["damaged"]`` sums them per topic. Messages later than the reorder window are counted apart
(``counts["late_dropped"]`` per kind). In the verdict, a topic that lost any message is a ``warning``; one that lost
more than :data:`BAD_FRACTION` of its messages is ``bad`` (``semslam run --strict`` then exits 3), and so is a kind
of message of which more than that fraction arrived too late.
"""

from __future__ import annotations

__all__ = ["BAD_FRACTION", "damaged_per_topic", "add_damage_checks"]

#: a topic that lost more than this fraction of its messages (damaged, unread, stamped outside the dive) makes the
#: verdict bad; fewer is a warning
BAD_FRACTION = 0.01

_REASONS = (("undecodable", "undecodable"), ("invalid", "invalid (a value out of its plausible range or a payload that "
                                                       "does not parse)"),
            ("unread", "declared by the bag's index but never read"),
            ("stamp_ahead", "stamped after their receive time"),
            ("stamp_before_start", "stamped before the bag's start"))


def damaged_per_topic(damage: dict | None) -> dict[str, int]:
    """Messages lost per topic (undecodable + unread + stamped outside the dive), only topics that lost some."""
    out: dict[str, int] = {}
    for key, _ in _REASONS:
        for topic, n in ((damage or {}).get(key) or {}).items():
            if n:
                out[topic] = out.get(topic, 0) + int(n)
    return dict(sorted(out.items()))


def add_damage_checks(verdict, counts: dict | None) -> None:
    """Add the ``damaged recording`` checks (one per topic that lost messages) and the ``stream order`` checks (late
    messages of the source beyond :data:`BAD_FRACTION`) to ``verdict`` (a :class:`~semslam.run.health.Verdict`)
    from a run's counts (the runner's, holding the source's under ``"source"``, or a dive's own, which hold
    ``"damage"``)."""
    counts = counts or {}
    # the source's counts (a bag's): a live node's late drops (no "source", no "damage") are the runner's business
    src = counts["source"] if isinstance(counts.get("source"), dict) else counts if "damage" in counts else {}
    damage = src.get("damage") or {}
    declared = damage.get("declared") or {}
    for topic, lost in damaged_per_topic(damage).items():
        total = max(int(declared.get(topic, 0)), lost)
        frac = lost / total
        why = "; ".join(f"{int(damage[k][topic])} {what}" for k, what in _REASONS
                        if (damage.get(k) or {}).get(topic))
        first = (damage.get("first_error") or {}).get(topic)
        if first:
            why += f" (first: {first})"
        level = "bad" if frac > BAD_FRACTION else "warning"
        verdict.add("damaged recording", level, f"topic {topic}: {lost} of {total} messages lost "
                    f"({100 * frac:.1f} %): {why}", topic=topic, lost=lost, declared=total, fraction=frac)
    extra = [f"{damage['chunks_skipped']} chunk(s) skipped"] if damage.get("chunks_skipped") else []
    if damage.get("stream_ended"):
        extra.append(f"the reader stopped early ({damage['stream_ended']})")
    if extra:
        verdict.add("damaged recording", "bad" if damage.get("stream_ended") else "warning", "; ".join(extra))
    late = src.get("late_dropped") or {}
    for kind, n in sorted(late.items()):
        total = int(n) + int(src.get(kind, 0) or 0)
        if n and total and n / total > BAD_FRACTION:
            verdict.add("stream order", "bad", f"{n} of {total} {kind} messages arrived later than the reorder "
                        f"window and were dropped ({100 * n / total:.1f} %): stamps out of order",
                        kind=kind, late=int(n), total=total)
