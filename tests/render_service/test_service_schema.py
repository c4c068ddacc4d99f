"""Property-based API test: schemathesis generates requests from the OpenAPI schema; none may give a 5xx.

In-process ASGI app (no Dask), authenticated, a DEM already uploaded (``service_dem``: the real Gale
patch, or a procedural Mars DEM without ../shared/data/dems); few examples per operation to keep it bounded.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from schemathesis.checks import not_a_server_error

from render_service.main import create_app
from render_service.settings import ServiceSettings

TOKEN = "schema-token-0123456789abcdef"


@pytest.fixture(scope="module")
def api_schema(service_dem):
    from fastapi.testclient import TestClient

    data = Path(tempfile.mkdtemp(prefix="skyloc-schema-"))
    app = create_app(ServiceSettings(data_dir=data, token=TOKEN, start_cluster=False, max_upload_bytes=4_000_000))
    with TestClient(app) as c:  # a DEM for generated jobs to refer to
        r = c.post("/v1/dems", files={"file": ("dem.tif", service_dem.path.read_bytes())},
                   headers={"Authorization": f"Bearer {TOKEN}"})
        assert r.status_code == 201, r.text
    return schemathesis.openapi.from_asgi("/openapi.json", app)


def test_no_server_errors(api_schema):
    checked, statuses = [], set()
    for result in api_schema.get_all_operations():
        operation = result.ok()

        @given(operation.as_strategy())
        @settings(max_examples=8, deadline=None, derandomize=True, database=None,
                  suppress_health_check=list(HealthCheck))
        def run(case):
            response = case.call_and_validate(headers={"Authorization": f"Bearer {TOKEN}"},
                                              checks=[not_a_server_error])
            statuses.add((operation.label, response.status_code))

        run()
        checked.append(operation.label)
    assert len(checked) >= 8, checked  # every route of the API was exercised
    codes = {code for _, code in statuses}
    assert any(200 <= c < 300 for c in codes) and 422 in codes, statuses  # requests really reached the app
