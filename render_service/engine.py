"""The ground segment's Dask engine: one place that starts (or connects to) the cluster.

Everything that farms work to Dask -- the render service's job runner, ``skyloc campaign``,
``skyloc sim descent-set``, ``skyloc descent eval`` -- gets its client from :func:`dask_client`,
so that the cluster's security is defined once:

* a LocalCluster (``scheduler`` None) listens on ``tls://127.0.0.1`` only, with mutual TLS and a
  certificate and key generated for it (:mod:`render_service.dask_tls`) in a folder only this user
  can read: a fresh temporary one per call, or ``tls_dir`` (the render service uses
  ``DATA/.dask-tls``).  A local user without the key cannot connect, so cannot run code on the
  workers or read the data through them;
* no dashboard (scheduler or workers) unless ``dashboard`` names one, and then only on a loopback
  address and behind ``dashboard_token`` (every route, page and websocket answers 401 without it:
  :mod:`render_service.dashboard_auth`); workers never serve HTTP routes;
* an existing scheduler (``scheduler="tls://host:8786"``) is reached with ``security`` (see
  :func:`security_from_files`, the ``--tls-ca-file/--tls-cert/--tls-key`` options) or, when None, with
  Dask's own configuration (``distributed.comm.tls.*``, e.g. a ``~/.config/dask/*.yaml`` security
  file).  A ``tcp://`` scheduler is unauthenticated: connecting to one logs a warning.

Use::

    with dask_client(scheduler=None, n_workers=2) as client:
        futures = client.map(task, items)
"""
from __future__ import annotations

import logging
import os
import shutil
import sys
import tempfile
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import Iterator

from board.errors import InvalidInputError

log = logging.getLogger(__name__)


def security_from_files(*, ca_file: str | os.PathLike, cert_file: str | os.PathLike,
                        key_file: str | os.PathLike | None = None):
    """A mutual-TLS ``Security`` for connecting a client to an existing ``tls://`` scheduler.

    ca_file : PEM of the CA the cluster's certificates are signed by
    cert_file, key_file : this client's certificate and key (PEM; the key may be appended to the cert)
    Raises InvalidInputError naming a file that cannot be read.
    """
    from distributed.security import Security  # noqa: PLC0415

    for what, f in (("--tls-ca-file", ca_file), ("--tls-cert", cert_file), ("--tls-key", key_file)):
        if f is not None and not os.access(f, os.R_OK):
            raise InvalidInputError(f"cannot read {what} {f}: give a readable PEM file")
    kw = {"tls_client_key": str(key_file)} if key_file is not None else {}
    return Security(require_encryption=True, tls_ca_file=str(ca_file), tls_client_cert=str(cert_file), **kw)


def check_dashboard_address(address: str | None) -> str | None:
    """``address`` if it is a loopback ``host:port`` (or None); InvalidInputError otherwise."""
    if address is None:
        return None
    from render_service.security import is_loopback  # noqa: PLC0415

    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit() or not is_loopback(host or ""):
        raise InvalidInputError(f"dashboard address {address!r} is not allowed: give a loopback host:port "
                                "such as 127.0.0.1:8787 (the dashboard can run code-free views of every task, "
                                "so it is never served on a public interface)")
    return address


def _http_config(dashboard: str | None):
    """Dask's HTTP routes for a LocalCluster: none without a dashboard.

    A Dask scheduler always listens for HTTP (8787 by default) with routes that answer its address
    (``/json/identity.json``), metrics and a proxy to the workers, even with ``dashboard=False``:
    without a dashboard it is moved to a random loopback port and given no route at all.
    """
    import dask  # noqa: PLC0415

    if dashboard:
        return dask.config.set({"distributed.worker.http.routes": []})
    return dask.config.set({"distributed.scheduler.http.routes": [], "distributed.worker.http.routes": []})


