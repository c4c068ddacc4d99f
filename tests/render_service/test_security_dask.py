"""The Dask engine's LocalCluster is behind credentials: mutual TLS with a generated key only its user reads.

A real LocalCluster (one worker process) from :func:`render_service.engine.dask_client`; the attacker is
every way a local user could try to reach it: plain ``tcp://``, ``tls://`` without a certificate, with a
self-made certificate, a raw TLS socket, and the scheduler's HTTP port (which used to answer
``/json/identity.json`` with the scheduler's address).  The positive control runs code with the credentials.
"""
from __future__ import annotations

import os
import socket
import ssl
import stat
from pathlib import Path

import httpx
import pytest

from board.errors import InvalidInputError
from render_service.dask_tls import generate_tls_files
from render_service.engine import check_dashboard_address, dask_client

pytestmark = [pytest.mark.service]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    tls_dir = tmp_path_factory.mktemp("tls") / "creds"
    with dask_client(n_workers=1, tls_dir=tls_dir) as client:
        yield client, tls_dir


def _host_port(address: str) -> tuple[str, int]:
    host, port = address.split("://", 1)[1].rsplit(":", 1)
    return host, int(port)


def test_credentials_are_private_files(cluster):
    _, tls_dir = cluster
    assert stat.S_IMODE(tls_dir.stat().st_mode) == 0o700
    files = sorted(tls_dir.iterdir())
    assert [p.name for p in files] == ["dask-cert.pem", "dask-key.pem"]
    for p in files:
        assert stat.S_IMODE(p.stat().st_mode) == 0o600 and p.stat().st_uid == os.getuid()


def test_the_credentialed_client_runs_code(cluster):
    client, _ = cluster
    assert client.scheduler.address.startswith("tls://127.0.0.1:")
    pids = client.run(os.getpid)
    assert len(pids) == 1 and all(p != os.getpid() for p in pids.values())  # a real worker process
    assert client.submit(sum, [1, 2, 3]).result() == 6


async def _identity(address: str, security=None) -> dict:
    """Connect to a Dask server as a client would and ask who it is (the first step of any Client)."""
    from distributed.comm import connect

    kw = security.get_connection_args("client") if security is not None else {}
    comm = await connect(address, timeout=5, **kw)
    try:
        await comm.write({"op": "identity"})
        return await comm.read()
    finally:
        await comm.close()


def test_clients_without_the_credentials_cannot_connect(cluster, tmp_path):
    """Dask's own connect() (what a Client does first), without creating Clients whose failed start leaves
    event-loop threads behind."""
    import asyncio

    from render_service.dask_tls import TlsFiles

    client, tls_dir = cluster
    addr = client.scheduler.address
    mine = TlsFiles(cert=tls_dir / "dask-cert.pem", key=tls_dir / "dask-key.pem").security()
    assert asyncio.run(_identity(addr, mine))["type"] == "Scheduler"  # the credentials work: the probe is sound
    with pytest.raises(TypeError, match="ssl_context"):  # tls:// with no security at all
        asyncio.run(_identity(addr))
    with pytest.raises(OSError):  # the same port in clear text
        asyncio.run(_identity(addr.replace("tls://", "tcp://")))
    own = generate_tls_files(tmp_path / "attacker").security()  # a well-formed certificate of another CA
    with pytest.raises(OSError):
        asyncio.run(_identity(addr, own))
    for worker in client.scheduler_info()["workers"]:  # the workers are behind the same TLS
        with pytest.raises(OSError):
            asyncio.run(_identity(worker, own))
        assert asyncio.run(_identity(worker, mine))["type"] == "Worker"
    assert len(client.run(os.getpid)) == 1  # the cluster is unharmed


def test_raw_tls_without_a_client_certificate_is_refused(cluster):
    client, _ = cluster
    host, port = _host_port(client.scheduler.address)
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_NONE  # the attacker does not care who the server is
    with socket.create_connection((host, port), timeout=5) as raw:
        with pytest.raises((ssl.SSLError, ConnectionError, OSError)):
            with ctx.wrap_socket(raw) as tls:
                tls.sendall(b"\x00" * 64)  # TLS 1.3 reports the missing certificate on first use
                assert tls.recv(1) == b""  # ... or the server just closes
                raise ConnectionError("closed by the server")


def test_no_dashboard_and_no_http_routes_unless_asked(cluster):
    client, _ = cluster
    info = client.scheduler_info()
    host, _ = _host_port(client.scheduler.address)
    http_port = info["services"].get("dashboard")
    assert http_port != 8787  # not the well-known port
    if http_port is not None:  # Dask always listens for HTTP: there must be nothing behind it
        for route in ("/json/identity.json", "/status", "/health", "/metrics", "/proxy/8786/127.0.0.1/status"):
            assert httpx.get(f"http://{host}:{http_port}{route}", timeout=5).status_code == 404, route
    for w in info["workers"].values():
        port = w.get("services", {}).get("dashboard")
        if port is not None:
            assert httpx.get(f"http://{host}:{port}/health", timeout=5).status_code == 404


