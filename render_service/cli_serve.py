"""``skyloc serve``: run the render service (uvicorn) on a LocalCluster or an existing Dask scheduler."""
from __future__ import annotations

import logging
from pathlib import Path

import click

from render_service.cli_tls import check_tls_options, tls_client_options

log = logging.getLogger(__name__)


@click.command("serve")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Interface to listen on; anything but loopback needs a token.")
@click.option("--port", default=8000, show_default=True, type=click.IntRange(0, 65535))
@click.option("--data", "data_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder for the job store, DEMs, jobs and results (created if missing).")
@click.option("--scheduler", default=None,
              help="Dask scheduler address (tls://host:8786) instead of a LocalCluster; its credentials come from "
                   "--tls-ca-file/--tls-cert/--tls-key or Dask's security config (distributed.comm.tls.*). "
                   "The default LocalCluster uses mutual TLS with credentials generated in DATA/.dask-tls.")
@tls_client_options
@click.option("--dashboard", default=None, metavar="127.0.0.1:PORT",
              help="Serve the LocalCluster's Dask dashboard on this loopback address (none by default).")
@click.option("--workers", "n_workers", default=None, type=click.IntRange(1, 256),
              help="LocalCluster worker processes (one thread each).  [default: 2]")
@click.option("--token-file", default=None, type=click.Path(dir_okay=False, exists=True, path_type=Path),
              help="File whose first line is the bearer token (else SKYLOC_TOKEN).")
@click.option("--log-level", default="info", show_default=True,
              type=click.Choice(["critical", "error", "warning", "info", "debug"]))
def serve(host: str, port: int, data_dir: Path, scheduler: str | None, tls_ca_file: Path | None,
          tls_cert: Path | None, tls_key: Path | None, dashboard: str | None, n_workers: int | None,
          token_file: Path | None, log_level: str) -> None:
    """Run the render service: REST queue for skyline databases on Dask (API docs at /docs)."""
    import uvicorn  # noqa: PLC0415

    from render_service.main import create_app  # noqa: PLC0415
    from render_service.settings import ServiceSettings  # noqa: PLC0415

    check_tls_options(scheduler, tls_ca_file, tls_cert, tls_key)
    overrides = {"host": host, "port": port, "data_dir": data_dir, "scheduler": scheduler, "token_file": token_file,
                 "tls_ca_file": tls_ca_file, "tls_cert": tls_cert, "tls_key": tls_key, "dashboard": dashboard}
    if n_workers is not None:
        overrides["n_workers"] = n_workers
    settings = ServiceSettings(**{k: v for k, v in overrides.items() if v is not None})
    logging.getLogger("render_service").setLevel(log_level.upper())
    app = create_app(settings)  # refuses a non-loopback host without a token (SkylocError -> exit 1)
    click.echo(f"skyloc render service on http://{host}:{port} (data {data_dir}); Ctrl-C stops it", err=True)
    uvicorn.run(app, host=host, port=port, log_level=log_level, access_log=log_level == "debug",
                timeout_graceful_shutdown=10)


def register(group: click.Group) -> None:
    """Add ``serve`` to the root ``skyloc`` group."""
    group.add_command(serve)