@contextmanager
def dask_client(scheduler: str | None = None, *, n_workers: int = 2, threads_per_worker: int = 1,
                processes: bool = True, security=None, dashboard: str | None = None,
                dashboard_token: str | None = None, timeout_s: float = 30.0,
                tls_dir: str | os.PathLike | None = None) -> Iterator["object"]:
    """A ``distributed.Client`` on a new TLS LocalCluster (``scheduler`` None) or on ``scheduler``.

    scheduler : address of an existing scheduler (``tls://host:8786``); None starts a LocalCluster
        bound to 127.0.0.1 with ``n_workers`` worker processes of ``threads_per_worker`` threads
    security : a ``distributed.security.Security``; None: generated credentials for a LocalCluster,
        Dask's configuration for an existing scheduler
    dashboard : a loopback dashboard address to serve (e.g. ``127.0.0.1:8787``); None serves none
    dashboard_token : the token every dashboard request must carry (Bearer, or the Basic password);
        required with ``dashboard`` (InvalidInputError without it)
    tls_dir : where a LocalCluster's credentials are written (None: a temporary folder, removed on exit)
    The cluster (if started here) and the client are closed on exit.
    """
    from distributed import Client, LocalCluster  # noqa: PLC0415 (heavy; ground segment only)

    cluster = None
    tmp_dir = None
    if scheduler:
        if scheduler.startswith("tcp://") and security is None:
            log.warning("the Dask scheduler %s is unencrypted and unauthenticated: anyone who can reach it can run "
                        "code on its workers; use a tls:// scheduler with --tls-ca-file/--tls-cert/--tls-key",
                        scheduler)
        log.info("connecting to the Dask scheduler %s", scheduler)
        client = Client(scheduler, timeout=timeout_s, security=security)
    else:
        dashboard = check_dashboard_address(dashboard)
        if dashboard and not dashboard_token:
            raise InvalidInputError("the Dask dashboard is only served behind a token: set SKYLOC_TOKEN or "
                                    "--token-file, or start without --dashboard")
        if security is None:
            from render_service.dask_tls import generate_tls_files  # noqa: PLC0415

            if tls_dir is None:
                tmp_dir = tempfile.mkdtemp(prefix="skyloc-dask-tls-")  # mode 0700
            security = generate_tls_files(Path(tls_dir or tmp_dir)).security()
        try:
            if dashboard:
                from render_service.dashboard_auth import gated_dashboard  # noqa: PLC0415

                gate = gated_dashboard(dashboard_token)
            else:
                gate = nullcontext()
            with _http_config(dashboard), gate, _without_blender_paths():
                cluster = LocalCluster(n_workers=n_workers, threads_per_worker=threads_per_worker,
                                       processes=processes, host="127.0.0.1", scheduler_port=0, protocol="tls://",
                                       security=security, dashboard_address=dashboard, worker_dashboard_address=None,
                                       scheduler_kwargs=None if dashboard else {"dashboard_address": "127.0.0.1:0"},
                                       silence_logs=logging.WARNING)
            if dashboard:
                from render_service.dashboard_auth import assert_gated  # noqa: PLC0415

                assert_gated(cluster.scheduler)
            client = Client(cluster, security=security, timeout=timeout_s)
        except BaseException:
            if cluster is not None:
                cluster.close(timeout=10)
            if tmp_dir is not None:
                shutil.rmtree(tmp_dir, ignore_errors=True)
            raise
        log.info("started a TLS LocalCluster on %s: %d workers x %d thread(s), dashboard %s",
                 cluster.scheduler_address, n_workers, threads_per_worker, dashboard or "off")
    try:
        yield client
    finally:
        try:
            client.close(timeout=10)
            if cluster is not None:
                cluster.close(timeout=10)
        except Exception as exc:  # shutting down: report, do not raise
            log.warning("closing Dask: %s", exc)
        if tmp_dir is not None:
            shutil.rmtree(tmp_dir, ignore_errors=True)


@contextmanager
def _without_blender_paths() -> Iterator[None]:
    """``sys.path`` without the folders Blender's module adds once ``bpy`` is imported, while workers spawn.

    Spawned worker processes start from the parent's ``sys.path``; Blender's ``scripts/modules`` holds a
    ``bpy`` package that only works inside Blender (``No module named '_bpy'``), and it would shadow the
    real module in every worker of a process that had imported bpy (the demo, a script inside Blender).
    """
    bpy = sys.modules.get("bpy")
    if bpy is None or not getattr(bpy, "__file__", None):
        yield
        return
    f = os.path.abspath(bpy.__file__)  # .../site-packages/bpy/5.0/scripts/modules/bpy/__init__.py once loaded
    cut = f.find(f"{os.sep}bpy{os.sep}")
    roots = [f[:cut + 4] if cut >= 0 else os.path.dirname(f)]
    user = os.environ.get("BLENDER_USER_RESOURCES")
    if user:
        roots.append(os.path.abspath(user))
    saved = list(sys.path)

    def blender_scripts(p: str) -> bool:
        a = os.path.abspath(p)
        return any(a.startswith(r + os.sep) and f"{os.sep}scripts" in a[len(r):] for r in roots)

    sys.path[:] = [p for p in sys.path if not blender_scripts(p)]
    try:
        yield
    finally:
        sys.path[:] = saved


def default_workers() -> int:
    """Worker processes for a LocalCluster on this machine (one per core, at least one)."""
    return max(1, os.cpu_count() or 1)
