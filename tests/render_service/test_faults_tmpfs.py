"""Real storage faults on a small tmpfs: a full disk mid-job (point 3) and a read-only data directory (point 4).

Needs ``mount`` (root, as in CI); skipped otherwise -- ``test_faults_runner.py`` injects the same faults at
the job store's seam and always runs.

* start-up on a read-only data directory is refused with the reason;
* a data directory remounted read-only under a running API: uploads and submissions answer 503
  ``storage_unavailable`` with the reason (not 500), ``/healthz`` is ``degraded`` until it is writable again;
* a real ``skyloc serve`` whose disk fills up mid-job: the job ends ``failed`` with a reason a user can
  act on, no temporary file is left, ``/healthz`` is ``degraded``; once space is freed it is ``ok`` again and
  the same job submitted again resumes (no tile rendered twice) and completes.
"""
from __future__ import annotations

import errno
import subprocess
import time
from contextlib import contextmanager
from pathlib import Path

import pytest
import skyloc_service_test_helpers as H  # registered by tests/conftest.py
from fastapi.testclient import TestClient

from board.errors import InvalidInputError
from render_service.main import create_app
from render_service.settings import ServiceSettings
from render_service.storage import NO_SPACE
from render_service.store import JobStore

pytestmark = [pytest.mark.service]


@contextmanager
def tmpfs(path: Path, size: str, *, read_only: bool = False):
    path.mkdir(parents=True, exist_ok=True)
    opts = f"size={size},mode=0755" + (",ro" if read_only else "")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", opts, "tmpfs", str(path)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({r.stderr.strip()}); test_faults_runner.py injects the faults")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], capture_output=True)


def fill_disk(folder: Path) -> Path:
    """Write a file until the file system is full; returns it."""
    filler = folder / "filler.bin"
    with open(filler, "wb", buffering=0) as fh:
        for size in (1 << 20, 1 << 12):
            block = b"\xff" * size
            try:
                while True:
                    fh.write(block)
            except OSError as exc:
                assert exc.errno == errno.ENOSPC, exc
    return filler


def test_startup_refuses_a_read_only_data_directory(tmp_path):
    with tmpfs(tmp_path / "ro", "1m", read_only=True) as mnt:
        with pytest.raises(InvalidInputError, match=r"cannot write the data directory .*Read-only file system"):
            create_app(ServiceSettings(data_dir=mnt / "data", token=H.TOKEN, start_cluster=False))
        with pytest.raises(InvalidInputError, match="Read-only file system"):
            create_app(ServiceSettings(data_dir=mnt, token=H.TOKEN, start_cluster=False))


def test_read_only_at_run_time_answers_503_and_health_degrades(tmp_path, service_dem):
    """A read-only file system mounted over DATA/dems under a running API (a remount of the whole folder is
    refused by the kernel while SQLite holds it open): uploads answer 503, /healthz degrades, then recovers."""
    dem_bytes = service_dem.path.read_bytes()
    settings = ServiceSettings(data_dir=tmp_path / "data", token=H.TOKEN, start_cluster=False, min_free_bytes=0)
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        c.headers.update(H.AUTH)
        dem = c.post("/v1/dems", files={"file": ("dem.tif", dem_bytes)}).json()
        assert c.get("/healthz").json()["status"] == "ok"
        with tmpfs(settings.dems_dir, "1m", read_only=True):
            up = c.post("/v1/dems", files={"file": ("dem.tif", dem_bytes)}, data={"body": "moon"})
            assert up.status_code == 503, up.text
            assert up.json()["code"] == "storage_unavailable" and "cannot write" in up.json()["detail"]
            assert str(tmp_path) not in up.text
            h = c.get("/healthz").json()
            assert h["status"] == "degraded" and "not writable" in h["detail"], h
            job = c.post("/v1/jobs", json={"kind": "skyline_db", "dem_id": dem["id"], "center": dem["center"],
                                           "size_m": 20, "step_m": 10, "azimuths": 36, "tile_size": 2})
            assert job.status_code == 202, job.text  # the job store still takes it: it waits in the queue
        time.sleep(1.1)  # the monitor re-checks at most once a second
        assert c.get("/healthz").json()["status"] == "ok"
        again = c.post("/v1/dems", files={"file": ("dem.tif", dem_bytes)}, data={"body": "moon"})
        assert again.status_code == 201, again.text


@pytest.mark.slow
def test_disk_full_mid_job_fails_it_with_a_reason_and_the_queue_recovers(tmp_path, service_dem):
    with tmpfs(tmp_path / "disk", "64m") as mnt:
        srv = H.Server(mnt / "data", workers=1, env={"SKYLOC_MIN_FREE_BYTES": str(2 << 20)}, log_dir=tmp_path)
        try:
            dem = srv.upload(service_dem.path).json()
            spec = {"kind": "skyline_db", "dem_id": dem["id"], "center": dem["center"], "size_m": 150, "step_m": 3,
                    "azimuths": 36, "tile_size": 6}  # 51 x 51 positions, 81 tiles
            job_id = srv.client.post("/v1/jobs", json=spec).json()["id"]
            srv.wait_tiles(job_id, 2)
            filler = fill_disk(mnt)
            j = srv.wait_job(job_id, timeout=120)
            assert j["state"] == "failed" and j["error"] == NO_SPACE, j
            assert 2 <= j["tiles_done"] < j["tiles_total"]
            h = srv.client.get("/healthz").json()
            assert h["status"] == "degraded" and "space" in h["detail"], h
            jdir = mnt / "data" / "jobs" / job_id
            assert not [p.name for p in jdir.iterdir() if ".tmp" in p.name], list(jdir.iterdir())

            filler.unlink()  # space is back
            t_end = time.monotonic() + 30
            while srv.client.get("/healthz").json()["status"] != "ok" and time.monotonic() < t_end:
                time.sleep(0.2)
            assert srv.client.get("/healthz").json()["status"] == "ok"
            assert srv.client.get(f"/v1/jobs/{job_id}").json()["state"] == "failed"  # recorded in the store
            assert srv.client.post("/v1/jobs", json=spec).json()["state"] == "queued"
            j = srv.wait_job(job_id, timeout=300)
            assert j["state"] == "done", (j, srv.read_log())
            counts = JobStore(mnt / "data" / "skyloc.sqlite").render_counts(job_id=job_id)
            assert len(counts) == 81 and max(counts.values()) == 1
        finally:
            srv.stop()
