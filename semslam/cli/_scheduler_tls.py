"""``--tls-ca-file --tls-cert --tls-key`` of the commands that take ``--scheduler`` (``batch``, ``montecarlo``), as
``dask scheduler`` takes them; the command runs its work inside
:func:`semslam.batch.engine.scheduler_tls`. Pure argparse: building the parser imports nothing else."""

from __future__ import annotations


def add_tls_options(parser) -> None:
    """The three options on ``parser`` (which has ``--scheduler``)."""
    parser.add_argument("--tls-ca-file", metavar="PEM", help="with a tls:// --scheduler: the CA certificate(s) that "
                        "signed the scheduler's and workers' certificates (PEM; default: Dask's config)")
    parser.add_argument("--tls-cert", metavar="PEM", help="with a tls:// --scheduler: this client's certificate, "
                        "signed by that CA (PEM; may hold the key too)")
    parser.add_argument("--tls-key", metavar="PEM", help="with a tls:// --scheduler: this client's private key (PEM)")
