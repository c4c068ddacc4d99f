"""The ground segment's Dask engine: one place that starts (or connects to) the cluster.

Everything that farms work to Dask -- the render service's job runner, ``skyloc campaign``,
``skyloc sim descent-set``, ``skyloc descent eval`` -- gets its client from :func:`dask_client`,
so that the cluster's security settings (loopback only, no dashboard unless asked for, and the
credentials of :mod:`render_service.security` when they are configured) are defined once.

Use::

    with dask_client(scheduler=None, n_workers=2) as client:
        futures = client.map(task, items)
"""
from __future__ import annotations

import logging
import os
from contextlib import contextmanager
from typing import Iterator

log = logging.getLogger(__name__)


@contextmanager
def dask_client(scheduler: str | None = None, *, n_workers: int = 2, threads_per_worker: int = 1,
                processes: bool = True, security=None, dashboard: str | None = None,
                timeout_s: float = 30.0) -> Iterator["object"]:
    """A ``distributed.Client`` on a new LocalCluster (``scheduler`` None) or on ``scheduler``.

    scheduler : address of an existing scheduler (``tls://host:8786``); None starts a LocalCluster
        bound to 127.0.0.1 with ``n_workers`` worker processes of ``threads_per_worker`` threads
    security : a ``distributed.security.Security`` for the connection (and the LocalCluster)
    dashboard : the dashboard address to serve (e.g. ``127.0.0.1:8787``); None serves none
    The cluster (if started here) and the client are closed on exit.
    """
    from distributed import Client, LocalCluster  # noqa: PLC0415 (heavy; ground segment only)

    cluster = None
    if scheduler:
        log.info("connecting to the Dask scheduler %s", scheduler)
        client = Client(scheduler, timeout=timeout_s, security=security)
    else:
        kw = {} if security is None else {"security": security}
        cluster = LocalCluster(n_workers=n_workers, threads_per_worker=threads_per_worker, processes=processes,
                               host="127.0.0.1", scheduler_port=0, dashboard_address=dashboard,
                               silence_logs=logging.WARNING, **kw)
        client = Client(cluster, security=security)
        log.info("started a LocalCluster: %d workers x %d thread(s)", n_workers, threads_per_worker)
    try:
        yield client
    finally:
        try:
            client.close(timeout=10)
            if cluster is not None:
                cluster.close(timeout=10)
        except Exception as exc:  # shutting down: report, do not raise
            log.warning("closing Dask: %s", exc)


def default_workers() -> int:
    """Worker processes for a LocalCluster on this machine (one per core, at least one)."""
    return max(1, os.cpu_count() or 1)
