"""The Dask engine of semslam's many-task commands (``semslam batch``, ``montecarlo``, ``db build --models``).

* :func:`dask_client`: a client of the cluster at ``scheduler`` (``tcp://host:8786``, or ``tls://host:8786`` with
  certificates: see below), or of a new ``LocalCluster`` of ``workers`` processes (default: one per core of this
  machine) with one thread each, closed (with its worker processes) on exit.
* :func:`map_tasks`: ``[fn(item) for item in items]``, serially in this process (``jobs=1``, no scheduler, no
  client) or as Dask tasks, with the results in the order of ``items`` whatever the order they finish in; a task
  whose worker dies is re-run by the scheduler on another worker (up to ``distributed.scheduler.allowed-failures``
  times), a task that raises is retried ``retries`` times.

Tasks must be module-level functions (or ``functools.partial`` of them) of small picklable arguments; they
return small results (metrics, arrays of a few thousand numbers), never a whole mission, so that the scheduler
and the client are not the bottleneck. The results do not depend on the engine: every task is seeded by its own
arguments, never by which worker runs it or when.

Security (docs/batch.md). A ``tcp://`` scheduler is unauthenticated and unencrypted: whoever reaches its port runs
code on every worker; for trusted networks only. A ``tls://`` scheduler is reached with Dask's TLS configuration,
the certificates ``dask scheduler --tls-ca-file --tls-cert --tls-key`` takes: the CA that signed the scheduler's
and the workers' certificates, and this client's certificate and key signed by it. They come from the CLI's
``--tls-ca-file --tls-cert --tls-key`` (made Dask's config for the command by :func:`scheduler_tls`) or from Dask's
config (``distributed.comm.tls.ca-file``, ``distributed.comm.tls.client.cert``, ``distributed.comm.tls.client.key``)
and become a ``distributed.Security(require_encryption=True, ...)``. Before the client connects, one TLS handshake
with the scheduler checks both ways (the scheduler's certificate against the CA, this client's certificate by the
scheduler), so that a refusal is a one-line :class:`InputError` in milliseconds, not a 10 s time-out.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import ssl
import warnings
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

from .._progress import Progress, progress_steps
from ..errors import InputError

#: how many times a task that raised is re-run before its error is final
DEFAULT_RETRIES = 2
#: how long to try to reach a ``--scheduler``
CONNECT_TIMEOUT = "10s"
#: how long the TLS handshake that checks the certificates may take (s)
HANDSHAKE_TIMEOUT_S = 10.0
#: the largest certificate or key file read (bytes): a PEM chain is a few KB
MAX_PEM_BYTES = 1 << 20
#: CLI option -> (Dask config key, what the file holds)
TLS_OPTIONS = {"--tls-ca-file": ("distributed.comm.tls.ca-file", "CA certificate"),
               "--tls-cert": ("distributed.comm.tls.client.cert", "client certificate"),
               "--tls-key": ("distributed.comm.tls.client.key", "private key")}


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
        security = scheduler_security(scheduler)
        if security is not None:
            _check_handshake(scheduler, security)
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT, security=security)
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


@contextlib.contextmanager
def scheduler_tls(scheduler: str | None, ca_file: str | None = None, cert: str | None = None,
                  key: str | None = None) -> Iterator[None]:
    """Check the CLI's ``--scheduler`` and ``--tls-*`` options and make the certificates Dask's configuration for
    the block, so that every :func:`dask_client` of ``scheduler`` in it uses them; one-line :class:`InputError` for
    certificates without a ``tls://`` scheduler, a ``tls://`` scheduler without certificates, and a missing,
    unreadable or non-PEM file."""
    import dask.config

    given = {opt: v for opt, v in zip(TLS_OPTIONS, (ca_file, cert, key)) if v is not None}
    if given and not _is_tls(scheduler):
        raise InputError(f"The --tls-* options ({', '.join(repr(o) for o in given)}) need a tls:// '--scheduler'. Got "
                         f"{'no --scheduler (a local cluster)' if not scheduler else f'--scheduler {scheduler!r}'} "
                         "instead.")
    if given:
        import distributed  # noqa: F401  (its config defaults first, or leaving the block would drop them)
    with dask.config.set({TLS_OPTIONS[opt][0]: str(Path(v).resolve()) for opt, v in given.items()}):
        if _is_tls(scheduler):
            _tls_files(scheduler, {opt: (f"the {opt!r} option", v) for opt, v in given.items()})
        yield


def scheduler_security(scheduler: str) -> Any:
    """The ``distributed.Security`` of a client of ``scheduler``: ``None`` for ``tcp://`` (unauthenticated: see
    the module docstring), else ``Security(require_encryption=True, ...)`` with Dask's TLS configuration."""
    import dask.config

    if not _is_tls(scheduler):
        if dask.config.get("distributed.comm.require-encryption", None):
            raise InputError(f"The '--scheduler' option must be a tls:// address: Dask's config requires encryption "
                             f"(distributed.comm.require-encryption). Got {scheduler!r} instead.")
        return None
    from distributed import Security

    ca, cert, key = _tls_files(scheduler, {})
    return Security(require_encryption=True, tls_ca_file=ca, tls_client_cert=cert, tls_client_key=key)


