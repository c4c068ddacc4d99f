"""Render-service API unit cases on an in-process app (TestClient, no Dask): auth, validation, limits, errors.

The bad inputs here are real files (GDAL-written rasters, a real PNG, a truncated GeoTIFF);
every refusal must be a 4xx JSON {"detail", "code"} with a reason, and the app must keep serving.
The uploaded DEM is ``service_dem`` (tests/render_service/conftest.py): the real Gale patch, or a
procedural Mars DEM when ../shared/data/dems is absent.
"""
from __future__ import annotations

import base64
import importlib.util

import numpy as np
import pytest
import skyloc_service_test_helpers as H  # registered by tests/conftest.py
from fastapi.testclient import TestClient

from board.errors import InvalidInputError
from render_service.main import create_app
from render_service.security import TokenAuth, check_startup, is_loopback, load_token
from render_service.settings import ServiceSettings


@pytest.fixture()
def app_client(tmp_path):
    settings = ServiceSettings(data_dir=tmp_path / "data", token=H.TOKEN, start_cluster=False,
                               max_upload_bytes=2_000_000)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        client.headers.update(H.AUTH)
        yield client


@pytest.fixture()
def uploaded_dem(app_client, service_dem):
    r = app_client.post("/v1/dems", files={"file": ("dem.tif", service_dem.path.read_bytes())})
    assert r.status_code == 201, r.text
    return r.json()


def _job(dem, **kw):
    spec = {"kind": "skyline_db", "dem_id": dem["id"], "center": dem["center"], "size_m": 100, "step_m": 10,
            "azimuths": 36, "tile_size": 4}
    spec.update(kw)
    return spec


def assert_refused(r, status=None, *, words=()):
    assert 400 <= r.status_code < 500, (r.status_code, r.text)
    if status is not None:
        assert r.status_code == status, r.text
    body = r.json()
    assert set(body) == {"detail", "code"}, body
    assert body["detail"] and body["code"]
    text = str(body["detail"]).lower()
    for w in words:
        assert w.lower() in text, (w, body)
    return body


# -- DEM upload ---------------------------------------------------------------------------------------
def test_upload_dem_summary_matches_gdal(app_client, uploaded_dem, service_dem):
    from osgeo import gdal

    ds = gdal.Open(str(service_dem.path))
    gt = ds.GetGeoTransform()
    assert uploaded_dem["size"] == [ds.RasterXSize, ds.RasterYSize]
    assert uploaded_dem["cell_m"] == pytest.approx(abs(gt[1]))
    assert uploaded_dem["bounds"][0] == pytest.approx(gt[0]) and uploaded_dem["bounds"][3] == pytest.approx(gt[3])
    assert uploaded_dem["body"] == service_dem.body and not uploaded_dem["is_geographic"]
    # same content again: same id, not a new DEM
    again = app_client.post("/v1/dems", files={"file": ("other.tif", service_dem.path.read_bytes())}).json()
    assert again["id"] == uploaded_dem["id"] and again["created"] is False
    assert [d["id"] for d in app_client.get("/v1/dems").json()] == [uploaded_dem["id"]]


def _png_bytes(tmp_path):
    from osgeo import gdal

    mem = gdal.GetDriverByName("MEM").Create("", 32, 32, 1, gdal.GDT_Byte)
    mem.GetRasterBand(1).WriteArray(np.arange(32 * 32, dtype=np.uint8).reshape(32, 32))
    gdal.GetDriverByName("PNG").CreateCopy(str(tmp_path / "x.png"), mem)
    return (tmp_path / "x.png").read_bytes()


@pytest.mark.parametrize("case", ["truncated", "garbage", "png_renamed", "no_crs_degrees", "unknown_body_degrees",
                                  "nodata_everywhere", "huge_declared", "bad_body_name", "vrt_pointing_elsewhere"])
