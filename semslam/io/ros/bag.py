"""Read ROS bags without ROS: ROS 1 ``.bag``, ROS 2 bag directories (sqlite3 ``.db3`` or ``.mcap`` storage with
``metadata.yaml``) and bare ``.mcap``/``.db3`` files, through rosbags (imported lazily).

>>> with open_bag("dive.bag") as bag:                                   # doctest: +SKIP
...     bag.require_topic("/points", ["sensor_msgs/msg/PointCloud2"])
...     for topic, msgtype, stamp_ns, msg in bag.messages(["/points", "/imu"]):
...         ...

Messages are streamed in time order (bag receive time): rosbags reads one ROS 1 chunk, one MCAP chunk or
one sqlite row at a time. Types come from the definitions the bag embeds (every ROS 1 bag, ROS 2 bags
from Iron on), else from ``.msg`` files given with ``msg_dirs`` (``--msg-dir``), else from ROS 2 Humble
(ROS 1 Noetic for a ``.bag``). Every failure is a one-line :class:`~semslam.errors.BagError` naming the bag.
"""

from __future__ import annotations

import contextlib
import os
import stat
from pathlib import Path
from typing import Any, Iterable, Iterator, Sequence

from ...errors import BagError
from ._types import _one_line, build_typestore, load_msg_dirs, missing_types, normalize_msgtype
from .bag_damage import new_damage, raw_records, stream_counting
from .bag_records import BagMessage, TopicRecord

__all__ = ["Bag", "BagMessage", "TopicRecord", "new_damage", "open_bag"]

_ROS2_SUFFIXES = (".mcap", ".db3")


@contextlib.contextmanager
def _boundary(path: Path, doing: str) -> Iterator[None]:
    """Turn anything rosbags, sqlite, the decompressors or the OS raise on a bad file into a BagError."""
    try:
        yield
    except BagError:
        raise
    except Exception as err:  # ReaderError, SerdeError, TypesysError, OSError, struct.error, AssertionError...
        raise BagError(f"Bag '{path}': {doing} ({type(err).__name__}: {_one_line(err)}).") from None