def test_dashboard_only_on_loopback(tmp_path):
    from render_service.main import create_app
    from render_service.settings import ServiceSettings

    with pytest.raises(InvalidInputError, match="loopback"):  # at start-up, before any cluster
        create_app(ServiceSettings(data_dir=tmp_path / "d", start_cluster=False, dashboard="0.0.0.0:8787"))
    assert check_dashboard_address(None) is None
    assert check_dashboard_address("127.0.0.1:8790") == "127.0.0.1:8790"
    for bad in ("0.0.0.0:8787", ":8787", "example.org:8787", "8787"):
        with pytest.raises(InvalidInputError, match="loopback"):
            check_dashboard_address(bad)


def test_the_temporary_credentials_are_removed_on_exit():
    import tempfile

    before = set(Path(tempfile.gettempdir()).glob("skyloc-dask-tls-*"))
    with dask_client(n_workers=1, processes=False) as client:
        assert client.submit(abs, -2).result() == 2
        during = set(Path(tempfile.gettempdir()).glob("skyloc-dask-tls-*")) - before
        assert len(during) == 1 and stat.S_IMODE(next(iter(during)).stat().st_mode) == 0o700
    assert not (set(Path(tempfile.gettempdir()).glob("skyloc-dask-tls-*")) - before)


def test_scheduler_credentials_from_files(cluster, tmp_path):
    """The --tls-ca-file/--tls-cert/--tls-key path (security_from_files) reaches a TLS scheduler; bad files refused."""
    import asyncio

    from render_service.engine import security_from_files

    client, tls_dir = cluster
    cert, key = tls_dir / "dask-cert.pem", tls_dir / "dask-key.pem"
    sec = security_from_files(ca_file=cert, cert_file=cert, key_file=key)
    assert asyncio.run(_identity(client.scheduler.address, sec))["type"] == "Scheduler"
    with pytest.raises(InvalidInputError, match="--tls-key"):
        security_from_files(ca_file=cert, cert_file=cert, key_file=tmp_path / "missing.pem")


DASH_TOKEN = "dashboard-token-0123456789abcdef"


@pytest.fixture(scope="module")
def dashboard_port():
    """A LocalCluster serving its dashboard (Bokeh pages included) behind DASH_TOKEN on a loopback port."""
    with dask_client(n_workers=1, dashboard="127.0.0.1:0", dashboard_token=DASH_TOKEN) as client:
        yield client, client.scheduler_info()["services"]["dashboard"]


def _basic(password: str) -> str:
    import base64

    return "Basic " + base64.b64encode(f"anyone:{password}".encode()).decode()


#: routes a local user would try: the pages, their data, the scheduler's address, metrics, the worker proxy
DASHBOARD_ROUTES = ("/status", "/json/identity.json", "/sitemap.json", "/metrics", "/health", "/individual-plots.json",
                    "/proxy/8786/127.0.0.1/status", "/statics/css/base.css", "/no-such-route")


def test_a_dashboard_needs_a_token():
    from render_service.main import create_app
    from render_service.settings import ServiceSettings

    with pytest.raises(InvalidInputError, match="token"):
        with dask_client(n_workers=1, processes=False, dashboard="127.0.0.1:0"):
            pass
    with pytest.raises(InvalidInputError, match="--dashboard needs a token"):  # at start-up
        create_app(ServiceSettings(data_dir=Path(os.environ.get("TMPDIR", "/tmp")) / "skyloc-dash-no-token",
                                   start_cluster=False, dashboard="127.0.0.1:8790"))


def test_the_dashboard_refuses_every_route_without_the_token(dashboard_port):
    _, port = dashboard_port
    base = f"http://127.0.0.1:{port}"
    for route in DASHBOARD_ROUTES:
        for headers in ({}, {"Authorization": "Bearer wrong-token-0123456789"}, {"Authorization": _basic("wrong")},
                        {"Authorization": "Bearer"}, {"Cookie": f"token={DASH_TOKEN}"}):
            r = httpx.get(base + route, headers=headers, timeout=10)
            assert r.status_code == 401, (route, headers, r.status_code)
            assert "scheduler" not in r.text.lower() and "tls://" not in r.text, route  # nothing leaks
        assert r.headers["www-authenticate"].startswith("Basic")  # a browser asks for it


def test_the_dashboard_answers_with_the_token(dashboard_port):
    client, port = dashboard_port
    base = f"http://127.0.0.1:{port}"
    for auth in (f"Bearer {DASH_TOKEN}", _basic(DASH_TOKEN)):
        ident = httpx.get(base + "/json/identity.json", headers={"Authorization": auth}, timeout=10)
        assert ident.status_code == 200 and ident.json()["address"] == client.scheduler.address
        page = httpx.get(base + "/status", headers={"Authorization": auth}, timeout=30)
        assert page.status_code == 200 and "bokeh" in page.text.lower()  # the real dashboard, not a stub
        assert httpx.get(base + "/no-such-route", headers={"Authorization": auth}, timeout=10).status_code == 404