def test_bad_uploads_are_refused_with_reason(app_client, tmp_path, service_dem, case):
    rng = np.random.default_rng(1)
    a = (rng.normal(size=(40, 40)) * 5 + 100).astype(np.float32)
    deg_gt = (10.0, 0.001, 0.0, 45.0, 0.0, -0.001)
    data, form, words = None, None, ()
    if case == "truncated":
        raw = service_dem.path.read_bytes()
        data, words = raw[: len(raw) // 3], ("gdal",)
    elif case == "garbage":
        data = b"II*\x00" + bytes(rng.integers(0, 256, 5000, dtype=np.uint8))
    elif case == "png_renamed":
        data, words = _png_bytes(tmp_path), ("not a readable dem",)
    elif case == "no_crs_degrees":
        data, words = H.write_tif(tmp_path / "f.tif", a, gt=deg_gt).read_bytes(), ("crs",)
    elif case == "unknown_body_degrees":
        wkt = ('GEOGCS["x",DATUM["x",SPHEROID["weird",1234567,0]],PRIMEM["Greenwich",0],'
               'UNIT["degree",0.0174532925199433]]')
        data, words = H.write_tif(tmp_path / "f.tif", a, wkt=wkt, gt=deg_gt).read_bytes(), ("body",)
    elif case == "nodata_everywhere":
        data = H.write_tif(tmp_path / "f.tif", np.full((40, 40), -9999.0), epsg=32633, nodata=-9999).read_bytes()
        words = ("nodata",)
    elif case == "huge_declared":
        data, words = H.write_huge_sparse_tif(tmp_path / "f.tif").read_bytes(), ("limit",)
    elif case == "bad_body_name":
        data, form, words = H.write_tif(tmp_path / "f.tif", a, gt=deg_gt).read_bytes(), {"body": "vulcan"}, ("body",)
    elif case == "vrt_pointing_elsewhere":  # a VRT renamed .tif that would read another server file
        data = (f'<VRTDataset rasterXSize="348" rasterYSize="337"><VRTRasterBand dataType="Float32" band="1">'
                f'<SimpleSource><SourceFilename relativeToVRT="0">{service_dem.path}</SourceFilename>'
                f'<SourceBand>1</SourceBand></SimpleSource></VRTRasterBand></VRTDataset>').encode()
    r = app_client.post("/v1/dems", files={"file": ("dem.tif", data)}, data=form)
    body = assert_refused(r, 422, words=words)
    assert "/tmp" not in str(body["detail"]) and str(tmp_path) not in str(body["detail"])  # no server paths
    assert app_client.get("/healthz").status_code == 200
    assert list((tmp_path / "data" / "dems").iterdir()) == []  # nothing kept


@pytest.mark.parametrize("name", ["../../etc/passwd.tif", "..\\x.tif", "/etc/x.tif", "a/b.tif", ".hidden.tif",
                                  "dem.vrt", "dem.sh"])
def test_upload_names_with_paths_or_bad_suffix_refused(app_client, service_dem, name):
    r = app_client.post("/v1/dems", files={"file": (name, service_dem.path.read_bytes())})
    assert_refused(r, 422, words=("file name",))


def test_upload_over_size_limit_is_413(app_client):
    r = app_client.post("/v1/dems", files={"file": ("big.tif", b"\0" * 2_200_000)})
    assert_refused(r, 413, words=("larger than",))
    assert app_client.get("/healthz").status_code == 200


# -- jobs -----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("patch,where", [
    ({"step_m": 0}, "step_m"), ({"step_m": -5}, "step_m"), ({"size_m": -1}, "size_m"),
    ({"center": "abc"}, "center"), ({"center": [1.0]}, "center"), ({"azimuths": "many"}, "azimuths"),
    ({"azimuths": 0}, "azimuths"), ({"renderer": "povray"}, "renderer"), ({"kind": "pizza"}, "kind"),
    ({"unexpected": 1}, "unexpected"), ({"dem_id": "../../etc"}, "dem_id"), ({"camera_height_m": -1}, "camera"),
])
def test_bad_job_fields_are_422(app_client, uploaded_dem, patch, where):
    r = app_client.post("/v1/jobs", json=_job(uploaded_dem, **patch))
    body = assert_refused(r, 422)
    assert body["code"] == "validation_error" and where in str(body["detail"])


