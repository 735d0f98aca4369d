"""Saving and loading a view database: one uncompressed ``.npz`` (no pickle), checksummed, its declared sizes
and decompressed size checked before anything is allocated (see :mod:`semslam.recognition.database` for the
format).
"""

from __future__ import annotations

import json
import zipfile
import zlib
from pathlib import Path

import numpy as np

from .._atomic import atomic_open
from ..errors import DatabaseError, InputError, SemslamError
from ..symmetry import Symmetry
from .preprocessing import ViewPreprocessing
from .database import (_ARRAYS, _MODEL_ARRAYS, FORMAT_NAME, FORMAT_VERSION, READABLE_VERSIONS, ClassInfo,
                       ViewDatabase, _check_consistency)

def _checksum(arr: np.ndarray) -> str:
    """CRC-32 of an array's bytes, 8 hex digits (integrity, not security: 1.4 GB/s where SHA-256 does 0.2)."""
    return f"{zlib.crc32(np.ascontiguousarray(arr).data):08x}"



def save_database(db: ViewDatabase, path: str | Path) -> Path:
    """Write ``db`` to ``path`` (an ``.npz``, written atomically). Returns the path."""
    if not isinstance(db, ViewDatabase):
        raise InputError(f"The 'db' argument of save_database must be a ViewDatabase. Got {type(db).__name__} instead.")
    path = Path(path)
    arrays = {name: getattr(db, name) for name in _ARRAYS + _MODEL_ARRAYS}
    meta = {
        "format": FORMAT_NAME, "version": FORMAT_VERSION, "n_views": db.n_views,
        "classes": {c: db.class_infos[c].to_dict() for c in db.classes},
        "params": dict(db.params),
        "checksums": {name: _checksum(arr) for name, arr in arrays.items()},
    }
    try:
        with atomic_open(path, "wb") as fh:
            np.savez(fh, meta=np.array(json.dumps(meta)), **arrays)
    except OSError as exc:
        raise DatabaseError(f"Cannot write the database file {str(path)!r}: {exc.strerror or exc}.") from None
    return path



def load_database(path: str | Path, *, verify: bool = True) -> ViewDatabase:
    """Read a database written by :func:`save_database`.

    Raises DatabaseError naming the file when it is missing, not a database, truncated or corrupted
    (zip CRC or array checksum mismatch, with ``verify``), of another format version, or inconsistent.
    """
    path = Path(path)
    where = f"The database file {str(path)!r}"
    if not path.is_file():
        raise DatabaseError(f"{where} does not exist or is not a regular file.")
    _inspect_archive(path, where)
    try:
        with np.load(path, allow_pickle=False) as npz:
            if "meta" not in npz.files:
                raise DatabaseError(f"{where} is not a semslam view database: it has no 'meta' entry.")
            meta = json.loads(str(npz["meta"][()]))
            if not isinstance(meta, dict) or meta.get("format") != FORMAT_NAME:
                raise DatabaseError(
                    f"{where} is not a semslam view database: format is "
                    f"{meta.get('format') if isinstance(meta, dict) else meta!r}, expected {FORMAT_NAME!r}."
                )
            version = meta.get("version")
            if version not in READABLE_VERSIONS:
                raise DatabaseError(f"{where} has format version {version!r}; this semslam reads versions "
                                    f"{', '.join(map(str, READABLE_VERSIONS))}. Rebuild it with 'semslam db build'.")
            names = _ARRAYS + (_MODEL_ARRAYS if version >= 2 else ())
            missing = [n for n in names if n not in npz.files]
            if missing:
                raise DatabaseError(f"{where} is missing the arrays {', '.join(missing)}.")
            arrays = {name: npz[name] for name in names}
    except DatabaseError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile) as exc:
        raise DatabaseError(f"{where} is truncated or corrupted (bad zip archive: {exc}).") from None
    except (ValueError, OSError, EOFError, KeyError, json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise DatabaseError(f"{where} is truncated or corrupted ({type(exc).__name__}: {exc}).") from None
    params = meta.get("params", {})
    if not isinstance(params, dict) or not all(v is None or isinstance(v, (str, int, float, bool, dict, list))
                                               for v in params.values()):
        raise DatabaseError(f"{where} has invalid descriptor parameters: expected a table, got {params!r:.80}.")
    if version < 3:  # written before the views' preprocessing was recorded
        params = {**params, "preprocessing": ViewPreprocessing.unknown().to_dict()}
    else:  # a record this semslam cannot apply is refused now, not at the first query
        ViewPreprocessing.from_dict(params.get("preprocessing"), where)
    if verify:
        checksums = meta.get("checksums", {})
        for name, arr in arrays.items():
            if checksums.get(name) != _checksum(arr):
                raise DatabaseError(f"{where} is corrupted: the checksum of the array {name!r} does not match.")
    try:
        classes = {c: ClassInfo(c, Symmetry.from_dict(info["symmetry"]), info["size_xyz_m"])
                   for c, info in meta["classes"].items()}
    except (KeyError, TypeError, AttributeError, SemslamError) as exc:
        raise DatabaseError(f"{where} has an invalid class table: {exc}.") from None
    db = object.__new__(ViewDatabase)
    for name, arr in arrays.items():
        object.__setattr__(db, name, arr)
    object.__setattr__(db, "class_infos", classes)
    object.__setattr__(db, "params", dict(params))
    if "model_labels" not in arrays:  # version 1: no pose-model views
        for name, value in zip(_MODEL_ARRAYS, (np.zeros(0, "<U1"), np.zeros(1, np.int64), np.zeros((0, 3), np.float32),
                                               np.zeros((0, 3)))):
            object.__setattr__(db, name, value)
    _check_consistency(db, where, DatabaseError)
    for name in _ARRAYS + _MODEL_ARRAYS:
        getattr(db, name).setflags(write=False)
    return db


#: the most a database may hold once decompressed: far above any real one, far below what a crafted file could ask
MAX_DECOMPRESSED_BYTES = 4 << 30



def _inspect_archive(path: Path, where: str) -> None:
    """Before numpy allocates anything: the file is a zip archive, its entries decompress to at most
    :data:`MAX_DECOMPRESSED_BYTES` in all, and no ``.npy`` entry declares more data than it holds (a crafted
    header could ask for terabytes)."""
    if not zipfile.is_zipfile(path):
        raise DatabaseError(f"{where} is truncated or corrupted, or not a semslam view database (.npz): it is not a "
                            "readable zip archive.")
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
            total = sum(i.file_size for i in infos)
            if total > MAX_DECOMPRESSED_BYTES:
                raise DatabaseError(f"{where} would decompress to {total} bytes, more than the "
                                    f"{MAX_DECOMPRESSED_BYTES} a view database may hold.")
            for info in infos:
                if not info.filename.endswith(".npy"):
                    continue
                with zf.open(info) as fh:
                    version = np.lib.format.read_magic(fh)
                    read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                                   else np.lib.format.read_array_header_2_0)
                    shape, _, dtype = read_header(fh)
                    if dtype.hasobject:
                        raise DatabaseError(f"{where}: the array {info.filename!r} holds Python objects.")
                    declared = int(np.prod(shape, dtype=object)) * dtype.itemsize
                    if declared > info.file_size:
                        raise DatabaseError(f"{where}: the array {info.filename!r} declares {declared} bytes but "
                                            f"holds {info.file_size}: truncated or crafted.")
    except DatabaseError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, OSError, EOFError, SyntaxError) as exc:
        raise DatabaseError(f"{where} is truncated or corrupted ({type(exc).__name__}: {exc}).") from None
