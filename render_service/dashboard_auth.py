"""The Dask dashboard behind the service's token.

Dask serves its dashboard (Bokeh pages, their websockets, ``/json/*``, ``/metrics``, the worker proxy)
from one Tornado application per scheduler, a :class:`distributed.http.routing.RoutingApplication`.
Every request that application receives -- plain HTTP and websocket upgrades alike -- is routed
through its ``find_handler``.  :func:`token_gated_application` makes a subclass whose ``find_handler``
answers 401 before any route (or Bokeh application) sees a request that does not carry the token,
exactly as the REST API wants it: ``Authorization: Bearer <token>``, or HTTP Basic with the token as
the password (what a browser sends after its login prompt, also on the pages' websockets and XHRs).

:func:`gated_dashboard` swaps that subclass in while a LocalCluster starts, so the dashboard never
answers one unauthenticated request, even during start-up; :func:`assert_gated` checks afterwards
that the scheduler really uses it (a Dask release that builds its HTTP server differently makes the
start fail rather than serve an open dashboard).
"""
from __future__ import annotations

import hmac
import threading
from contextlib import contextmanager
from typing import Iterator

from board.errors import InvalidInputError

#: the browser prompt's challenge (any user name, the token as password), as on the service's status page
DASHBOARD_CHALLENGE = 'Basic realm="skyloc dask dashboard", charset="UTF-8"'

_swap_lock = threading.Lock()


def token_gated_application(token: str) -> type:
    """A ``RoutingApplication`` subclass that refuses (401) every request without ``token``."""
    from distributed.http.routing import RoutingApplication  # noqa: PLC0415
    from tornado import web  # noqa: PLC0415 (ground segment only)

    from render_service.security import token_from_header  # noqa: PLC0415

    if not token:
        raise InvalidInputError("the Dask dashboard needs the service's token: set SKYLOC_TOKEN or --token-file")
    secret = token.encode("utf-8")

    @web.stream_request_body
    class Refused(web.RequestHandler):
        """401 for every method, sent as soon as the headers are in: a request body is never buffered."""

        def initialize(self, reason: str) -> None:  # noqa: D401 (tornado hook)
            self.reason = reason

        def prepare(self) -> None:
            self.set_status(401)
            self.set_header("WWW-Authenticate", DASHBOARD_CHALLENGE)
            self.set_header("Content-Type", "text/plain; charset=utf-8")
            self.set_header("Cache-Control", "no-store")
            self.finish(self.reason + "\n")

        def data_received(self, chunk: bytes) -> None:  # a body sent anyway is dropped, never stored
            pass

    class TokenGatedRoutingApplication(RoutingApplication):
        skyloc_token_gated = True

        def find_handler(self, request, **kwargs):  # type: ignore[no-untyped-def]
            given = token_from_header(request.headers.get("Authorization", ""))
            if given is None:
                reason = "missing credentials: send 'Authorization: Bearer <token>' (or the token as Basic password)"
            elif not hmac.compare_digest(given.encode("utf-8"), secret):
                reason = "invalid token: send the token the server was started with"
            else:
                return super().find_handler(request, **kwargs)
            return self.get_handler_delegate(request, Refused, target_kwargs={"reason": reason})

    return TokenGatedRoutingApplication


@contextmanager
def gated_dashboard(token: str) -> Iterator[None]:
    """While inside, every Dask server started in this process builds its HTTP app behind ``token``.

    Start the LocalCluster inside (its scheduler runs in this process); workers in other processes are
    not affected (the engine gives them no HTTP routes at all).
    """
    import distributed.node as node  # noqa: PLC0415

    gated = token_gated_application(token)
    with _swap_lock:
        original = node.RoutingApplication
        node.RoutingApplication = gated
        try:
            yield
        finally:
            node.RoutingApplication = original


def assert_gated(scheduler) -> None:
    """RuntimeError unless ``scheduler``'s HTTP application is the token-gated one."""
    app = getattr(scheduler, "http_application", None)
    if not getattr(app, "skyloc_token_gated", False):
        raise RuntimeError("the Dask dashboard could not be put behind the token (this Dask release builds its "
                           "HTTP server differently); start without --dashboard")