def test_missing_fields_are_422(app_client, uploaded_dem):
    spec = _job(uploaded_dem)
    for field in ("dem_id", "center", "size_m", "step_m", "kind"):
        r = app_client.post("/v1/jobs", json={k: v for k, v in spec.items() if k != field})
        assert_refused(r, 422)
    assert_refused(app_client.post("/v1/jobs", content=b"{not json", headers={"Content-Type": "application/json"}),
                   422)


def test_job_limits_and_dem_bounds(app_client, uploaded_dem):
    assert_refused(app_client.post("/v1/jobs", json=_job(uploaded_dem, size_m=20000, step_m=50)), 422,
                   words=("km^2", "limit"))
    assert_refused(app_client.post("/v1/jobs", json=_job(uploaded_dem, size_m=300, step_m=0.1)), 422,
                   words=("positions",))
    assert_refused(app_client.post("/v1/jobs", json=_job(uploaded_dem, azimuths=5000)), 422, words=("azimuths",))
    x, y = uploaded_dem["bounds"][2], uploaded_dem["bounds"][3]  # centre on the corner: grid half outside
    assert_refused(app_client.post("/v1/jobs", json=_job(uploaded_dem, center=[x, y])), 422, words=("inside",))
    assert_refused(app_client.post("/v1/jobs", json=_job(uploaded_dem, dem_id="0123456789abcdef")), 422,
                   words=("upload",))


def test_job_submit_idempotent_list_cancel(app_client, uploaded_dem):
    spec = _job(uploaded_dem)
    r1 = app_client.post("/v1/jobs", json=spec)
    assert r1.status_code == 202 and r1.headers["location"] == f"/v1/jobs/{r1.json()['id']}"
    j = r1.json()
    # 11 x 11 positions in tiles of 4 -> 3 x 3 tiles
    assert (j["state"], j["tiles_total"], j["tiles_done"], j["positions_total"]) == ("queued", 9, 0, 121)
    assert app_client.post("/v1/jobs", json=spec).json()["id"] == j["id"]          # same spec, same job
    key = {"Idempotency-Key": "k1"}
    other = app_client.post("/v1/jobs", json=_job(uploaded_dem, azimuths=72), headers=key).json()
    assert other["id"] != j["id"]
    again = app_client.post("/v1/jobs", json=_job(uploaded_dem, azimuths=72), headers=key).json()
    assert again["id"] == other["id"]
    assert_refused(app_client.post("/v1/jobs", json=_job(uploaded_dem, azimuths=90), headers=key), 422,
                   words=("idempotency",))
    assert {x["id"] for x in app_client.get("/v1/jobs").json()["jobs"]} == {j["id"], other["id"]}
    assert app_client.get(f"/v1/jobs/{j['id']}/result").status_code == 409   # not done yet
    c = app_client.delete(f"/v1/jobs/{j['id']}")
    assert c.status_code == 202 and c.json()["state"] == "cancel-requested"
    assert_refused(app_client.get("/v1/jobs/ffffffffffffffffffff"), 404)
    assert_refused(app_client.delete("/v1/jobs/ffffffffffffffffffff"), 404)
    assert app_client.get("/v1/jobs/..%2F..%2Fetc").status_code in (404, 422)


def test_dataset_job_scene_names(app_client):
    for scene in ("../../etc/passwd", "/abs", "a/b"):
        assert_refused(app_client.post("/v1/jobs", json={"kind": "dataset", "scene": scene}), 422)
    r = app_client.post("/v1/jobs", json={"kind": "dataset", "scene": "no_such_scene_xyz"})
    assert r.status_code in (422, 501), r.text  # unknown scene, or dataset generation not installed
    assert set(r.json()) == {"detail", "code"}


