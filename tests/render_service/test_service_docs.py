"""``/docs`` (Swagger UI) and ``/redoc`` work offline: local assets from the installed fastapi-offline package.

A real uvicorn server (thread of this process, no Dask) and headless Chromium with every non-local host
unresolvable: the pages must render the API's operations from ``/docs-assets`` alone.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import threading
import time

import httpx
import pytest
import skyloc_service_test_helpers as H  # registered by tests/conftest.py

from render_service.main import create_app
from render_service.settings import ServiceSettings


@pytest.fixture(scope="module")
def docs_server(tmp_path_factory):
    import uvicorn

    app = create_app(ServiceSettings(data_dir=tmp_path_factory.mktemp("docs") / "data", token=H.TOKEN,
                                     start_cluster=False))
    port = H.free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    t_end = time.monotonic() + 20
    while not server.started and time.monotonic() < t_end:
        time.sleep(0.05)
    yield f"http://127.0.0.1:{port}"
    server.should_exit = True
    thread.join(10)


@pytest.mark.parametrize("page,asset", [("/docs", "swagger-ui-bundle.js"), ("/redoc", "redoc.standalone.js")])
def test_doc_pages_reference_only_local_assets(docs_server, page, asset):
    html = httpx.get(docs_server + page, timeout=10).text
    srcs = [s.split('"')[0] for s in html.split('src="')[1:]] + [s.split('"')[0] for s in html.split('href="')[1:]]
    assert srcs and all(s.startswith("/") for s in srcs), srcs  # nothing from another host
    assert f"/docs-assets/{asset}" in html
    js = httpx.get(f"{docs_server}/docs-assets/{asset}", timeout=10)
    assert js.status_code == 200 and len(js.content) > 100_000  # the real bundle, served without a token


def test_swagger_ui_renders_offline_in_headless_chromium(docs_server, tmp_path):
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("chromium is not installed (apt install chromium)")
    args = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-dev-shm-usage", f"--user-data-dir={tmp_path / 'profile'}",
            "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",  # no internet, as offline
            "--virtual-time-budget=15000", "--dump-dom"]
    env = {**os.environ, "HOME": str(tmp_path)}
    dom = subprocess.run(args + [docs_server + "/docs"], capture_output=True, text=True, timeout=120, env=env).stdout
    assert 'class="swagger-ui"' in dom and "opblock" in dom, dom[:2000]  # operations rendered by the JS
    for path in ("/v1/jobs", "/v1/dems", "/healthz"):
        assert path in dom, path
    redoc = subprocess.run(args + [docs_server + "/redoc"], capture_output=True, text=True, timeout=120,
                           env=env).stdout
    assert "Upload a DEM" in redoc, redoc[:2000]  # an operation summary: only the rendered page has it