def _check_path(path: Path) -> bool:
    """Reject what cannot be a bag before opening anything (a FIFO would block); True for ROS 1."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise BagError(f"Bag '{path}': no such file or directory.") from None
    except OSError as err:
        raise BagError(f"Bag '{path}': cannot be read ({err.strerror or err}).") from None
    mode = st.st_mode
    if stat.S_ISDIR(mode):
        if not (path / "metadata.yaml").exists():
            raise BagError(f"Bag '{path}': a directory must be a ROS 2 bag holding metadata.yaml. Got none instead.")
        with _boundary(path, "cannot be listed"):
            special = [e.name for e in path.iterdir() if not (e.is_file() or e.is_dir())]
        if special:  # a FIFO or a device would block the reader
            raise BagError(f"Bag '{path}': '{special[0]}' must be a regular file. Got a special file instead.")
        return False
    if not stat.S_ISREG(mode):
        raise BagError(f"Bag '{path}': must be a regular file or a ROS 2 bag directory. "
                       f"Got a special file (FIFO, device or socket) instead.")
    suffix = path.suffix.lower()
    if suffix != ".bag" and suffix not in _ROS2_SUFFIXES:
        raise BagError(f"Bag '{path}': must be a ROS 1 .bag, a .mcap or .db3 file, or a ROS 2 bag directory. "
                       f"Got suffix {suffix or '(none)'!r} instead.")
    if st.st_size == 0:
        raise BagError(f"Bag '{path}': the file is empty (0 bytes).")
    return suffix == ".bag"


class Bag:
    """An open ROS 1 or ROS 2 bag; see :func:`open_bag`. Use as a context manager (or call :meth:`close`)."""

    def __init__(self, path: str | os.PathLike, *, msg_dirs: Iterable[str | os.PathLike] = ()) -> None:
        self.path = Path(path)
        self.is_ros1 = _check_path(self.path)
        self._user_types = load_msg_dirs(msg_dirs)
        from rosbags.rosbag1 import Reader as Reader1
        from rosbags.rosbag2 import Reader as Reader2

        self._reader: Any = None
        with _boundary(self.path, f"cannot be opened as a ROS {1 if self.is_ros1 else 2} bag"):
            reader = Reader1(self.path) if self.is_ros1 else Reader2(self.path)
            reader.open()
            self._connections = list(reader.connections)
        self._reader = reader
        self._store: Any = None
        self._records: list[TopicRecord] | None = None
        #: records lost to damage, filled by ``messages(on_damage="count")`` (see :meth:`messages`)
        self.damage: dict = new_damage()

    # -- life cycle -------------------------------------------------------------------------------------
    def close(self) -> None:
        """Close the files; idempotent."""
        reader, self._reader = self._reader, None
        if reader is not None:
            with contextlib.suppress(Exception):
                reader.close()

    def __enter__(self) -> "Bag":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Bag('{self.path}', {'ROS 1' if self.is_ros1 else 'ROS 2'}, {len(self._connections)} connections)"

    @property
    def start_time_ns(self) -> int | None:
        """The bag's first receive time over all its topics (ns), None for an empty bag: a clock origin that does
        not depend on which topics a reader maps."""
        reader = self._open_reader()
        try:
            t = int(reader.start_time)
        except (AttributeError, TypeError, ValueError, OverflowError):
            return None
        return t if 0 <= t < 2 ** 63 - 1 else None

    def _open_reader(self) -> Any:
        if self._reader is None:
            raise BagError(f"Bag '{self.path}': is closed.")
        return self._reader

    # -- topics -----------------------------------------------------------------------------------------
    def _types_by_topic(self) -> dict[str, list[Any]]:
        by_topic: dict[str, list[Any]] = {}
        for conn in self._connections:
            by_topic.setdefault(conn.topic, []).append(conn)
        return dict(sorted(by_topic.items()))

    def _cheap_records(self) -> list[TopicRecord]:
        return [TopicRecord(topic, ", ".join(sorted({c.msgtype for c in conns})), sum(c.msgcount for c in conns))
                for topic, conns in self._types_by_topic().items()]

    def topics(self) -> list[TopicRecord]:
        """Every topic (sorted by name) with its type, message count, first/last receive stamp and rate.

        ROS 1 stamps come from the bag index; ROS 2 stamps from one streamed pass over the bag (no message is
        deserialized), done once and cached.
        """
        if self._records is None:
            reader = self._open_reader()
            first: dict[str, int] = {}
            last: dict[str, int] = {}
            count: dict[str, int] = {}
            indexes = getattr(reader, "indexes", None) if self.is_ros1 else None
            with _boundary(self.path, "cannot be scanned (corrupt or truncated?)"):
                if indexes is not None:
                    stamps = ((c.topic, e.time) for c in self._connections for e in indexes.get(c.id, ()))
                else:  # damaged chunks skipped here: messages(on_damage=...) decides whether they are fatal
                    stamps = ((c.topic, t) for c, t, _ in raw_records(reader, self._connections, new_damage(),
                                                                      self.is_ros1))
                for topic, t in stamps:
                    first[topic] = min(first.get(topic, t), t)
                    last[topic] = max(last.get(topic, t), t)
                    count[topic] = count.get(topic, 0) + 1
            self._records = [TopicRecord(r.topic, r.msgtype, count.get(r.topic, 0), first.get(r.topic),
                                         last.get(r.topic)) for r in self._cheap_records()]
        return list(self._records)

    def _topic_list(self) -> str:
        records = self._cheap_records()
        return ", ".join(f"'{r.topic}' ({r.msgtype})" for r in records) if records else "none"

    def require_topic(self, topic: str, allowed_types: Sequence[str] = ()) -> TopicRecord:
        """The record of ``topic``; BagError when the bag lacks it or it has none of ``allowed_types``
        (``"sensor_msgs/Imu"`` and ``"sensor_msgs/msg/Imu"`` are the same type; empty = any type)."""
        if isinstance(allowed_types, str):
            allowed_types = [allowed_types]
        record = next((r for r in self._cheap_records() if r.topic == topic), None)
        if record is None:
            raise BagError(f"Bag '{self.path}': topic '{topic}' not found. The bag's topics are: {self._topic_list()}.")
        allowed = [normalize_msgtype(t) for t in allowed_types]
        if allowed and record.msgtype not in allowed:
            raise BagError(f"Bag '{self.path}': topic '{topic}' must have type {' or '.join(allowed)}. "
                           f"Got {record.msgtype} instead.")
        return record

    # -- messages ---------------------------------------------------------------------------------------
    def _typestore(self) -> Any:
        if self._store is None:
            with _boundary(self.path, "has message definitions that cannot be used"):
                self._store = build_typestore(self._connections, self._user_types, ros1=self.is_ros1)
        return self._store

    def messages(self, topics: str | Iterable[str] | None = None, *, on_damage: str = "raise") -> Iterator[BagMessage]:
        """Deserialized messages of ``topics`` (default all), in bag receive-time order, streamed.

        ``on_damage="count"``: a record that cannot be decoded, a chunk that cannot be read (MCAP, ROS 1: the
        reader goes on with the next one) and, at the end, the messages the bag's index declares but that were
        never read (a zeroed block, a stream cut short) are counted per topic in :attr:`damage` and skipped;
        ``"raise"`` (default): the first one is a BagError.

        Raises
        ------
        BagError
            A requested topic is missing; a type has no definition (pass its ``.msg`` file's directory with
            ``msg_dirs`` / ``--msg-dir``); the data is corrupt or truncated (raised when reached; with
            ``on_damage="count"`` only when every one of a topic's first records fails to decode: a wrong
            definition, not damage).
        """
        if on_damage not in ("raise", "count"):
            raise BagError(f"Bag '{self.path}': on_damage must be 'raise' or 'count'. Got {on_damage!r} instead.")
        reader = self._open_reader()
        wanted = [topics] if isinstance(topics, str) else (None if topics is None else list(topics))
        if wanted is not None:
            for topic in wanted:
                if not any(c.topic == topic for c in self._connections):
                    raise BagError(f"Bag '{self.path}': topic '{topic}' not found. "
                                   f"The bag's topics are: {self._topic_list()}.")
        conns = [c for c in self._connections if wanted is None or c.topic in wanted]
        if not conns:
            return iter(())
        store = self._typestore()
        for conn in conns:
            if missing := missing_types(store, conn.msgtype):
                raise BagError(f"Bag '{self.path}': topic '{conn.topic}' has message type '{conn.msgtype}' with no "
                               f"definition for {', '.join(repr(m) for m in missing)} (the bag does not embed it): "
                               f"pass the directory of its PKG/msg/NAME.msg file with --msg-dir (msg_dirs=...).")
        if on_damage == "count":
            return stream_counting(self, reader, conns, store)
        return self._stream(reader, conns, store)

    def _stream(self, reader: Any, conns: list[Any], store: Any) -> Iterator[BagMessage]:
        deserialize = store.deserialize_ros1 if self.is_ros1 else store.deserialize_cdr
        with _boundary(self.path, "cannot be read"):
            raw_messages = reader.messages(connections=conns)
        n_read = 0
        per_topic: dict[str, int] = {}
        while True:
            with _boundary(self.path, f"is corrupt or truncated after {n_read} message(s)"):
                try:
                    conn, stamp_ns, raw = next(raw_messages)
                except StopIteration:
                    self._check_all_read(conns, per_topic)
                    return
            per_topic[conn.topic] = per_topic.get(conn.topic, 0) + 1
            with _boundary(self.path, f"topic '{conn.topic}' message at {stamp_ns} ns cannot be decoded as "
                                      f"{conn.msgtype}"):
                msg = deserialize(raw, conn.msgtype)
            n_read += 1
            yield BagMessage(conn.topic, conn.msgtype, int(stamp_ns), msg)

    def _check_all_read(self, conns: list[Any], per_topic: dict[str, int]) -> None:
        """Every message the bag's index declares was read: else a BagError (a zeroed block inside an MCAP chunk
        loses messages without an error from the reader)."""
        declared: dict[str, int] = {}
        for c in conns:
            declared[c.topic] = declared.get(c.topic, 0) + max(int(c.msgcount or 0), 0)
        for topic, n in declared.items():
            if per_topic.get(topic, 0) < n:
                raise BagError(f"Bag '{self.path}': is damaged: its index declares {n} message(s) on topic '{topic}', "
                               f"only {per_topic.get(topic, 0)} could be read.")


def open_bag(path: str | os.PathLike, *, msg_dirs: Iterable[str | os.PathLike] = ()) -> Bag:
    """Open a ROS 1 ``.bag``, a ROS 2 bag directory (sqlite3 or mcap) or a bare ``.mcap``/``.db3`` file.

    Parameters
    ----------
    path : path-like
        The bag. A ``.bag`` must be a regular file (checked first, so a FIFO or device never blocks).
    msg_dirs : iterable of path-like
        Directories holding ``PKG/msg/NAME.msg`` definitions of custom types a ROS 2 bag does not embed.

    Returns
    -------
    Bag
        Open; use it in a ``with`` block.

    Raises
    ------
    BagError
        Missing, empty, special, truncated, corrupt or non-bag file; directory without ``metadata.yaml``;
        unparsable ``.msg`` file. The message names the file.
    """
    return Bag(path, msg_dirs=msg_dirs)