# -- security ---------------------------------------------------------------------------------------------
def test_token_required_and_compared(app_client, uploaded_dem):
    for headers in ({}, {"Authorization": "Bearer wrong-token-0123456789"}, {"Authorization": "Token " + H.TOKEN},
                    {"Authorization": "Bearer"}, {"Authorization": "Basic !!!"}):
        for method, url in (("GET", "/v1/jobs"), ("GET", "/"), ("POST", "/v1/jobs"), ("GET", "/v1/dems")):
            r = app_client.request(method, url, headers={"Authorization": ""} | headers)
            assert_refused(r, 401)
            assert r.headers["www-authenticate"].startswith("Basic" if url == "/" else "Bearer")
    basic = base64.b64encode(f"anyone:{H.TOKEN}".encode()).decode()
    assert app_client.get("/v1/jobs", headers={"Authorization": f"Basic {basic}"}).status_code == 200
    assert app_client.get("/healthz", headers={"Authorization": ""}).status_code == 200


def test_startup_rules(tmp_path):
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.5") and not is_loopback("example.org")
    with pytest.raises(InvalidInputError, match="SKYLOC_TOKEN"):
        create_app(ServiceSettings(data_dir=tmp_path, host="0.0.0.0", start_cluster=False))
    with pytest.raises(InvalidInputError, match="too short"):
        check_startup(ServiceSettings(host="0.0.0.0"), "short")
    tf = tmp_path / "token"
    tf.write_text(H.TOKEN + "\n")
    s = ServiceSettings(data_dir=tmp_path, host="0.0.0.0", token_file=tf, start_cluster=False)
    assert load_token(s) == H.TOKEN
    create_app(s)  # a token: allowed on any interface
    (tmp_path / "empty").write_text("")
    with pytest.raises(InvalidInputError, match="empty"):
        load_token(ServiceSettings(token_file=tmp_path / "empty"))
    assert not TokenAuth(None).enabled


def test_serve_cli_refuses_public_host_without_token(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from skyloc.cli import main

    monkeypatch.delenv("SKYLOC_TOKEN", raising=False)
    r = CliRunner().invoke(main, ["serve", "--host", "0.0.0.0", "--data", str(tmp_path / "d")])
    assert r.exit_code == 1 and "SKYLOC_TOKEN" in r.output


def test_token_never_in_logs_or_responses(tmp_path, caplog):
    caplog.set_level("DEBUG")
    s = ServiceSettings(data_dir=tmp_path, token=H.TOKEN, start_cluster=False)
    with TestClient(create_app(s), raise_server_exceptions=False) as c:
        c.get("/v1/jobs", headers={"Authorization": "Bearer nope-nope-nope-nope"})
        ok = c.get("/v1/jobs", headers=H.AUTH)
        html = c.get("/", headers=H.AUTH).text
        spec = c.get("/openapi.json").text
    assert ok.status_code == 200
    assert H.TOKEN not in caplog.text and H.TOKEN not in html and H.TOKEN not in spec
    assert H.TOKEN not in repr(s)


def test_no_cors_by_default(app_client):
    r = app_client.options("/v1/jobs",
                           headers={"Origin": "http://evil.example", "Access-Control-Request-Method": "GET"})
    assert "access-control-allow-origin" not in {k.lower() for k in r.headers}


def test_dataset_job_accepted_for_a_known_scene(app_client):
    if importlib.util.find_spec("blender_addon.sim") is None:
        r = app_client.post("/v1/jobs", json={"kind": "dataset", "scene": "test_tiny"})
        assert r.status_code == 501 and r.json()["code"] == "not_available"
        return
    r = app_client.post("/v1/jobs", json={"kind": "dataset", "scene": "test_tiny"})
    assert r.status_code == 202, r.text
    j = r.json()
    assert (j["kind"], j["state"], j["tiles_total"]) == ("dataset", "queued", 1)
    assert app_client.post("/v1/jobs", json={"kind": "dataset", "scene": "test_tiny"}).json()["id"] == j["id"]