def _is_tls(scheduler: str | None) -> bool:
    return bool(scheduler) and str(scheduler).strip().lower().startswith("tls://")


def _tls_files(scheduler: str, given: dict) -> tuple:
    """``(ca_file, cert, key)`` of a client of the tls:// ``scheduler``, from ``given`` (option -> (its name in an
    error, path)) else Dask's config; each checked: present, readable, PEM, loadable, key matching certificate."""
    import dask.config

    found = {}
    for opt, (config_key, what) in TLS_OPTIONS.items():
        if opt in given:
            found[opt] = given[opt]
        elif dask.config.get(config_key, None):
            found[opt] = (f"Dask's config {config_key!r}", str(dask.config.get(config_key)))
    missing = [o for o in ("--tls-ca-file", "--tls-cert") if o not in found]
    if missing:
        raise InputError(f"The '--scheduler' {scheduler!r} is a TLS scheduler: give {' and '.join(missing)} (the "
                         "PEM files `dask scheduler --tls-ca-file --tls-cert --tls-key` takes: the CA that signed the "
                         "scheduler's certificate, this client's certificate signed by it, and its key), or set "
                         f"them in Dask's config ({', '.join(TLS_OPTIONS[o][0] for o in missing)}).")
    texts = {opt: _read_pem(name, path, TLS_OPTIONS[opt][1]) for opt, (name, path) in found.items()}
    ca_name, ca = found["--tls-ca-file"]
    cert_name, cert = found["--tls-cert"]
    key_name, key = found.get("--tls-key", (None, None))
    for opt in ("--tls-ca-file", "--tls-cert"):
        if "-----BEGIN CERTIFICATE-----" not in texts[opt]:
            raise InputError(f"The file of {found[opt][0]} must be a PEM {TLS_OPTIONS[opt][1]} "
                             f"('-----BEGIN CERTIFICATE-----'). Got {found[opt][1]!r}, which holds none.")
    key_text = texts["--tls-key"] if key else texts["--tls-cert"]
    if "PRIVATE KEY-----" not in key_text:
        raise InputError(f"The file of {key_name or cert_name} must hold a PEM private key ('-----BEGIN ... PRIVATE "
                         f"KEY-----'){'' if key else '; give --tls-key'}. Got {key or cert!r}, which holds none.")
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    try:
        ctx.load_verify_locations(cafile=ca)
    except ssl.SSLError as exc:
        raise InputError(f"The file of {ca_name} must be a PEM CA certificate. Got {ca!r}, which OpenSSL could not "
                         f"load: {exc}.") from None
    try:
        ctx.load_cert_chain(cert, key)
    except ssl.SSLError as exc:
        raise InputError(f"The certificate of {cert_name} ({cert!r}) and the private key of {key_name or cert_name} "
                         f"({key or cert!r}) must be a matching PEM pair. OpenSSL could not load them: "
                         f"{exc}.") from None
    return ca, cert, key


