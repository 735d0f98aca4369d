"""The Dask engine of semslam's many-task commands (``semslam batch``, ``montecarlo``, ``db build --models``).

* :func:`dask_client`: a client of the cluster at ``scheduler`` (``tcp://host:8786``), or of a new
  ``LocalCluster`` of ``workers`` processes (default: one per core of this machine) with one thread each, closed
  (with its worker processes) on exit.
* :func:`map_tasks`: ``[fn(item) for item in items]``, serially in this process (``jobs=1``, no scheduler, no
  client) or as Dask tasks, with the results in the order of ``items`` whatever the order they finish in; a task
  whose worker dies is re-run by the scheduler on another worker (up to ``distributed.scheduler.allowed-failures``
  times), a task that raises is retried ``retries`` times.

Tasks must be module-level functions (or ``functools.partial`` of them) of small picklable arguments; they
return small results (metrics, arrays of a few thousand numbers), never a whole mission, so that the scheduler
and the client are not the bottleneck. The results do not depend on the engine: every task is seeded by its own
arguments, never by which worker runs it or when.
"""

from __future__ import annotations

import contextlib
import logging
import os
import warnings
from typing import Any, Callable, Iterator, Sequence

from .._progress import Progress, progress_steps
from ..errors import InputError

#: how many times a task that raised is re-run before its error is final
DEFAULT_RETRIES = 2
#: how long to try to reach a ``--scheduler``
CONNECT_TIMEOUT = "10s"


def machine_workers() -> int:
    """Cores this process may use: the default size of a local cluster."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return max(1, os.cpu_count() or 1)


def check_jobs(jobs: Any, option: str = "--jobs") -> int:
    """``jobs`` as a positive int, or an :class:`InputError` naming ``option``."""
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise InputError(f"The {option!r} option must be a positive number of worker processes. Got {jobs!r} instead.")
    return jobs


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Any]:
    """A ``distributed.Client`` (see the module docstring); closed, with a local cluster's workers, on exit."""
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT)
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(f"The '--scheduler' option must be the address of a running Dask scheduler "
                             f"(e.g. tcp://host:8786). Could not connect to {scheduler!r}: {exc}") from None
        try:
            yield client
        finally:
            client.close()
        return
    n = check_jobs(workers if workers is not None else machine_workers(), "--workers")
    with warnings.catch_warnings():  # no dashboard; the scheduler's health endpoint moves off a busy 8787 quietly
        warnings.filterwarnings("ignore", message="Port .* is already in use", category=UserWarning)
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.ERROR)
    try:
        client = Client(cluster)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()


class TaskFailed:
    """The final error of one task (``map_tasks(..., capture_errors=True)``): its type name and message."""

    def __init__(self, exc: BaseException):
        self.type = type(exc).__name__
        self.message = " ".join(str(exc).split()) or self.type

    def __str__(self) -> str:
        return f"{self.type}: {self.message}"

    def __repr__(self) -> str:
        return f"TaskFailed({self})"


def map_tasks(fn: Callable[[Any], Any], items: Sequence[Any], *, client: Any = None, scheduler: str | None = None,
              jobs: int = 1, retries: int = DEFAULT_RETRIES, progress: Progress = False, desc: str = "tasks",
              on_result: Callable[[int, Any], None] | None = None, capture_errors: bool = False) -> list:
    """``[fn(item) for item in items]`` on the engine chosen by ``client`` / ``scheduler`` / ``jobs``.

    ``client``: an open ``distributed.Client`` (used, not closed); else ``scheduler``: the address of a running
    scheduler; else ``jobs`` > 1: a local cluster of ``jobs`` worker processes for this call; ``jobs`` = 1: serial,
    in this process. ``progress``: a bar or ``progress(done, total)`` per finished task; ``on_result(i, result)``
    as each task finishes (in finishing order). ``capture_errors``: a task's final error becomes a
    :class:`TaskFailed` in its slot instead of being raised (the other tasks go on).
    """
    items = list(items)
    jobs = check_jobs(jobs)
    if client is None and not scheduler and jobs == 1:
        return _serial(fn, items, progress, desc, on_result, capture_errors)
    if client is not None:
        return _on_client(client, fn, items, retries, progress, desc, on_result, capture_errors)
    with dask_client(scheduler, min(jobs, max(1, len(items)))) as new:  # no idle worker processes
        return _on_client(new, fn, items, retries, progress, desc, on_result, capture_errors)


def _serial(fn, items, progress, desc, on_result, capture_errors) -> list:
    out = []
    with progress_steps(progress, len(items), desc, "task") as step:
        for i, item in enumerate(items):
            try:
                r = fn(item)
            except Exception as exc:
                if not capture_errors:
                    raise
                r = TaskFailed(exc)
            out.append(r)
            step()
            if on_result is not None:
                on_result(i, r)
    return out


def _on_client(client, fn, items, retries, progress, desc, on_result, capture_errors) -> list:
    from distributed import as_completed

    futures = client.map(fn, items, retries=int(retries), pure=False)
    slot = {f.key: i for i, f in enumerate(futures)}
    out: list = [None] * len(items)
    try:
        with progress_steps(progress, len(items), desc, "task") as step:
            for fut in as_completed(futures):
                i = slot[fut.key]
                try:
                    out[i] = fut.result()
                except Exception as exc:
                    if not capture_errors:
                        raise
                    out[i] = TaskFailed(exc)
                fut.release()
                step()
                if on_result is not None:
                    on_result(i, out[i])
    finally:
        client.cancel([f for f in futures if not f.done()])
    return out
