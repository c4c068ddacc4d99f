"""The security-and-fault probe's smaller findings (issue 12, points 6 and 7), each generated here.

In-process app (TestClient, no Dask) unless stated; every refusal is a JSON ``{"detail", "code"}``.
"""
from __future__ import annotations

import json
import re
import subprocess
import sys
import textwrap

import pytest
import skyloc_service_test_helpers as H  # registered by tests/conftest.py
from fastapi.testclient import TestClient

from board.errors import InvalidInputError
from render_service.main import create_app
from render_service.settings import ServiceSettings


@pytest.fixture()
def c(tmp_path):
    s = ServiceSettings(data_dir=tmp_path / "data", token=H.TOKEN, start_cluster=False, max_upload_bytes=4_000_000)
    with TestClient(create_app(s), raise_server_exceptions=False) as client:
        client.headers.update(H.AUTH)
        yield client


@pytest.fixture()
def dem(c, service_dem):
    r = c.post("/v1/dems", files={"file": ("dem.tif", service_dem.path.read_bytes())})
    assert r.status_code == 201, r.text
    return r.json()


def _job(dem, **kw):
    return {"kind": "skyline_db", "dem_id": dem["id"], "center": dem["center"], "size_m": 100, "step_m": 10,
            "azimuths": 36, "tile_size": 4, **kw}


def _refused(r, status):
    assert r.status_code == status, (r.status_code, r.text)
    body = r.json()
    assert set(body) == {"detail", "code"} and body["detail"] and body["code"], body
    return body


# -- point 7: every error has a code and is in the schema ----------------------------------------------
def test_routing_and_parsing_errors_have_a_code(c):
    assert _refused(c.put("/v1/jobs"), 405)["code"] == "method_not_allowed"
    assert _refused(c.get("/v1/nothing-here"), 404)["code"] == "not_found"
    bad_multipart = c.post("/v1/dems", content=b"--x\r\nContent-Disposition: form-data; name=\"file\"\r\n\r\nabc",
                           headers={"Content-Type": "multipart/form-data; boundary=x"})
    assert bad_multipart.status_code in (400, 422), bad_multipart.text
    assert set(bad_multipart.json()) == {"detail", "code"}
    no_boundary = c.post("/v1/dems", content=b"abc", headers={"Content-Type": "multipart/form-data"})
    assert set(no_boundary.json()) == {"detail", "code"} and 400 <= no_boundary.status_code < 500
    bad_json = c.post("/v1/jobs", content=b'{"kind": ', headers={"Content-Type": "application/json"})
    assert set(bad_json.json()) == {"detail", "code"} and bad_json.status_code in (400, 422)


def test_every_operation_documents_the_common_errors(c):
    spec = c.get("/openapi.json").json()
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            for code in ("400", "404", "405", "413"):
                ref = op["responses"].get(code, {}).get("content", {}).get("application/json", {}).get("schema", {})
                assert ref.get("$ref", "").endswith("/ErrorOut"), (method, path, code)


def test_not_found_detail_is_not_quoted(c):
    body = _refused(c.get("/v1/jobs/ffffffffffffffffffff"), 404)
    assert body["detail"].startswith("no job with id") and not body["detail"].startswith(("'", '"'))


def test_json_limit_message_speaks_of_json(c):
    body = _refused(c.post("/v1/jobs", content=b"[" + b"1," * 600_000 + b"1]",
                           headers={"Content-Type": "application/json"}), 413)
    assert "json" in body["detail"].lower() and "upload" not in body["detail"].lower()
    big = _refused(c.post("/v1/dems", files={"file": ("big.tif", b"\0" * 4_200_000)}), 413)
    assert "upload a smaller file" in big["detail"]


def test_tiny_step_gives_a_short_message(c, dem):
    body = _refused(c.post("/v1/jobs", json=_job(dem, step_m=1e-300)), 422)
    assert len(body["detail"]) < 300 and not re.search(r"\d{20}", body["detail"]), body["detail"]
    assert "step_m" in body["detail"] and "positions" in body["detail"]


@pytest.mark.parametrize("patch,field", [({"azimuths": True}, "azimuths"), ({"size_m": "100"}, "size_m"),
                                         ({"tile_size": 4.0}, "tile_size"), ({"center": ["1", 2]}, "center"),
                                         ({"camera_height_m": False}, "camera_height_m")])
def test_numbers_are_strict(c, dem, patch, field):
    body = _refused(c.post("/v1/jobs", json=_job(dem, **patch)), 422)
    assert body["code"] == "validation_error" and field in json.dumps(body["detail"])


