"""The one progress convention of semslam. Every long call takes ``progress``:

* ``False`` / ``None``: silent;
* ``True``: a tqdm bar on stderr (closed at the end, left on screen only while running);
* a callable ``progress(done, total)``: called after every step (to drive a GUI, a log, a test).

Inside, ``with progress_steps(progress, total, "scans", "scan") as step: ... step()``.
"""

from __future__ import annotations

import contextlib
from typing import Any, Callable, Iterator

Progress = bool | Callable[[int, int], None] | None


@contextlib.contextmanager
def progress_steps(progress: Any, total: int, desc: str, unit: str = "it") -> Iterator[Callable[[int], None]]:
    """A ``step(n=1)`` function reporting ``n`` more steps done out of ``total`` (see the module docstring)."""
    if callable(progress) and not isinstance(progress, bool):
        done = [0]

        def step(n: int = 1) -> None:
            done[0] += n
            progress(done[0], total)

        yield step
    elif progress:
        from tqdm import tqdm

        bar = tqdm(total=total, desc=desc, unit=unit, leave=False)
        try:
            yield bar.update
        finally:
            bar.close()
    else:
        yield lambda n=1: None
