"""Outputs that never destroy what semslam did not write: the one module deciding what an output may replace.

**Ownership marker.** Every directory semslam writes as a whole (a run, a mission, a bag directory, a segmentation,
a demo, a batch's folder) holds the file :data:`MARKER` (``.semslam-run``), one JSON object::

    {"semslam_output": 2, "kind": "run", "id": "<uuid4 hex>", "check": "<sha256 hex>"}

``id`` is a random UUID drawn when the directory is staged; ``check`` is the SHA-256 of a semslam-specific prefix,
the version, the kind and the id (:func:`_check`). A directory is semslam's only when its marker parses, has this
version and its ``check`` matches: a look-alike cannot fake this by accident (a folder holding ``config.json`` +
``metrics.json`` + ``report.html``, or ``mission.json``, or a ``.semslam-run`` of any other content, e.g. the fixed
text ``semslam run`` of the first markers, proves nothing). Such folders are never replaced: the error says to remove
them yourself. The marker is not a security device (its recipe is in this file): it guards against accidents. A copy
of a semslam output (``cp -r``) carries the marker and is semslam's too.

**Rules** (:func:`check_output_dir`, :func:`check_output_file`; the CLI calls them before any work):

* an existing non-empty directory is replaced only with ``overwrite`` and only when its marker proves semslam wrote
  it, as an output of a kind in ``replaces`` (by default the same kind, a run and a demo being alike:
  ``--overwrite`` of a run never replaces a mission or a bag); an empty directory may always be used; a symbolic
  link is never replaced;
* an existing file is replaced only with ``overwrite``; a directory is never replaced by a file, nor a file by a
  directory;
* an output equal to an input, inside an input, or holding an input (``inputs=``) is refused;
* a folder updated in place (a batch's ``--out``, :func:`claim_output_dir`) is marked when new or empty and used
  only when its marker says it is of that kind.

**Staging.** :func:`staged_output_dir` and :func:`staged_output_file` write into a fresh hidden sibling named
``.NAME.semslam-<pid>-<random>.tmp`` (made by :func:`tempfile.mkdtemp`: unique to the process and the call) and
rename it over the target at the end, so an interrupted write leaves the previous output intact. Nothing is swapped
in after the command received a Ctrl-C, even one a library swallowed (:func:`semslam._signals.raise_if_interrupted`). Clean-up removes
only the staging folders the call itself created: never another sibling, whatever its name (a killed process's
staging folder stays until you remove it).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import tempfile
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator

from ._signals import raise_if_interrupted, remove_on_interrupt
from .errors import InputError

MARKER = ".semslam-run"
MARKER_VERSION = 2
_PREFIX = b"semslam output ownership marker\x00"
_MAX_MARKER_BYTES = 4096
#: how the error messages name an output of each kind
_NOUN = {"run": "run", "demo": "run", "mission": "mission", "bag": "bag", "segmentation": "segmentation",
         "batch": "batch folder"}
#: the kinds an output of each kind replaces unless the caller says otherwise (a run and a demo are both run dirs)
_REPLACES = {"run": ("run", "demo"), "demo": ("demo", "run")}


@dataclass(frozen=True)
class Ownership:
    """What a valid marker says: the output's ``kind`` and its ``id``."""

    kind: str
    id: str


def _check(kind: str, ident: str) -> str:
    return hashlib.sha256(_PREFIX + f"{MARKER_VERSION}\x00{kind}\x00{ident}".encode()).hexdigest()


def marker_text(kind: str, ident: str | None = None) -> str:
    """The marker of a new output of ``kind`` (a fresh random id unless ``ident``)."""
    ident = uuid.uuid4().hex if ident is None else ident
    doc = {"semslam_output": MARKER_VERSION, "kind": kind, "id": ident, "check": _check(kind, ident)}
    return json.dumps(doc) + "\n"