def test_ints_are_still_numbers(c, dem):
    r = c.post("/v1/jobs", json=_job(dem, size_m=100, step_m=10, center=[round(v) for v in dem["center"]]))
    assert r.status_code == 202, r.text


def test_reupload_with_another_body_is_a_new_dem(c, dem, service_dem):
    raw = service_dem.path.read_bytes()
    same = c.post("/v1/dems", files={"file": ("dem.tif", raw)}, data={"body": dem["body"]}).json()
    assert same["id"] == dem["id"] and same["created"] is False  # same file, same body: the same DEM
    moon = c.post("/v1/dems", files={"file": ("dem.tif", raw)}, data={"body": "moon"})
    assert moon.status_code == 201, moon.text
    m = moon.json()
    assert m["created"] is True and m["id"] != dem["id"] and m["sha256"] == dem["sha256"]
    assert m["body"] == "moon" and m["body_radius_m"] != dem["body_radius_m"]
    assert c.get(f"/v1/dems/{m['id']}").json()["body"] == "moon"
    assert c.get(f"/v1/dems/{dem['id']}").json()["body"] == dem["body"]
    again = c.post("/v1/dems", files={"file": ("dem.tif", raw)}, data={"body": "moon"}).json()
    assert again["id"] == m["id"] and again["created"] is False


def test_idempotency_key_sent_for_an_existing_job_is_recorded(c, dem):
    first = c.post("/v1/jobs", json=_job(dem)).json()  # no key
    same = c.post("/v1/jobs", json=_job(dem), headers={"Idempotency-Key": "k2"}).json()
    assert same["id"] == first["id"]
    other = c.post("/v1/jobs", json=_job(dem, azimuths=72), headers={"Idempotency-Key": "k2"})
    assert _refused(other, 422)["code"] == "invalid_input" and "idempotency" in other.json()["detail"].lower()
    assert len(c.get("/v1/jobs").json()["jobs"]) == 1  # no second job under the same key


# -- point 7: one server per data directory ------------------------------------------------------------
def test_a_second_server_is_refused_the_data_directory(tmp_path):
    s = ServiceSettings(data_dir=tmp_path / "data", token=H.TOKEN, start_cluster=False)
    with TestClient(create_app(s)):
        with pytest.raises(InvalidInputError, match=r"in use by another skyloc server \(pid \d+\)"):
            create_app(s)
        r = subprocess.run([sys.executable, "-m", "skyloc.cli", "serve", "--data", str(s.data_dir), "--port", "0"],
                           capture_output=True, text=True, timeout=120, env=_env())
        assert r.returncode == 1 and "in use by another skyloc server" in r.stderr + r.stdout, r.stderr[-2000:]
    with TestClient(create_app(s)) as again:  # released when the first one stopped
        assert again.get("/healthz").status_code == 200


def _env():
    import os

    return {**os.environ, "SKYLOC_TOKEN": H.TOKEN}


# -- point 6: DEM validation in bounded memory ------------------------------------------------------------
@pytest.mark.slow
def test_sparse_dem_validation_peak_memory_is_bounded(tmp_path):
    """A 16000 x 16000 sparse GeoTIFF (a few kB, 1 GB of float32 cells) uploaded to a fresh API process:
    with GDAL's default block cache (5 % of RAM) its validation grew the process by about 1 GB (the probe's
    30000 x 30000 file by 1.1 GB, see docs/benchmarks.md); bounded, by 64 MiB + 4 blocks, and read block by
    block (blender_addon.terrain.raster_sample)."""
    tif = H.write_huge_sparse_tif(tmp_path / "sparse.tif", 16_000)
    assert tif.stat().st_size < 200_000
    script = textwrap.dedent(f"""
        import json, resource
        from fastapi.testclient import TestClient
        from render_service.main import create_app
        from render_service.settings import ServiceSettings
        s = ServiceSettings(data_dir={str(tmp_path / 'data')!r}, token={H.TOKEN!r}, start_cluster=False)
        with TestClient(create_app(s)) as c:
            before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
            r = c.post("/v1/dems", files={{"file": ("sparse.tif", open({str(tif)!r}, "rb").read())}},
                       headers={{"Authorization": "Bearer {H.TOKEN}"}})
            after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        print(json.dumps({{"status": r.status_code, "grew_mb": (after - before) / 1024}}))
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, env=_env())
    assert out.returncode == 0, out.stderr[-3000:]
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["status"] in (201, 422), res  # accepted (all zeros) or refused: either way validated
    assert res["grew_mb"] < 160, res  # 64 MiB cache + 4 x 4 MiB blocks + the interpreter's own growth