def _read_pem(name: str, path: str, what: str) -> str:
    p = Path(path)
    head = f"The file of {name} must be a PEM {what} file (as `dask scheduler --tls-*` takes). Got {path!r}, which"
    if not p.exists():
        raise InputError(f"{head} does not exist.")
    if not p.is_file():
        raise InputError(f"{head} is not a file.")
    try:
        with p.open("rb") as f:
            data = f.read(MAX_PEM_BYTES + 1)
    except OSError as exc:
        raise InputError(f"{head} cannot be read: {exc.strerror or exc}.") from None
    if len(data) > MAX_PEM_BYTES:
        raise InputError(f"{head} is larger than {MAX_PEM_BYTES} bytes.")
    return data.decode("latin-1")


def _check_handshake(scheduler: str, security: Any, timeout_s: float | None = None) -> None:
    """One TLS handshake with ``scheduler`` as ``security``'s client, and the scheduler's first bytes: a one-line
    :class:`InputError` if either side refuses the other's certificate (or the scheduler cannot be reached) within
    ``timeout_s`` (default :data:`HANDSHAKE_TIMEOUT_S`)."""
    from distributed.comm.addressing import parse_address, parse_host_port

    timeout_s = HANDSHAKE_TIMEOUT_S if timeout_s is None else timeout_s
    try:
        host, port = parse_host_port(parse_address(scheduler.strip())[1], 8786)
        if not 0 < int(port) < 65536:
            raise ValueError(f"port {port} is not in 1-65535")
    except ValueError as exc:
        raise InputError(f"The '--scheduler' option must be an address like tls://host:8786. Got {scheduler!r}: "
                         f"{exc}") from None
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)  # as Dask's client: the CA's signature is checked, not host names
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_REQUIRED
    ctx.load_verify_locations(cafile=security.tls_ca_file)
    if security.tls_client_cert:
        ctx.load_cert_chain(security.tls_client_cert, security.tls_client_key)
    try:
        raw = socket.create_connection((host, int(port)), timeout=timeout_s)
    except (OSError, OverflowError) as exc:
        raise InputError(f"The '--scheduler' option must be the address of a running Dask scheduler "
                         f"(e.g. tls://host:8786). Could not connect to {scheduler!r}: {exc}") from None
    try:
        with ctx.wrap_socket(raw, server_hostname=host) as tls:
            try:  # TLS 1.3: the scheduler judges this client's certificate after the handshake; it then speaks first
                first = tls.recv(1)
            except (socket.timeout, TimeoutError):
                return  # accepted, silent: the client's own connection tells the rest
            if not first:
                raise InputError(f"The TLS scheduler {scheduler!r} closed the connection after the handshake: it "
                                 "refused this client (is its certificate signed by the CA the scheduler trusts?).")
    except ssl.SSLCertVerificationError as exc:
        raise InputError(f"The TLS handshake with the scheduler {scheduler!r} failed: its certificate is not signed "
                         f"by the CA of --tls-ca-file ({exc.verify_message}). Give the CA that signed the scheduler's "
                         "certificate.") from None
    except ssl.SSLError as exc:
        reason = (exc.reason or str(exc)).lower().replace("_", " ")
        if "alert" not in reason and "certificate" not in reason:
            raise InputError(f"The TLS handshake with the scheduler {scheduler!r} failed ({reason}): is it a tls:// "
                             "Dask scheduler?") from None
        raise InputError(f"The TLS scheduler {scheduler!r} refused this client's certificate ({reason}): give a "
                         "--tls-cert signed by the CA the scheduler trusts (its --tls-ca-file).") from None
    except OSError as exc:
        raise InputError(f"The TLS handshake with the scheduler {scheduler!r} failed: {exc}. Is it a tls:// Dask "
                         "scheduler?") from None
    finally:
        raw.close()


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
