"""The token is checked before any request body is read: an unauthenticated upload writes nothing anywhere.

A real uvicorn server (in a thread of this process, no Dask) and a raw socket: the client declares a
400 MiB multipart upload, sends its headers and the first MiB, and must get its 401 at once (before the
fix the server spooled the whole body to a temporary file first, and only then answered).  The client
then keeps streaming from a generator until the server hangs up; nothing appears in the data directory
or in the temporary folder the multipart parser would spool to.
"""
from __future__ import annotations

import json
import socket
import tempfile
import threading
import time

import pytest
import skyloc_service_test_helpers as H  # registered by tests/conftest.py

from render_service.main import create_app
from render_service.settings import ServiceSettings

DECLARED = 400 * 1024**2  # bytes the client says it will send
CHUNK = 1024**2


@pytest.fixture()
def live_app(tmp_path, monkeypatch):
    import uvicorn

    spool = tmp_path / "spool"
    spool.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(spool))  # where python-multipart would spool the upload
    data = tmp_path / "data"
    app = create_app(ServiceSettings(data_dir=data, token=H.TOKEN, start_cluster=False))
    port = H.free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", lifespan="on"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    t_end = time.monotonic() + 20
    while not server.started and time.monotonic() < t_end:
        time.sleep(0.05)
    assert server.started, "uvicorn did not start"
    before = {p.relative_to(data) for p in data.rglob("*")}
    yield port, data, spool, before
    server.should_exit = True
    thread.join(10)


def _body_chunks(boundary: bytes):
    """A 400 MiB multipart body, generated (never held in memory)."""
    head = (b"--" + boundary + b'\r\nContent-Disposition: form-data; name="file"; filename="big.tif"\r\n'
            b"Content-Type: application/octet-stream\r\n\r\n")
    tail = b"\r\n--" + boundary + b"--\r\n"
    yield head + b"\0" * (CHUNK - len(head))
    sent = CHUNK
    while sent < DECLARED - len(tail):
        n = min(CHUNK, DECLARED - len(tail) - sent)
        yield b"\0" * n
        sent += n
    yield tail


def _read_response(sock: socket.socket, timeout_s: float) -> bytes:
    sock.settimeout(timeout_s)
    data = b""
    while b"\r\n\r\n" not in data:
        got = sock.recv(65536)
        if not got:
            break
        data += got
    head, _, rest = data.partition(b"\r\n\r\n")
    length = next((int(line.split(b":")[1]) for line in head.split(b"\r\n")
                   if line.lower().startswith(b"content-length:")), 0)
    while len(rest) < length:
        got = sock.recv(65536)
        if not got:
            break
        rest += got
    return head + b"\r\n\r\n" + rest


@pytest.mark.parametrize("authorization", [None, "Bearer wrong-token-0123456789"])
def test_unauthenticated_400_mib_upload_is_refused_before_its_body(live_app, authorization):
    port, data, spool, before = live_app
    boundary = b"skylocboundary0123456789"
    headers = [b"POST /v1/dems HTTP/1.1", f"Host: 127.0.0.1:{port}".encode(),
               b"Content-Type: multipart/form-data; boundary=" + boundary, f"Content-Length: {DECLARED}".encode()]
    if authorization:
        headers.append(f"Authorization: {authorization}".encode())
    chunks = _body_chunks(boundary)
    sent = 0
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(b"\r\n".join(headers) + b"\r\n\r\n")
        first = next(chunks)
        try:
            sock.sendall(first)
            sent += len(first)
        except OSError:  # the server may answer and hang up on the headers alone
            pass
        try:
            raw = _read_response(sock, timeout_s=10.0)  # the answer comes before the other 399 MiB
        except socket.timeout:
            pytest.fail("no answer after the headers and 1 MiB: the server waits for the whole body")
        status_line, _, _ = raw.partition(b"\r\n")
        assert status_line.split()[1] == b"401", raw[:300]
        body = json.loads(raw.partition(b"\r\n\r\n")[2])
        assert body["code"] == "unauthorized" and body["detail"]
        assert b"www-authenticate: bearer" in raw.lower()
        # keep streaming: the server has hung up and takes (at most socket buffers of) nothing more
        try:
            for chunk in chunks:
                sock.sendall(chunk)
                sent += len(chunk)
        except OSError:
            pass
    assert sent < DECLARED, "the server read the whole unauthenticated body"
    assert list(spool.iterdir()) == [], "the upload was spooled to a temporary file"
    assert {p.relative_to(data) for p in data.rglob("*")} == before, "the upload was written to the data directory"


def test_authenticated_upload_still_works_and_public_paths_need_no_token(live_app, service_dem):
    import httpx

    port, data, _, _ = live_app
    url = f"http://127.0.0.1:{port}"
    r = httpx.post(url + "/v1/dems", headers=H.AUTH, files={"file": ("dem.tif", service_dem.path.read_bytes())},
                   timeout=60)
    assert r.status_code == 201, r.text
    assert len(list((data / "dems").iterdir())) == 1
    for path in ("/healthz", "/openapi.json", "/docs", "/redoc", "/docs-assets/swagger-ui-bundle.js"):
        assert httpx.get(url + path, timeout=10).status_code == 200, path
    for path in ("/v1/jobs", "/", "/v1/dems", "/no/such/route"):
        assert httpx.get(url + path, timeout=10).status_code == 401, path
