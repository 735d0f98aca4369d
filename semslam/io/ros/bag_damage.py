"""Reading a damaged bag (:meth:`semslam.io.ros.Bag.messages` with ``on_damage="count"``): records that cannot be
read or decoded are counted per topic in the bag's damage record (:func:`new_damage`) and skipped, the ROS 1 records
and the MCAP chunks each guarded; the messages the bag's index declares but that were never read are counted at the
end."""

from __future__ import annotations

import heapq
import os
from typing import Any, Iterator

from ...errors import BagError
from ._types import _one_line
from .bag_records import BagMessage

__all__ = ["new_damage", "raw_records", "stream_counting"]


#: with ``on_damage="count"``, this many undecodable messages of a topic before any decoded one is a wrong
#: definition (a BagError), not damage
_ALL_BAD_AFTER = 20


def new_damage() -> dict:
    """An empty damage record (see :meth:`Bag.messages`): per topic ``declared`` (the index's counts),
    ``undecodable``, ``unread`` (declared but never read), ``invalid``, ``stamp_ahead`` / ``stamp_before_start``
    (filled by
    :func:`semslam.dataset.rosbag.stream_bag`), and ``chunks_skipped``."""
    return {"declared": {}, "undecodable": {}, "invalid": {}, "unread": {}, "stamp_ahead": {}, "stamp_before_start": {},
            "chunks_skipped": 0}


def _bump(d: dict, key: str, n: int = 1) -> None:
    d[key] = d.get(key, 0) + n


def _mcap_raw(storage: Any, conns: list[Any], dmg: dict) -> Iterator[tuple[Any, int, bytes]]:
    """rosbags' indexed MCAP read (one chunk at a time, merged in time order), each chunk guarded: one that cannot
    be read or decompressed is counted and skipped, the others are read."""
    from rosbags.rosbag2.storage_mcap import msgsrc

    by_key = {(c.topic, c.msgtype): c for c in conns}
    channel_map = {sc.id: by_key[(sc.topic, sc.msgtype)] for sc in storage.connections
                   if (sc.topic, sc.msgtype) in by_key}

    def guarded(chunk):
        try:
            yield from msgsrc(chunk, channel_map, chunk.message_start_time, chunk.message_end_time + 1, storage.bio)
        except Exception:
            dmg["chunks_skipped"] += 1

    sources = [guarded(x) for x in storage.chunks if any(x.channel_count.get(cid, 0) for cid in channel_map)]
    for timestamp, offset, connection, data in heapq.merge(*sources, key=lambda m: m[0]):
        if offset and connection is not None and data is not None:
            yield connection, timestamp, data


def _ros1_raw(reader: Any, conns: list[Any], dmg: dict) -> Iterator[tuple[Any, int, bytes]]:
    """rosbags' ROS 1 read (index entries merged in time order, one decompressed chunk at a time), each record
    guarded: a chunk that cannot be decompressed or a record that is not the message its index names is counted
    and skipped."""
    from rosbags.rosbag1.reader import Header, RecordType, read_bytes, read_uint32

    bio = reader.bio
    current: tuple[int | None, Any] = (None, None)
    bad_chunks: set[int] = set()
    by_id = {c.id: c for c in conns}
    tagged = [[(e.time, e.chunk_pos, e.offset, c.id) for e in reader.indexes.get(c.id, ())] for c in conns]
    for time, chunk_pos, offset, cid in heapq.merge(*tagged):
        conn = by_id[cid]
        try:
            if chunk_pos in bad_chunks:
                raise ValueError("chunk skipped")
            if current[0] != chunk_pos:
                try:
                    head = reader.chunks[chunk_pos]
                    bio.seek(head.datapos)
                    current = (chunk_pos, _BytesIO(head.decompressor(read_bytes(bio, head.datasize))))
                except Exception:
                    bad_chunks.add(chunk_pos)
                    dmg["chunks_skipped"] += 1
                    raise
            chunk = current[1]
            chunk.seek(offset)
            while True:
                header = Header.read(chunk)
                op = header.get_uint8("op")
                if op != RecordType.CONNECTION:
                    break
                chunk.seek(read_uint32(chunk), os.SEEK_CUR)
            if op != RecordType.MSGDATA or header.get_uint32("conn") != cid or header.get_time("time") != time:
                raise ValueError("not the message the index names")
            data = read_bytes(chunk, read_uint32(chunk))
        except Exception:
            _bump(dmg["undecodable"], conn.topic)
            continue
        yield conn, time, data


