"""Output directories that never destroy what semslam did not write.

Every directory semslam creates as a whole (a run, a mission, a demo) carries a marker file, :data:`MARKER`.
:func:`staged_output_dir` builds the new directory beside the target and swaps it in at the end: an interrupted
run leaves the previous one intact (and only a hidden ``.NAME.*.tmp`` sibling, removed by the next run into the
same place). An existing target is replaced only with ``overwrite`` and only when it carries the marker (or is
empty); a foreign non-empty directory, or a file, is refused with a one-line error.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from .errors import InputError

MARKER = ".semslam-run"


def check_output_dir(path: str | os.PathLike, *, overwrite: bool, option: str = "--out",
                     markers: tuple[str, ...] = (MARKER,)) -> Path:
    """Raise unless ``path`` may become a new semslam directory (see the module docstring); ``markers``: files
    any of which shows a directory is semslam's (a version-1 mission directory has ``mission.json`` only)."""
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise InputError(f"The {option!r} option must name a directory. Got the file {str(out)!r} instead.")
    if out.is_dir() and any(out.iterdir()):
        if not any((out / m).is_file() for m in markers) and not _legacy_run(out):
            raise InputError(f"The {option!r} directory {str(out)!r} is not empty and was not written by semslam: "
                             "choose another (semslam never replaces what it did not write).")
        if not overwrite:
            raise InputError(f"The {option!r} directory {str(out)!r} holds an earlier semslam run: choose another, "
                             "or overwrite it.")
    return out


def _legacy_run(out: Path) -> bool:
    """A run directory semslam 0.1 wrote before the marker existed (config.json and metrics.json beside its report
    or its trajectory): still ours to replace, so that an upgrade does not break ``make demo``."""
    return all((out / f).is_file() for f in ("config.json", "metrics.json")) and \
        any((out / f).is_file() for f in ("report.html", "trajectory.csv"))


def _clean_stale(out: Path) -> None:
    for p in out.parent.glob(f".{out.name}.*.tmp"):
        shutil.rmtree(p, ignore_errors=True)


@contextlib.contextmanager
def staged_output_dir(path: str | os.PathLike, *, overwrite: bool = False, kind: str = "run",
                      option: str = "--out", markers: tuple[str, ...] = (MARKER,)) -> Iterator[Path]:
    """Yield a temporary sibling of ``path`` to write into; on success mark it and swap it in (atomically
    replacing an earlier semslam directory), on failure remove it."""
    out = check_output_dir(path, overwrite=overwrite, option=option, markers=markers)
    out.parent.mkdir(parents=True, exist_ok=True)
    _clean_stale(out)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    try:
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(tmp, 0o777 & ~mask)
        yield tmp
        (tmp / MARKER).write_text(f"semslam {kind}\n", encoding="utf-8")
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
            os.replace(out, old / "previous")
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