def ownership(path: str | os.PathLike) -> Ownership | None:
    """The ownership recorded in the directory ``path`` by semslam, or None when it proves nothing (no marker, a
    marker of another content or version, a symbolic link)."""
    m = Path(path) / MARKER
    try:
        if m.is_symlink() or not m.is_file() or m.stat().st_size > _MAX_MARKER_BYTES:
            return None
        doc = json.loads(m.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("semslam_output") != MARKER_VERSION:
        return None
    kind, ident, check = doc.get("kind"), doc.get("id"), doc.get("check")
    if not all(isinstance(v, str) and v for v in (kind, ident, check)) or check != _check(kind, ident):
        return None
    return Ownership(kind, ident)


def is_owned(path: str | os.PathLike, kind: str | None = None) -> bool:
    """Whether ``path`` is a directory semslam wrote (as an output of ``kind``, when given)."""
    p = Path(path)
    if p.is_symlink() or not p.is_dir():
        return False
    own = ownership(p)
    return own is not None and (kind is None or own.kind == kind)


def _resolved(p: str | os.PathLike) -> Path:
    return Path(os.path.abspath(Path(p).expanduser())).resolve()


def check_inputs(path: str | os.PathLike, inputs: Iterable, *, option: str = "--out") -> None:
    """Refuse an output ``path`` equal to, inside or holding one of ``inputs`` (None and paths that do not exist,
    e.g. ``synthetic:1`` or ``builtin``, are skipped: they cannot be overwritten)."""
    out = _resolved(path)
    for given in inputs or ():
        if given is None or not isinstance(given, (str, os.PathLike)) or not Path(given).exists():
            continue
        src = _resolved(given)
        if out == src:
            raise InputError(f"The {option!r} output {str(path)!r} is the input {str(given)!r}: choose another "
                             "output (semslam never writes over its input).")
        if src in out.parents:
            raise InputError(f"The {option!r} output {str(path)!r} is inside the input {str(given)!r}: choose an "
                             "output outside it.")
        if out in src.parents:
            raise InputError(f"The {option!r} output {str(path)!r} holds the input {str(given)!r}: choose an "
                             "output that does not contain it.")


def check_output_dir(path: str | os.PathLike, *, overwrite: bool, option: str = "--out", kind: str = "run",
                     replaces: tuple[str, ...] | None = None, inputs: Iterable = ()) -> Path:
    """Raise unless ``path`` may become a new semslam directory of ``kind`` (see the module docstring);
    ``replaces``: the kinds of earlier semslam outputs it may replace (default: ``kind``; a run and a demo replace
    each other). Returns the path."""
    out = Path(path)
    check_inputs(out, inputs, option=option)
    if out.is_symlink():
        raise InputError(f"The {option!r} directory {str(out)!r} is a symbolic link: semslam never replaces a link; "
                         "give another path.")
    if out.exists() and not out.is_dir():
        raise InputError(f"The {option!r} option must name a directory. Got the file {str(out)!r} instead.")
    if out.is_dir() and any(out.iterdir()):
        own = ownership(out)
        if own is None:
            raise InputError(f"The {option!r} directory {str(out)!r} is not empty and semslam cannot prove it wrote "
                             f"it (no valid {MARKER} ownership marker; semslam never replaces what it did not write, "
                             "nor one marked before ownership ids): choose another, or remove it yourself.")
        allowed = _REPLACES.get(kind, (kind,)) if replaces is None else tuple(replaces)
        noun = _NOUN.get(kind, kind)
        if own.kind not in allowed:
            raise InputError(f"The {option!r} directory {str(out)!r} holds a semslam {_NOUN.get(own.kind, own.kind)}, "
                             f"not a {noun}: choose another, or remove it yourself.")
        if not overwrite:
            raise InputError(f"The {option!r} directory {str(out)!r} holds an earlier semslam {noun}: choose another, "
                             "or overwrite it (--overwrite).")
    return out


def check_output_file(path: str | os.PathLike, *, overwrite: bool, option: str = "--out",
                      inputs: Iterable = ()) -> Path:
    """Raise unless ``path`` may be written as a file: not an input, not a directory, and replacing an existing
    file only with ``overwrite``. Returns the path."""
    out = Path(path)
    check_inputs(out, inputs, option=option)
    if out.is_dir():
        raise InputError(f"The {option!r} option must name a file to write. Got the directory {str(out)!r} instead.")
    if (out.exists() or out.is_symlink()) and not overwrite:
        raise InputError(f"The {option!r} file {str(out)!r} exists: choose another, or overwrite it (--overwrite).")
    if out.exists() and not out.is_file():
        raise InputError(f"The {option!r} option must name a regular file. Got {str(out)!r} instead.")
    return out


def staging_dir(path: str | os.PathLike, what: str = "tmp") -> Path:
    """A new empty hidden sibling of ``path``, ``.NAME.semslam-<pid>-<random>.<what>``, unique to this call: the
    caller removes it (and only it)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.semslam-{os.getpid()}-", suffix=f".{what}", dir=out.parent))
    if what != "old":  # (an "old" folder holds the earlier output during a swap: never removed by the watchdog)
        remove_on_interrupt(tmp)
    return tmp


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def staged_output_dir(path: str | os.PathLike, *, overwrite: bool = False, kind: str = "run", option: str = "--out",
                      replaces: tuple[str, ...] | None = None, inputs: Iterable = ()) -> Iterator[Path]:
    """Yield a staging sibling of ``path`` to write into; on success mark it (:data:`MARKER`) and swap it in
    (replacing an earlier semslam output, under the rules of :func:`check_output_dir`, checked again at the swap);
    on failure remove it."""
    inputs = tuple(inputs or ())
    out = check_output_dir(path, overwrite=overwrite, option=option, kind=kind, replaces=replaces, inputs=inputs)
    tmp = staging_dir(out)
    try:
        os.chmod(tmp, 0o777 & ~_umask())
        yield tmp
        (tmp / MARKER).write_text(marker_text(kind), encoding="utf-8")
        raise_if_interrupted()
        check_output_dir(out, overwrite=overwrite, option=option, kind=kind, replaces=replaces, inputs=inputs)
        if out.exists():
            trash = staging_dir(out, "old")
            try:
                os.replace(out, trash / "previous")
                try:
                    os.replace(tmp, out)
                except BaseException:
                    os.replace(trash / "previous", out)  # put the earlier output back
                    raise
            finally:
                shutil.rmtree(trash, ignore_errors=True)
        else:
            os.replace(tmp, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)  # ours: gone once swapped in, else an interrupted write


@contextlib.contextmanager
def staged_output_file(path: str | os.PathLike, *, overwrite: bool = False, option: str = "--out",
                       inputs: Iterable = ()) -> Iterator[Path]:
    """Yield a path, with the name of ``path``, inside a staging sibling folder; on success the file written there
    replaces ``path`` (under the rules of :func:`check_output_file`, checked again then); the folder is removed."""
    inputs = tuple(inputs or ())
    out = check_output_file(path, overwrite=overwrite, option=option, inputs=inputs)
    tmp = staging_dir(out)
    try:
        yield tmp / out.name
        staged = tmp / out.name
        if not staged.is_file():
            raise InputError(f"Nothing was written for the {option!r} file {str(out)!r}.")
        raise_if_interrupted()
        check_output_file(out, overwrite=overwrite, option=option, inputs=inputs)
        os.replace(staged, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def claim_output_dir(path: str | os.PathLike, *, kind: str, option: str = "--out", inputs: Iterable = ()) -> Path:
    """Use ``path`` as a directory semslam updates in place (a batch's folder of run directories): created and
    marked when it does not exist or is empty, accepted when semslam's marker says it is of ``kind``, refused
    otherwise (a foreign or look-alike folder)."""
    out = Path(path)
    check_inputs(out, inputs, option=option)
    if out.is_symlink():
        raise InputError(f"The {option!r} directory {str(out)!r} is a symbolic link: give the real path.")
    if out.exists() and not out.is_dir():
        raise InputError(f"The {option!r} option must name a directory. Got the file {str(out)!r} instead.")
    if out.is_dir() and any(out.iterdir()):
        own = ownership(out)
        if own is None or own.kind != kind:
            what = ("semslam cannot prove it wrote it (no valid " + MARKER + " ownership marker)" if own is None
                    else f"it holds a semslam {_NOUN.get(own.kind, own.kind)}")
            raise InputError(f"The {option!r} directory {str(out)!r} is not empty and {what}: semslam writes a "
                             f"{_NOUN.get(kind, kind)} only into a new directory or one it made; choose another, or "
                             "remove it yourself.")
        return out
    out.mkdir(parents=True, exist_ok=True)
    from ._atomic import atomic_write_text

    atomic_write_text(out / MARKER, marker_text(kind))
    return out


__all__ = ["MARKER", "Ownership", "ownership", "is_owned", "marker_text", "check_inputs", "check_output_dir",
           "check_output_file", "staging_dir", "staged_output_dir", "staged_output_file", "claim_output_dir"]
