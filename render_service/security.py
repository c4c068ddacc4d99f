"""Bearer-token authentication of the render service.

The token comes from ``SKYLOC_TOKEN`` or a token file; a server listening on a non-loopback
interface refuses to start without one.  Tokens are compared in constant time and never logged
(they live in :class:`pydantic.SecretStr` until the comparison).
"""
from __future__ import annotations

import base64
import binascii
import hmac
import ipaddress
import json
import logging
from pathlib import Path

from fastapi import HTTPException, Request

from board.errors import InvalidInputError
from render_service.settings import ServiceSettings

log = logging.getLogger(__name__)

#: Challenges sent with 401: Bearer for the API, Basic (any user name, the token as password) for the
#: HTML page so that a browser asks for it (browsers do not parse several challenges in one header).
API_CHALLENGE = 'Bearer realm="skyloc"'
PAGE_CHALLENGE = 'Basic realm="skyloc", charset="UTF-8"'


def is_loopback(host: str) -> bool:
    """True when ``host`` (name or address) only accepts connections from this machine."""
    if host.strip().lower() in ("localhost", "localhost.localdomain"):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def load_token(settings: ServiceSettings) -> str | None:
    """The configured token: ``SKYLOC_TOKEN`` / ``settings.token`` first, else the token file's first line.

    Raises InvalidInputError when the token file is unreadable or empty.
    """
    if settings.token is not None and settings.token.get_secret_value().strip():
        return settings.token.get_secret_value().strip()
    if settings.token_file is not None:
        path = Path(settings.token_file)
        try:
            lines = path.read_text().splitlines()
        except OSError as exc:
            raise InvalidInputError(f"cannot read the token file {path} ({exc.strerror}); "
                                    "give a readable file whose first line is the token") from None
        token = lines[0].strip() if lines else ""
        if not token:
            raise InvalidInputError(f"the token file {path} is empty: write the token on its first line")
        return token
    return None


def check_startup(settings: ServiceSettings, token: str | None) -> None:
    """Refuse to serve a non-loopback interface without a token (InvalidInputError)."""
    if token is None and not is_loopback(settings.host):
        raise InvalidInputError(
            f"refusing to listen on {settings.host} without authentication: set SKYLOC_TOKEN or pass "
            "--token-file FILE, or listen on 127.0.0.1")
    if token is not None and len(token) < 16:
        raise InvalidInputError("the token is too short: use at least 16 random characters "
                                "(e.g. `python -c 'import secrets; print(secrets.token_urlsafe(32))'`)")
    if token is None:
        log.warning("no token configured: the API is open to every local user of this machine")


def token_from_header(header: str) -> str | None:
    """The token an ``Authorization`` header's value carries (Bearer, or the Basic password), else None."""
    scheme, _, value = header.partition(" ")
    scheme = scheme.lower()
    if scheme == "bearer":
        return value.strip()
    if scheme == "basic":
        try:
            decoded = base64.b64decode(value.strip(), validate=True).decode("utf-8")
        except (binascii.Error, UnicodeDecodeError):
            return None
        return decoded.partition(":")[2]
    return None


def _presented_token(request: Request) -> str | None:
    return token_from_header(request.headers.get("authorization", ""))


#: Paths served without a token: liveness, the API schema and its documentation pages and their assets.
PUBLIC_PATHS = frozenset({"/healthz", "/openapi.json", "/docs", "/docs/oauth2-redirect", "/redoc"})
PUBLIC_PREFIXES = ("/docs-assets/",)


class TokenAuth:
    """FastAPI dependency: 401 unless the request carries the token (Bearer, or Basic password)."""

    def __init__(self, token: str | None) -> None:
        self._token = token.encode("utf-8") if token is not None else None

    @property
    def enabled(self) -> bool:
        return self._token is not None

    def refusal(self, authorization: str, path: str) -> tuple[str, dict[str, str]] | None:
        """None when ``authorization`` (the header's value) carries the token, else (reason, headers)."""
        if self._token is None:
            return None
        given = token_from_header(authorization)
        challenge = {"WWW-Authenticate": PAGE_CHALLENGE if path == "/" else API_CHALLENGE}
        if given is None:
            return "missing credentials: send 'Authorization: Bearer <token>'", challenge
        if not hmac.compare_digest(given.encode("utf-8"), self._token):
            return "invalid token: send the token the server was started with", challenge
        return None

    def __call__(self, request: Request) -> None:
        refused = self.refusal(request.headers.get("authorization", ""), request.url.path)
        if refused is not None:
            raise HTTPException(401, refused[0], headers=refused[1])


class TokenGateMiddleware:
    """Pure ASGI middleware: the token is checked on the request's headers, before any body is received.

    A request without the token gets its 401 at once and its body is never read (the server closes the
    connection rather than drain it), so an unauthenticated upload writes nothing anywhere.  The
    public paths (:data:`PUBLIC_PATHS`) pass; the route dependency (:class:`TokenAuth`) checks again.
    """

    def __init__(self, app, *, auth: TokenAuth) -> None:
        self.app = app
        self.auth = auth

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or not self.auth.enabled:
            return await self.app(scope, receive, send)
        path = scope.get("path", "")
        if path in PUBLIC_PATHS or path.startswith(PUBLIC_PREFIXES):
            return await self.app(scope, receive, send)
        header = b""
        for k, v in scope.get("headers") or ():
            if k == b"authorization":
                header = v
                break
        refused = self.auth.refusal(header.decode("latin-1"), path)
        if refused is None:
            return await self.app(scope, receive, send)
        body = json.dumps({"detail": refused[0], "code": "unauthorized"}).encode()
        headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                   (b"connection", b"close")]
        headers += [(k.lower().encode(), v.encode()) for k, v in refused[1].items()]
        await send({"type": "http.response.start", "status": 401, "headers": headers})
        await send({"type": "http.response.body", "body": body})