def test_the_dashboard_websocket_and_bodies_are_refused_before_use(dashboard_port):
    """Bokeh's live updates come over a websocket: its handshake needs the token too; a POST body is not read."""
    import asyncio

    from tornado.httpclient import HTTPClientError, HTTPRequest
    from tornado.websocket import websocket_connect

    _, port = dashboard_port

    async def handshake(headers):
        try:
            conn = await websocket_connect(HTTPRequest(f"ws://127.0.0.1:{port}/status/ws", headers=headers))
        except HTTPClientError as exc:
            return exc.code
        conn.close()
        return 101

    assert asyncio.run(handshake({})) == 401
    assert asyncio.run(handshake({"Authorization": "Bearer wrong-token-0123456789"})) == 401
    assert asyncio.run(handshake({"Authorization": f"Bearer {DASH_TOKEN}"})) != 401  # reaches Bokeh

    def endless_body():
        for _ in range(64 * 1024):  # up to 4 GiB if the server kept reading
            yield b"\0" * 65536

    with httpx.Client(timeout=30) as http:
        try:
            r = http.post(f"http://127.0.0.1:{port}/status", content=endless_body())
            assert r.status_code == 401
        except (httpx.RemoteProtocolError, httpx.WriteError, httpx.ReadError):
            pass  # answered 401 and closed while the client was still sending: the body was not read


def test_a_dashboard_asked_for_is_served_on_loopback_only(dashboard_port):
    """Positive control of the no-routes test: with ``dashboard`` the routes answer (with the token), on 127.0.0.1."""
    _, port = dashboard_port
    r = httpx.get(f"http://127.0.0.1:{port}/json/identity.json", headers={"Authorization": f"Bearer {DASH_TOKEN}"},
                  timeout=10)
    assert r.status_code == 200
    with socket.socket() as s:
        s.settimeout(2)
        public = next((a for a in socket.gethostbyname_ex(socket.gethostname())[2]
                       if not a.startswith("127.")), None)
        if public is not None:  # not listening on the machine's other addresses
            assert s.connect_ex((public, port)) != 0


def test_workers_serve_no_http_routes_with_a_dashboard(dashboard_port):
    client, _ = dashboard_port
    for w in client.scheduler_info()["workers"].values():
        port = w.get("services", {}).get("dashboard")
        if port is not None:
            assert httpx.get(f"http://127.0.0.1:{port}/health", timeout=5).status_code == 404


def test_tls_options_are_for_a_scheduler_and_need_a_client_certificate(tmp_path):
    """skyloc serve and skyloc campaign share the TLS option rules (render_service/cli_tls.py)."""
    from click.testing import CliRunner

    from skyloc.cli import main

    pem = tmp_path / "x.pem"
    pem.write_text("not used")
    r = CliRunner()
    for cmd in (["serve", "--data", str(tmp_path / "d")], ["campaign", "--out", str(tmp_path / "c")]):
        res = r.invoke(main, [*cmd, "--tls-cert", str(pem)])
        assert res.exit_code == 2 and "are for a --scheduler" in res.output
        res = r.invoke(main, [*cmd, "--scheduler", "tls://127.0.0.1:1", "--tls-ca-file", str(pem)])
        assert res.exit_code == 2 and "give --tls-cert" in res.output
        res = r.invoke(main, [*cmd, "--scheduler", "tls://127.0.0.1:1", "--tls-cert", str(pem)])
        assert res.exit_code == 2 and "give --tls-ca-file" in res.output
    assert not (tmp_path / "d").exists() and not (tmp_path / "c").exists()


def test_the_service_serves_its_dashboard_behind_its_own_token(tmp_path):
    """``skyloc serve --dashboard``: the runner's LocalCluster gets the API's token for its dashboard."""
    from fastapi.testclient import TestClient

    from render_service.main import create_app
    from render_service.settings import ServiceSettings

    settings = ServiceSettings(data_dir=tmp_path / "data", token=DASH_TOKEN, n_workers=1, dashboard="127.0.0.1:0")
    with TestClient(create_app(settings), raise_server_exceptions=False) as api:
        runner = api.app.state.runner
        assert runner.wait_ready(120) and runner.error is None, runner.error
        port = runner.client.scheduler_info()["services"]["dashboard"]
        url = f"http://127.0.0.1:{port}/json/identity.json"
        assert httpx.get(url, timeout=10).status_code == 401
        assert httpx.get(url, headers={"Authorization": f"Bearer {DASH_TOKEN}"}, timeout=10).status_code == 200