def _BytesIO(data: bytes) -> Any:
    from io import BytesIO

    return BytesIO(data)


def stream_counting(bag, reader: Any, conns: list[Any], store: Any) -> Iterator[BagMessage]:
    """``bag``'s messages of ``conns`` with ``on_damage="count"`` (see :meth:`Bag.messages`): damage counted in
    ``bag.damage`` and skipped; a :class:`BagError` when every one of a topic's first records fails to decode."""
    deserialize = store.deserialize_ros1 if bag.is_ros1 else store.deserialize_cdr
    dmg = bag.damage
    declared: dict[str, int] = {}
    for c in conns:
        declared[c.topic] = declared.get(c.topic, 0) + max(int(c.msgcount or 0), 0)
    read: dict[str, int] = dict.fromkeys(declared, 0)
    ok: dict[str, int] = dict.fromkeys(declared, 0)
    for topic, n in declared.items():
        dmg["declared"][topic] = dmg["declared"].get(topic, 0) + n
    before = dict(dmg["undecodable"])  # records the raw reader skipped are counted there, not read
    failed: dict[str, int] = {}
    raw_messages = raw_records(reader, conns, dmg, bag.is_ros1)
    try:
        while True:
            try:
                conn, stamp_ns, raw = next(raw_messages)
            except StopIteration:
                break
            except Exception as err:  # a reader that cannot go on: the rest is unread, counted below
                dmg["stream_ended"] = f"{type(err).__name__}: {_one_line(err)}"
                break
            read[conn.topic] = read.get(conn.topic, 0) + 1
            try:
                msg = deserialize(raw, conn.msgtype)
                stamp = int(stamp_ns)
            except Exception as err:
                _bump(dmg["undecodable"], conn.topic)
                _bump(failed, conn.topic)
                if not ok.get(conn.topic) and dmg["undecodable"][conn.topic] >= _ALL_BAD_AFTER:
                    raise BagError(f"Bag '{bag.path}': the first {_ALL_BAD_AFTER} messages of topic "
                                   f"'{conn.topic}' cannot be decoded as {conn.msgtype} ({type(err).__name__}: "
                                   f"{_one_line(err)}): a wrong message definition, not damage.") from None
                continue
            ok[conn.topic] = ok.get(conn.topic, 0) + 1
            yield BagMessage(conn.topic, conn.msgtype, stamp, msg)
    finally:
        for topic, n in declared.items():  # declared by the index, never read: a zeroed block, a cut stream
            seen = read.get(topic, 0) + dmg["undecodable"].get(topic, 0) - before.get(topic, 0) \
                - failed.get(topic, 0)
            if n > seen:
                _bump(dmg["unread"], topic, n - seen)


def raw_records(reader: Any, conns: list[Any], dmg: dict, is_ros1: bool) -> Iterator[tuple[Any, int, bytes]]:
    """``(connection, receive stamp ns, raw bytes)`` of ``conns``: a damaged chunk of an indexed MCAP file or a
    damaged record of a ROS 1 bag is counted in ``dmg`` and skipped; other storages as rosbags reads them."""
    if is_ros1 and hasattr(reader, "indexes") and hasattr(reader, "chunks"):
        return _ros1_raw(reader, conns, dmg)
    st = getattr(reader, "storage", None)
    if hasattr(st, "storages"):  # a bag directory (files compressed as a whole or per message: not guarded)
        storages, mode = st.storages, getattr(st.metadata, "compression_mode", None)
    else:  # a bare .mcap / .db3 file
        storages, mode = [st], None
    mcap = None
    if storages is not None and len(storages) == 1 and mode in ("", "none", None):
        st = storages[0]
        if type(st).__name__ == "McapReader" and getattr(st, "chunks", None):
            mcap = st
    if mcap is None:
        return reader.messages(connections=conns)
    return _mcap_raw(mcap, conns, dmg)
