"""``--scheduler tls://...`` (semslam.batch.engine, docs/batch.md): a real ``dask scheduler`` and ``dask worker``
with TLS on 127.0.0.1, certificates made here by ``openssl`` (a CA, and one signed certificate for the scheduler,
the worker and the client; a second CA with its own certificate for a stranger). A batch runs through it from the
CLI, and tasks from Dask's TLS config; a client without the certificates, or with the stranger's, is refused with
a one-line error; every process is stopped by its PID and checked gone."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil
import pytest

from semslam.errors import InputError
from semslam.batch import engine as _dask
from semslam.batch.engine import dask_client, map_tasks, scheduler_security, scheduler_tls

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
DASK = BIN / "dask"

pytestmark = [pytest.mark.skipif(shutil.which("openssl") is None, reason="openssl (for certificates) not on PATH"),
              pytest.mark.skipif(not DASK.is_file(), reason=f"the dask CLI not found at {DASK}")]

LEAF_EXTENSIONS = ("basicConstraints=critical,CA:FALSE\nkeyUsage=critical,digitalSignature,keyEncipherment\n"
                   "extendedKeyUsage=serverAuth,clientAuth\nsubjectAltName=IP:127.0.0.1,DNS:localhost\n"
                   "subjectKeyIdentifier=hash\nauthorityKeyIdentifier=keyid\n")


def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=30)


def make_ca_and_cert(folder: Path, name: str) -> dict:
    """A CA (EC P-256, 1 day) and one certificate + key it signed for 127.0.0.1 (server and client use)."""
    folder.mkdir(parents=True)
    ec = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes")
    _openssl("req", "-x509", *ec, "-keyout", "ca.key", "-out", "ca.pem", "-days", "1", "-subj", f"/CN={name} CA",
             "-addext", "basicConstraints=critical,CA:TRUE", "-addext", "keyUsage=critical,keyCertSign,cRLSign",
             "-addext", "subjectKeyIdentifier=hash", cwd=folder)
    _openssl("req", *ec, "-keyout", "node.key", "-out", "node.csr", "-subj", "/CN=127.0.0.1", cwd=folder)
    (folder / "leaf.cnf").write_text(LEAF_EXTENSIONS)
    _openssl("x509", "-req", "-in", "node.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
             "-out", "node.pem", "-days", "1", "-extfile", "leaf.cnf", cwd=folder)
    for f in ("ca.key", "node.key"):
        (folder / f).chmod(0o600)
    return {"ca": str(folder / "ca.pem"), "cert": str(folder / "node.pem"), "key": str(folder / "node.key")}


def tls_args(c: dict) -> list:
    return ["--tls-ca-file", c["ca"], "--tls-cert", c["cert"], "--tls-key", c["key"]]


def _stop(procs: list) -> None:
    """SIGTERM each process by its PID, the worker first (it closes at once while its scheduler is up), then
    SIGKILL it if still there after 10 s; reaped."""
    for p in reversed(procs):
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=10)


@pytest.fixture(scope="module")
def tls_cluster(tmp_path_factory):
    """``(address, certificates, stranger's certificates, [scheduler, worker] Popen)`` of a TLS scheduler with one
    worker (1 thread, no nanny: one process each), listening on 127.0.0.1 only; both stopped by PID at the end,
    and checked gone with their children."""
    root = tmp_path_factory.mktemp("tls")
    good = make_ca_and_cert(root / "good", "semslam test")
    other = make_ca_and_cert(root / "other", "stranger")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    sched_file = root / "scheduler.json"
    procs: list = []
    logs = [open(root / "scheduler.log", "wb"), open(root / "worker.log", "wb")]
    try:
        procs.append(subprocess.Popen(
            [str(DASK), "scheduler", "--host", "127.0.0.1", "--port", "0", "--protocol", "tls", *tls_args(good),
             "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(sched_file),
             "--idle-timeout", "600"],  # a safety net: gone 10 min after its last task should this process die
            cwd=root, env=env, stdout=logs[0], stderr=subprocess.STDOUT))
        address = _scheduler_address(sched_file, procs[0], root / "scheduler.log")
        assert address.startswith("tls://127.0.0.1:")
        procs.append(subprocess.Popen(
            [str(DASK), "worker", address, *tls_args(good), "--host", "127.0.0.1", "--nthreads", "1",
             "--no-nanny", "--no-dashboard", "--local-directory", str(root / "worker-space"),
             "--death-timeout", "60"],
            cwd=ROOT, env=env, stdout=logs[1], stderr=subprocess.STDOUT))
        with scheduler_tls(address, good["ca"], good["cert"], good["key"]), dask_client(address) as client:
            client.wait_for_workers(1, timeout=90)
        yield address, good, other, procs
    finally:
        family = [q for p in procs if psutil.pid_exists(p.pid) for q in _family(p.pid)]
        _stop(procs)
        for f in logs:
            f.close()
        gone, alive = psutil.wait_procs(family, timeout=15)
        for q in alive:  # pragma: no cover - only if dask leaves a child behind; the assertion below reports it
            q.kill()
        assert not alive, f"processes left behind: {alive}"


def _scheduler_address(sched_file: Path, proc: subprocess.Popen, log: Path, timeout_s: float = 60.0) -> str:
    """The address the scheduler wrote to its ``--scheduler-file`` (read until it parses: it may be half-written)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            return json.loads(sched_file.read_text())["address"]
        except (OSError, ValueError, KeyError):
            time.sleep(0.2)
    raise AssertionError(f"the TLS scheduler did not start: {log.read_text()[-2000:]}")


def _family(pid: int) -> list:
    try:
        p = psutil.Process(pid)
        return [p, *p.children(recursive=True)]
    except psutil.NoSuchProcess:
        return []


def test_batch_on_a_tls_scheduler_gives_the_serial_summary(tls_cluster, tmp_path, capsys):
    """``semslam batch --scheduler tls://... --tls-*``: each dive runs on the TLS worker and its row comes back, in
    order; the rows and summary are the serial batch's. (Dives that fail at once, a corrupt and an empty mission:
    a real dive takes minutes.)"""
    from semslam.cli.main import main
    from semslam.batch.dives import SUMMARY_CSV, SUMMARY_MD

    address, good, _other, procs = tls_cluster
    corrupt, empty = tmp_path / "dives" / "corrupt", tmp_path / "dives" / "empty"
    corrupt.mkdir(parents=True)
    empty.mkdir()
    (corrupt / "mission.json").write_text("{ not json", encoding="utf-8")
    batch = ["batch", str(corrupt), str(empty), "--db", "builtin", "--json"]
    capsys.readouterr()
    assert main([*batch, "--out", str(tmp_path / "tls"), "--scheduler", address, *tls_args(good)]) == 1
    rows = json.loads(capsys.readouterr().out)["dives"]
    assert [r["dive"] for r in rows] == ["corrupt", "empty"] and all(r["status"] == "failed" for r in rows)
    assert rows[0]["error"] and rows[1]["error"] and rows[0]["error"] != rows[1]["error"]
    assert main([*batch, "--out", str(tmp_path / "serial"), "--workers", "1"]) == 1
    assert json.loads(capsys.readouterr().out)["dives"] == rows
    for name in (SUMMARY_CSV, SUMMARY_MD):
        assert (tmp_path / "tls" / name).read_bytes() == (tmp_path / "serial" / name).read_bytes(), name
    assert all(p.poll() is None for p in procs)  # the cluster is still up: the errors were the dives' own


def test_dask_config_certificates_serve_the_library(tls_cluster):
    """Dask's ``distributed.comm.tls.*`` config is enough for ``map_tasks`` (so ``run_batch(scheduler=...)``,
    ``db build --scheduler``); the client's Security requires encryption."""
    import dask.config
    import distributed  # noqa: F401  (its config defaults before the override, which must not hide them)

    address, good, _other, _procs = tls_cluster
    with dask.config.set({"distributed.comm.tls.ca-file": good["ca"], "distributed.comm.tls.client.cert": good["cert"],
                          "distributed.comm.tls.client.key": good["key"]}):
        security = scheduler_security(address)
        assert security.require_encryption and security.tls_client_cert == good["cert"]
        assert map_tasks(abs, [-3, 1, -2], scheduler=address) == [3, 1, 2]
    assert scheduler_security("tcp://127.0.0.1:8786") is None


def test_client_without_certificates_is_refused(tls_cluster, capsys, monkeypatch):
    """No certificates: a one-line error naming the missing options; and the scheduler itself refuses a TLS client
    that shows no certificate, and a plain tcp:// client."""
    from distributed import Security

    from semslam.cli.main import main

    address, good, _other, _procs = tls_cluster
    mc = ["montecarlo", "--runs", "1", "--mode", "dr", "--source", "synthetic", "--loops", "1"]
    assert main([*mc, "--scheduler", address]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is a TLS scheduler: give --tls-ca-file and --tls-cert" in err[0]
    assert main([*mc, "--scheduler", address, "--tls-ca-file", good["ca"]]) == 1
    assert "give --tls-cert" in capsys.readouterr().err

    no_cert = Security(require_encryption=True, tls_ca_file=good["ca"])
    t0 = time.monotonic()
    with pytest.raises(InputError, match="refused this client's certificate .*certificate required"):
        _dask._check_handshake(address, no_cert)
    assert time.monotonic() - t0 < 5  # refused at once, not after a time-out

    monkeypatch.setattr(_dask, "CONNECT_TIMEOUT", "2s")
    assert main([*mc, "--scheduler", address.replace("tls://", "tcp://")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Could not connect to 'tcp://127.0.0.1:" in err[0]


def test_certificate_from_another_ca_is_refused(tls_cluster, capsys):
    """The stranger's CA does not trust the scheduler; the scheduler does not trust the stranger's certificate;
    both are one-line errors within a second or so."""
    from semslam.cli.main import main

    address, good, other, procs = tls_cluster
    mc = ["montecarlo", "--runs", "1", "--mode", "dr", "--source", "synthetic", "--loops", "1"]
    t0 = time.monotonic()
    assert main([*mc, "--scheduler", address, *tls_args(other)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "its certificate is not signed by the CA of --tls-ca-file" in err[0]
    stranger = ["--tls-ca-file", good["ca"], "--tls-cert", other["cert"], "--tls-key", other["key"]]
    assert main([*mc, "--scheduler", address, *stranger]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "refused this client's certificate (tlsv1 alert unknown ca)" in err[0]
    assert time.monotonic() - t0 < 10
    assert all(p.poll() is None for p in procs)


def test_bad_certificate_options_are_one_line_errors(tmp_path, capsys):
    """Missing, non-file and non-PEM files, a key of another certificate, and --tls-* without a tls:// scheduler:
    one line each, naming the option and the file, before anything connects (port 9 is not listening)."""
    from semslam.cli.main import main

    good = make_ca_and_cert(tmp_path / "good", "a")
    other = make_ca_and_cert(tmp_path / "other", "b")
    text = tmp_path / "notes.txt"
    text.write_text("not a certificate\n")
    base = ["montecarlo", "--runs", "1", "--mode", "dr", "--source", "synthetic", "--loops", "1"]
    sched = ["--scheduler", "tls://127.0.0.1:9"]
    cases = [
        ([*sched, "--tls-ca-file", str(tmp_path / "nope.pem"), "--tls-cert", good["cert"], "--tls-key", good["key"]],
         "'--tls-ca-file' option must be a PEM CA certificate file .*nope.pem', which does not exist"),
        ([*sched, "--tls-ca-file", good["ca"], "--tls-cert", str(tmp_path), "--tls-key", good["key"]],
         "'--tls-cert' option must be a PEM client certificate file .* which is not a file"),
        ([*sched, "--tls-ca-file", str(text), "--tls-cert", good["cert"], "--tls-key", good["key"]],
         "'--tls-ca-file' option must be a PEM CA certificate .*notes.txt', which holds none"),
        ([*sched, "--tls-ca-file", good["ca"], "--tls-cert", good["cert"]],
         "'--tls-cert' option must hold a PEM private key .*give --tls-key"),
        ([*sched, "--tls-ca-file", good["ca"], "--tls-cert", good["cert"], "--tls-key", other["key"]],
         "must be a matching PEM pair. .*key values mismatch"),
        (["--scheduler", "tcp://127.0.0.1:9", *tls_args(good)],
         r"--tls-\* options \('--tls-ca-file', '--tls-cert', '--tls-key'\) need a tls:// '--scheduler'"),
        (["--tls-cert", good["cert"]], "need a tls:// '--scheduler'. Got no --scheduler"),
        ([*sched, *tls_args(good)], "Could not connect to 'tls://127.0.0.1:9'"),
    ]
    big = tmp_path / "big.pem"
    big.write_bytes(b"-----BEGIN CERTIFICATE-----\n" + b"A" * (1 << 20))
    cases.append(([*sched, "--tls-ca-file", str(big), "--tls-cert", good["cert"], "--tls-key", good["key"]],
                  "big.pem', which is larger than 1048576 bytes"))
    if os.geteuid() != 0:  # root reads any file
        locked = tmp_path / "locked.pem"
        shutil.copy(good["ca"], locked)
        locked.chmod(0)
        cases.append(([*sched, "--tls-ca-file", str(locked), "--tls-cert", good["cert"], "--tls-key", good["key"]],
                      "locked.pem', which cannot be read: Permission denied"))
    for extra, pattern in cases:
        assert main([*base, *extra]) == 1, extra
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and re.search(pattern, err[0]), (pattern, err)


def test_tls_address_of_something_else_is_a_clear_error(tmp_path):
    """A tls:// address whose server does not speak TLS (e.g. a tcp:// scheduler, which talks first), or says
    nothing: an error naming it, within the handshake's time limit; a port out of range."""
    good = make_ca_and_cert(tmp_path / "good", "a")
    for greeting, pattern in ((b"plain bytes, not TLS" * 10, r"failed \(.*\): is it a tls:// Dask scheduler\?"),
                              (None, "handshake with the scheduler .* failed: .*timed out")):
        with socket.create_server(("127.0.0.1", 0)) as server:
            address = f"tls://127.0.0.1:{server.getsockname()[1]}"
            thread = threading.Thread(target=_serve_once, args=(server, greeting), daemon=True)
            thread.start()
            with scheduler_tls(address, good["ca"], good["cert"], good["key"]):
                security = scheduler_security(address)
            t0 = time.monotonic()
            with pytest.raises(InputError, match=pattern):
                _dask._check_handshake(address, security, timeout_s=1.0)
            assert time.monotonic() - t0 < 4
            thread.join(timeout=10)
    with pytest.raises(InputError, match="must be an address like tls://host:8786.*port 99999 is not in 1-65535"):
        _dask._check_handshake("tls://127.0.0.1:99999", security)


def _serve_once(server: socket.socket, greeting: bytes | None) -> None:
    """Accept one connection; send ``greeting`` (None: nothing) and hold it open until the client hangs up."""
    server.settimeout(30)
    conn, _ = server.accept()
    with conn:
        conn.settimeout(3)
        if greeting is not None:
            conn.sendall(greeting)
        try:
            while conn.recv(4096):
                pass
        except OSError:
            pass


def test_tcp_scheduler_refused_when_dask_config_requires_encryption():
    import dask.config
    import distributed  # noqa: F401  (its config defaults before the override, which must not hide them)

    with dask.config.set({"distributed.comm.require-encryption": True}):
        with pytest.raises(InputError, match="must be a tls:// address: Dask's config requires encryption"):
            scheduler_security("tcp://127.0.0.1:8786")
