"""The ``--tls-ca-file/--tls-cert/--tls-key`` options of the commands that can use an existing Dask scheduler.

Defined once for ``skyloc serve`` and ``skyloc campaign``: the credentials are for ``--scheduler``
only (a LocalCluster generates its own), and a CA needs a client certificate.
"""
from __future__ import annotations

from pathlib import Path

import click

_PEM = click.Path(dir_okay=False, exists=True, path_type=Path)


def tls_client_options(f):
    """Add the three TLS options (PEM files) to a click command."""
    f = click.option("--tls-key", default=None, type=_PEM,
                     help="The key of --tls-cert (PEM), unless appended to it.")(f)
    f = click.option("--tls-cert", default=None, type=_PEM,
                     help="Client certificate (PEM) for the --scheduler's cluster.")(f)
    return click.option("--tls-ca-file", default=None, type=_PEM,
                        help="CA certificate (PEM) of the --scheduler's cluster.")(f)


def check_tls_options(scheduler: str | None, tls_ca_file: Path | None, tls_cert: Path | None,
                      tls_key: Path | None) -> bool:
    """Refuse contradictory TLS options (click.BadParameter naming the fix); True when some were given."""
    given = bool(tls_ca_file or tls_cert or tls_key)
    if given and not scheduler:
        raise click.BadParameter("--tls-ca-file/--tls-cert/--tls-key are for a --scheduler: the LocalCluster "
                                 "generates its own credentials", param_hint="--tls-cert")
    if tls_ca_file and not tls_cert:
        raise click.BadParameter("give --tls-cert (and --tls-key) with --tls-ca-file", param_hint="--tls-cert")
    if tls_cert and not tls_ca_file:
        raise click.BadParameter("give --tls-ca-file (the cluster's CA) with --tls-cert", param_hint="--tls-ca-file")
    return given
