"""Message definitions for a bag: the definitions the bag embeds, ``.msg`` files given by the user, a default
typestore (ROS 1 Noetic or ROS 2 Humble) and the definitions packaged with semslam (``semslam/io/ros/msg``:
semslam's own ``semslam_msgs`` and the DVL messages vehicles record, see its SOURCES.md), in that order of
precedence. rosbags imported lazily."""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any, Iterable, Iterator, Sequence

from ...errors import BagError

__all__ = ["PACKAGED_MSG_DIR", "build_typestore", "load_msg_dirs", "missing_types", "normalize_msgtype",
           "packaged_types", "semslam_typestore"]

_IDL_SEP = "=" * 80 + "\n"
#: the ``PKG/msg/NAME.msg`` definitions shipped with semslam (package data)
PACKAGED_MSG_DIR = Path(__file__).resolve().parent / "msg"
_PACKAGED: dict[str, Any] | None = None


def normalize_msgtype(name: str) -> str:
    """``"sensor_msgs/Imu"`` (ROS 1 style) -> ``"sensor_msgs/msg/Imu"`` (rosbags' name); others unchanged."""
    parts = str(name).strip().split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else str(name).strip()


def _regular(path: Path, what: str) -> None:
    try:
        mode = os.stat(path).st_mode
    except OSError as err:
        raise BagError(f"{what} '{path}' cannot be read ({err.strerror or err}).") from None
    if not stat.S_ISREG(mode):
        raise BagError(f"{what} '{path}' must be a regular file. Got a special file (FIFO, device or socket) instead.")


def load_msg_dirs(msg_dirs: Iterable[str | os.PathLike]) -> dict[str, Any]:
    """Parse every ``PKG/msg/NAME.msg`` file under each directory into rosbags type definitions.

    A directory may be a ``msg`` folder, a package (holding ``msg/``) or a folder of packages; a ``.msg``
    file's type is ``PKG/msg/NAME`` where PKG is the folder above its ``msg`` folder.
    """
    if isinstance(msg_dirs, (str, os.PathLike)):
        msg_dirs = [msg_dirs]
    from rosbags.typesys import get_types_from_msg

    types: dict[str, Any] = {}
    for entry in msg_dirs:
        root = Path(entry)
        if not root.is_dir():
            raise BagError(f"The 'msg_dirs' argument of open_bag must list directories holding PKG/msg/NAME.msg files. "
                           f"Got '{root}' (not a directory) instead.")
        files = sorted(p for p in root.rglob("*.msg") if p.parent.name == "msg")
        if not files:
            raise BagError(f"The 'msg_dirs' argument of open_bag must list directories holding PKG/msg/NAME.msg files. "
                           f"Got '{root}', which holds none, instead.")
        for file in files:
            _regular(file, "Message definition")
            name = f"{file.parent.parent.name}/msg/{file.stem}"
            try:
                types.update(get_types_from_msg(file.read_text(encoding="utf-8"), name))
            except Exception as err:  # rosbags parse errors, UnicodeDecodeError, OSError
                raise BagError(f"Message definition '{file}' ({name}) cannot be parsed: {_one_line(err)}") from None
    return types


def packaged_types() -> dict[str, Any]:
    """The rosbags definitions of the ``.msg`` files shipped in :data:`PACKAGED_MSG_DIR` (parsed once)."""
    global _PACKAGED
    if _PACKAGED is None:
        _PACKAGED = load_msg_dirs([PACKAGED_MSG_DIR])
    return dict(_PACKAGED)


def _with_packaged(default_fielddefs: dict[str, Any]) -> dict[str, Any]:
    """The packaged definitions under the default store's: a standard type keeps its distribution's definition."""
    types = packaged_types()
    types.update(default_fielddefs)
    return types


def semslam_typestore(ros1: bool = False) -> Any:
    """The default typestore (ROS 1 Noetic or ROS 2 Humble) plus every packaged definition it lacks: what a
    writer of semslam's bags (or a test writing a vendor DVL message) registers its messages from."""
    from ._encode import default_typestore

    store = default_typestore(ros1=ros1)
    store.register({k: v for k, v in packaged_types().items() if k not in store.fielddefs})
    return store


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) <= 300 else text[:297] + "..."


def embedded_types(connections: Sequence[Any]) -> dict[str, Any]:
    """Types defined by the connections' embedded definitions (ROS 1 msgdef, ROS 2 msg/idl); empty
    definitions (ROS 2 Humble bags, types without a schema) add nothing."""
    from rosbags.interfaces import MessageDefinitionFormat as Fmt
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    types: dict[str, Any] = {}
    for conn in connections:
        fmt, data = conn.msgdef.format, conn.msgdef.data
        if fmt == Fmt.NONE or not data or not data.strip():
            continue
        if fmt == Fmt.MSG:
            types.update(get_types_from_msg(data, conn.msgtype))
        elif data.startswith(f"{_IDL_SEP}IDL: "):
            for block in data.split(_IDL_SEP)[1:]:
                types.update(get_types_from_idl(block.split("\n", 1)[1]))
        else:
            types.update(get_types_from_idl(data))
    return types


def _references(fields: Sequence[Any]) -> Iterator[str]:
    """Names of the message types the fields of a definition refer to (nested arrays/sequences included)."""
    from rosbags.typesys.base import Nodetype

    for _, desc in fields:
        while desc[0] in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            desc = desc[1][0]
        if desc[0] == Nodetype.NAME:
            yield desc[1]


def _closure(types: dict[str, Any], roots: Iterable[str]) -> dict[str, Any]:
    """The definitions in ``types`` reachable from ``roots`` (names not in ``types`` are left out)."""
    needed: dict[str, Any] = {}
    stack = list(roots)
    while stack:
        name = stack.pop()
        if name in needed or name not in types:
            continue
        needed[name] = types[name]
        stack.extend(_references(types[name][1]))
    return needed


def build_typestore(connections: Sequence[Any], user_types: dict[str, Any], *, ros1: bool) -> Any:
    """A rosbags typestore with, by precedence, the bag's embedded, the user's, the default and the packaged
    types; only the types the connections need are registered (registration generates code: keep it small)."""
    from rosbags.typesys import Stores, get_typestore

    from ._encode import default_typestore

    types = _with_packaged(default_typestore(ros1=ros1).fielddefs)
    types.update(user_types)
    types.update(embedded_types(connections))
    store = get_typestore(Stores.EMPTY)
    store.register(_closure(types, {c.msgtype for c in connections}))
    return store


def missing_types(store: Any, msgtype: str) -> list[str]:
    """Types ``msgtype`` needs (itself or nested) that ``store`` does not define; empty when complete."""
    missing: list[str] = []
    seen: set[str] = set()
    stack = [msgtype]
    while stack:
        name = stack.pop()
        if name in seen:
            continue
        seen.add(name)
        if name not in store.fielddefs:
            missing.append(name)
        else:
            stack.extend(_references(store.fielddefs[name][1]))
    return missing
