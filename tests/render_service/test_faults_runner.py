"""Fault injection at the job store's seam: the runner survives, the job fails with a reason, the queue goes on.

The probe's case: a full disk made the runner's own failure handler raise
``sqlite3.OperationalError: database or disk is full``; the thread died, the job stayed ``running``
and ``/healthz`` said ``ok``.  Here the in-process app runs its real job runner on a real (TLS)
LocalCluster of one worker process; the publish step fails with ENOSPC (leaving ``result.zip.tmp`` as
a full disk does) and recording the failure raises SQLite's disk-full error until the test "frees
space".  (``test_faults_tmpfs.py`` does the same with a real full file system.)
"""
from __future__ import annotations

import errno
import sqlite3
import time

import pytest
import skyloc_service_test_helpers as H  # registered by tests/conftest.py
from fastapi.testclient import TestClient

import render_service.runner as runner_mod
from render_service.main import create_app
from render_service.settings import ServiceSettings
from render_service.storage import NO_SPACE
from render_service.store import JobStore

pytestmark = [pytest.mark.service]

SPEC = {"kind": "skyline_db", "size_m": 20, "step_m": 10, "azimuths": 36, "tile_size": 2}  # 3 x 3, 4 tiles


@pytest.fixture(scope="module")
def service(tmp_path_factory, service_dem):
    settings = ServiceSettings(data_dir=tmp_path_factory.mktemp("faults") / "data", token=H.TOKEN, n_workers=1,
                               min_free_bytes=0)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        client.headers.update(H.AUTH)
        assert client.app.state.runner.wait_ready(120)
        r = client.post("/v1/dems", files={"file": ("dem.tif", service_dem.path.read_bytes())})
        assert r.status_code == 201, r.text
        yield client, r.json(), settings


def _wait(client, job_id, states, timeout=120.0):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        j = client.get(f"/v1/jobs/{job_id}").json()
        if j["state"] in states:
            return j
        time.sleep(0.2)
    raise TimeoutError(f"job {job_id} still {j['state']}")


def test_disk_full_in_the_failure_handler_does_not_kill_the_runner(service, monkeypatch):
    client, dem, settings = service
    runner = client.app.state.runner
    real_set_state = JobStore.set_state
    disk_full = {"on": True}

    def zip_on_a_full_disk(folder, zip_path, *, arcroot):
        zip_path.with_name(zip_path.name + ".tmp").write_bytes(b"PK partial")  # what a full disk leaves
        raise OSError(errno.ENOSPC, "No space left on device", str(zip_path))

    def set_state(self, *, job_id, state, **kw):
        if disk_full["on"] and state == "failed":
            raise sqlite3.OperationalError("database or disk is full")
        return real_set_state(self, job_id=job_id, state=state, **kw)

    monkeypatch.setattr(runner_mod, "write_result_zip", zip_on_a_full_disk)
    monkeypatch.setattr(JobStore, "set_state", set_state)
    a = client.post("/v1/jobs", json={**SPEC, "dem_id": dem["id"], "center": dem["center"]}).json()
    j = _wait(client, a["id"], ("failed", "done"))
    assert j["state"] == "failed" and j["error"] == NO_SPACE, j  # shown although not yet written
    assert runner.alive()
    health = client.get("/healthz").json()
    assert health["status"] == "degraded" and "not recorded" in health["detail"], health
    assert JobStore(settings.store_path).get_job(job_id=a["id"]).state == "running"  # the store could not be written
    jdir = settings.jobs_dir / a["id"]
    assert not [p.name for p in jdir.iterdir() if ".tmp" in p.name], "temporary files left behind"

    b = client.post("/v1/jobs", json={**SPEC, "dem_id": dem["id"], "center": dem["center"], "azimuths": 72}).json()
    time.sleep(2.0)
    assert client.get(f"/v1/jobs/{b['id']}").json()["state"] == "queued"  # nothing starts while degraded

    disk_full["on"] = False  # space is back
    monkeypatch.setattr(runner_mod, "write_result_zip", _real_zip())
    jb = _wait(client, b["id"], ("done", "failed"))
    assert jb["state"] == "done", jb  # the queue continued
    _assert_cli_terrain_levels(settings.jobs_dir / b["id"] / "db.zarr", dem, tmp=settings.data_dir.parent)
    stored = JobStore(settings.store_path).get_job(job_id=a["id"])
    assert (stored.state, stored.error) == ("failed", NO_SPACE)  # the failure was written once possible
    assert client.get("/healthz").json()["status"] == "ok"
    again = client.post("/v1/jobs", json={**SPEC, "dem_id": dem["id"], "center": dem["center"]}).json()
    assert again["id"] == a["id"] and again["state"] == "queued"
    ja = _wait(client, a["id"], ("done", "failed"))
    assert ja["state"] == "done" and ja["tiles_done"] == 4, ja
    assert max(JobStore(settings.store_path).render_counts(job_id=a["id"]).values()) == 1  # resumed, not redone


def _assert_cli_terrain_levels(db_path, dem, *, tmp):
    """The service database carries the CLI's ``terrain_levels`` metadata (same grid rendered by the CLI)."""
    from board.skydb import SkyDB
    from render_service.dbrender import render_database
    from render_service.renderers.base import RenderSpec

    service = SkyDB.open(db_path).meta.extra
    store = JobStore(tmp / "data" / "skyloc.sqlite")
    cli = render_database(store.get_dem(dem_id=dem["id"]).path, center_xy=tuple(dem["center"]), size_m=20,
                          step_m=10, spec=RenderSpec(camera_height_m=2.0, n_azimuth=72), out=tmp / "cli.zarr",
                          tile_size=2, progress=False).meta.extra
    assert cli["terrain_levels"] and service["terrain_levels"] == cli["terrain_levels"]


def _real_zip():
    from render_service.result_zip import write_result_zip

    return write_result_zip


def test_job_errors_show_no_server_paths(service, monkeypatch):
    client, dem, settings = service
    data = str(settings.data_dir)

    def zip_fails(folder, zip_path, *, arcroot):
        raise RuntimeError(f"cannot read {folder}/zarr.json (nor /etc/skyloc/secret.conf)")

    monkeypatch.setattr(runner_mod, "write_result_zip", zip_fails)
    a = client.post("/v1/jobs", json={**SPEC, "dem_id": dem["id"], "center": dem["center"], "azimuths": 90}).json()
    j = _wait(client, a["id"], ("failed", "done"))
    assert j["state"] == "failed"
    assert data not in j["error"] and "/etc/skyloc" not in j["error"], j["error"]
    assert "cannot read <data>/jobs/" in j["error"] and "<file>" in j["error"], j["error"]
    page = client.get("/").text
    assert data not in page and "/etc/skyloc" not in page
