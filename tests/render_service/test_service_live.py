"""The render service end to end: a real `skyloc serve` (uvicorn) subprocess on 127.0.0.1 with a Dask
LocalCluster of worker processes, a real DEM (HiRISE Gale crater patch, 1 m, Mars), or a procedural
Mars DEM (1 m) when ../shared/data/dems is absent (``service_dem``, tests/render_service/conftest.py).

* clean run: upload, submit, poll, download the zip (also by ranges), verify its checksum manifest,
  open it with board.skydb.SkyDB, and compare it with the CLI's renderer run in this process;
* crash run: kill -9 the server mid-job, restart it on the same data folder, and the job completes with
  a database identical to the clean run and no tile rendered twice (the store's tile-render log);
* cancel, bad inputs against the live server, and the `/` page in headless Chromium.
"""
from __future__ import annotations

import hashlib
import importlib.util
import io
import json
import os
import shutil
import subprocess
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import skyloc_service_test_helpers as H  # registered by tests/conftest.py

from board.skydb import SkyDB
from render_service.store import JobStore

pytestmark = [pytest.mark.service, pytest.mark.slow]

# 100 m at 2 m: 51 x 51 positions, tiles of 6 -> 9 x 9 = 81 tiles, 72 azimuths (5 degrees)
JOB = {"kind": "skyline_db", "size_m": 100, "step_m": 2, "azimuths": 72, "tile_size": 6, "camera_height_m": 1.5}


def job_spec(dem: dict, **kw) -> dict:
    return {**JOB, "dem_id": dem["id"], "center": dem["center"], **kw}


def unzip(data: bytes, dest: Path) -> Path:
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        zf.extractall(dest)
    return dest


def check_manifest(folder: Path) -> list[str]:
    lines = (folder / "MANIFEST.sha256").read_text().splitlines()
    files = sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file() and p.name != "MANIFEST.sha256")
    assert sorted(line.split("  ", 1)[1] for line in lines) == files
    for line in lines:
        digest, rel = line.split("  ", 1)
        assert hashlib.sha256((folder / rel).read_bytes()).hexdigest() == digest, rel
    return lines


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("service")


@pytest.fixture(scope="module")
def server_a(work):
    srv = H.Server(work / "data_a", workers=2)
    yield srv
    srv.stop()


@pytest.fixture(scope="module")
def clean_run(server_a, work, service_dem):
    """Upload the DEM, render JOB, download the result: (job, dem, zip bytes, extracted folder)."""
    r = server_a.upload(service_dem.path)
    assert r.status_code == 201, r.text
    dem = r.json()
    sub = server_a.client.post("/v1/jobs", json=job_spec(dem))
    assert sub.status_code == 202, sub.text
    job = server_a.wait_job(sub.json()["id"])
    assert job["state"] == "done", job
    res = server_a.client.get(job["result_url"])
    assert res.status_code == 200 and res.headers["content-type"] == "application/zip"
    return job, dem, res.content, unzip(res.content, work / "clean")


def test_clean_run_result_opens_and_matches_the_cli_renderer(clean_run, service_dem, work):
    job, dem, data, folder = clean_run
    assert (job["tiles_done"], job["tiles_total"], job["positions_total"]) == (81, 81, 51 * 51)
    assert hashlib.sha256(data).hexdigest() == job["result_sha256"] and len(data) == job["result_bytes"]
    check_manifest(folder)
    db = SkyDB.open(folder / "db.zarr")
    assert db.complete and db.shape == (51, 51, 72) and db.meta.body == service_dem.body
    assert db.meta.camera_height_m == 1.5 and db.meta.dem_sha256 == dem["sha256"]
    assert db.grid.bounds() == pytest.approx((dem["center"][0] - 50, dem["center"][1] - 50,
                                              dem["center"][0] + 50, dem["center"][1] + 50))
    got = np.concatenate([db.read_tile_raw(t).reshape(-1, 72) for t in db.tiles])
    assert (got != -32768).all()  # every position rendered
    # the same database through the CLI's code path (one process, no Dask, no service)
    from board.skydb import AZIMUTH_SUBSAMPLES
    from render_service.dbrender import render_database
    from render_service.renderers.base import RenderSpec

    ref = render_database(service_dem.path, center_xy=tuple(dem["center"]), size_m=100, step_m=2,
                          spec=RenderSpec(camera_height_m=1.5, n_azimuth=72, azimuth_subsamples=AZIMUTH_SUBSAMPLES),
                          out=work / "cli.zarr",
                          tile_size=6, progress=False)
    want = np.concatenate([ref.read_tile_raw(t).reshape(-1, 72) for t in ref.tiles])
    np.testing.assert_array_equal(got, want)


def test_result_supports_range_requests(server_a, clean_run):
    job, _, data, _ = clean_run
    part = server_a.client.get(job["result_url"], headers={"Range": "bytes=100-1123"})
    assert part.status_code == 206 and part.content == data[100:1124]
    tail = server_a.client.get(job["result_url"], headers={"Range": f"bytes={len(data) - 10}-"})
    assert tail.status_code == 206 and tail.content == data[-10:]


def _children(pid: int) -> list[int]:
    out = []
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                stat = (p / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(p.name))
    return out


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def test_kill9_mid_job_resumes_to_an_identical_database(clean_run, work, service_dem):
    job_a, dem_a, _, clean = clean_run
    data_b = work / "data_b"
    srv = H.Server(data_b, workers=2)
    try:
        dem = srv.upload(service_dem.path).json()
        job_id = srv.client.post("/v1/jobs", json=job_spec(dem)).json()["id"]
        assert job_id == job_a["id"]  # same spec, same job id on any server
        srv.wait_tiles(job_id, 3)
        workers = _children(srv.proc.pid)
        srv.kill9()
    except BaseException:
        srv.stop()
        raise
    store = JobStore(data_b / "skyloc.sqlite")
    before = store.render_counts(job_id=job_id)
    n_before = sum(before.values())
    assert 3 <= n_before < 81, f"the kill must land mid-job ({n_before} of 81 tiles rendered)"
    assert store.get_job(job_id=job_id).state == "running"
    # the LocalCluster's worker processes exit with their parent (no orphan keeps writing tiles)
    t_end = time.monotonic() + 30
    while any(_alive(p) for p in workers) and time.monotonic() < t_end:
        time.sleep(0.2)
    assert not any(_alive(p) for p in workers), "Dask worker processes outlived the killed server"

    srv2 = H.Server(data_b, workers=2)
    try:
        j = srv2.wait_job(job_id)
        assert j["state"] == "done", j
        crashed = unzip(srv2.client.get(j["result_url"]).content, work / "crashed")
    finally:
        srv2.stop()

    counts = store.render_counts(job_id=job_id)
    recovered = store.recovered_tiles(job_id=job_id)
    assert len(counts) == 81 and max(counts.values()) == 1, "a tile was rendered twice"
    assert {k for k, n in counts.items() if n == 0} <= recovered  # unrendered only if found written after the crash
    assert all(counts[k] == 1 for k, n in before.items() if n == 1)

    # identical database: every file of the Zarr store byte for byte, except the group's zarr.json whose
    # attributes must be equal apart from the creation time
    files_a = sorted(p.relative_to(clean) for p in (clean / "db.zarr").rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(crashed) for p in (crashed / "db.zarr").rglob("*") if p.is_file())
    assert files_a == files_b
    root = Path("db.zarr") / "zarr.json"
    for rel in files_a:
        if rel != root:
            assert (clean / rel).read_bytes() == (crashed / rel).read_bytes(), rel
    ja, jb = (json.loads((d / root).read_text()) for d in (clean, crashed))
    ja["attributes"].pop("created_utc"), jb["attributes"].pop("created_utc")
    assert ja == jb
    a, b = SkyDB.open(clean / "db.zarr"), SkyDB.open(crashed / "db.zarr")
    for t in a.tiles:
        np.testing.assert_array_equal(a.read_tile_raw(t), b.read_tile_raw(t))


def _dask_worker_pids(server_pid: int) -> list[int]:
    pids = []
    for pid in _children(server_pid):
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            continue
        if b"spawn_main" in cmd:
            pids.append(pid)
    return pids


def test_kill9_of_a_worker_mid_job_loses_and_repeats_nothing(server_a, clean_run):
    _, dem, _, _ = clean_run
    job_id = server_a.client.post("/v1/jobs", json=job_spec(dem, camera_height_m=1.7)).json()["id"]
    server_a.wait_tiles(job_id, 3)
    workers = _dask_worker_pids(server_a.proc.pid)
    assert workers, "no Dask worker process found under the server"
    os.kill(workers[0], 9)
    assert server_a.client.get(f"/v1/jobs/{job_id}").json()["state"] == "running"  # the kill landed mid-job
    j = server_a.wait_job(job_id)
    assert j["state"] == "done", j
    counts = JobStore(server_a.data_dir / "skyloc.sqlite").render_counts(job_id=job_id)
    assert len(counts) == 81 and max(counts.values()) == 1, counts
    db = SkyDB.open(server_a.data_dir / "jobs" / job_id / "db.zarr")
    assert db.complete and all((db.read_tile_raw(t) != -32768).all() for t in db.tiles)
    t_end = time.monotonic() + 60
    while server_a.client.get("/healthz").json()["workers"] != 2 and time.monotonic() < t_end:
        time.sleep(0.5)
    assert server_a.client.get("/healthz").json()["workers"] == 2  # the nanny restarted the worker


def test_failing_tiles_are_retried_then_the_job_fails_with_the_reason(server_a, clean_run):
    _, dem, _, _ = clean_run
    job_id = server_a.client.post("/v1/jobs", json=job_spec(dem, camera_height_m=1.9)).json()["id"]
    server_a.wait_tiles(job_id, 1)
    # damage the store under the running job (as a failing disk would): every later tile write fails
    (server_a.data_dir / "jobs" / job_id / "db.zarr" / "elevation" / "zarr.json").write_text("{broken")
    j = server_a.wait_job(job_id)
    assert j["state"] == "failed", j
    # 1 try + max_tile_retries=2, and the reason of the last failure (the store's damaged metadata)
    assert "failed 3 times" in j["error"] and ("corrupt" in j["error"] or "JSON" in j["error"]), j["error"]
    assert j["result_url"] is None and server_a.client.get(f"/v1/jobs/{job_id}/result").status_code == 409
    assert server_a.client.get("/healthz").json()["status"] == "ok"


def test_cancel_running_job_publishes_nothing(server_a, clean_run):
    _, dem, _, _ = clean_run
    sub = server_a.client.post("/v1/jobs", json=job_spec(dem, size_m=300, tile_size=8))  # 151 x 151, 361 tiles
    job_id = sub.json()["id"]
    server_a.wait_job(job_id, states=("running",))
    r = server_a.client.delete(f"/v1/jobs/{job_id}")
    assert r.status_code == 202 and r.json()["state"] in ("cancel-requested", "cancelled")
    j = server_a.wait_job(job_id, timeout=60)
    assert j["state"] == "cancelled" and j["tiles_done"] < j["tiles_total"]
    assert server_a.client.get(f"/v1/jobs/{job_id}/result").status_code == 409
    assert not (server_a.data_dir / "jobs" / job_id / "result.zip").exists()
    assert server_a.client.delete(f"/v1/jobs/{clean_run[0]['id']}").status_code == 409  # done: nothing to cancel


def test_bad_inputs_against_the_live_server(server_a, clean_run, tmp_path, service_dem):
    _, dem, _, _ = clean_run
    c = server_a.client
    png = tmp_path / "x.png"
    from osgeo import gdal

    gdal.GetDriverByName("PNG").CreateCopy(str(png), gdal.GetDriverByName("MEM").Create("", 8, 8, 1))
    cases = [
        c.post("/v1/dems", files={"file": ("x.tif", png.read_bytes())}),
        c.post("/v1/dems", files={"file": ("../../x.tif", service_dem.path.read_bytes())}),
        c.post("/v1/jobs", json=job_spec(dem, step_m=0)),
        c.post("/v1/jobs", json=job_spec(dem, size_m=50000)),
        c.post("/v1/jobs", json={"kind": "skyline_db"}),
        c.get("/v1/jobs", headers={"Authorization": "Bearer wrong-wrong-wrong-wrong"}),
        c.get("/v1/jobs", headers={"Authorization": ""}),
    ]
    for r in cases:
        assert 400 <= r.status_code < 500 and r.json()["detail"], r.text
    assert [r.status_code for r in cases[-2:]] == [401, 401]
    assert c.get("/healthz").json()["status"] == "ok"
    assert c.get(f"/v1/jobs/{clean_run[0]['id']}").json()["state"] == "done"


def test_status_page_in_headless_chromium(server_a, clean_run, tmp_path):
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("chromium is not installed (apt install chromium)")
    job_id = clean_run[0]["id"]
    url = f"http://skyloc:{H.TOKEN}@127.0.0.1:{server_a.port}/"
    args = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-dev-shm-usage", f"--user-data-dir={tmp_path / 'profile'}"]
    env = {**os.environ, "HOME": str(tmp_path)}
    dom = subprocess.run(args + ["--dump-dom", url], capture_output=True, text=True, timeout=90, env=env).stdout
    assert job_id in dom and 'role="progressbar"' in dom and "<polyline" in dom, dom[:2000]
    assert 'aria-valuenow="100"' in dom  # the finished job's bar is full
    shot = tmp_path / "status.png"
    subprocess.run(args + [f"--screenshot={shot}", "--window-size=1000,800", url], capture_output=True,
                   timeout=90, env=env)
    assert shot.is_file()
    from PIL import Image  # matplotlib's dependency

    img = np.asarray(Image.open(shot).convert("L"))
    assert img.std() > 5  # not a blank page


def test_dataset_job_renders_a_test_set(server_a, tmp_path):
    if importlib.util.find_spec("blender_addon.sim") is None or importlib.util.find_spec("bpy") is None:
        pytest.skip("the simulator's dataset generator (and bpy) are not installed")
    r = server_a.client.post("/v1/jobs", json={"kind": "dataset", "scene": "test_tiny"})
    assert r.status_code == 202, r.text
    j = server_a.wait_job(r.json()["id"], timeout=600)
    assert j["state"] == "done", j
    folder = unzip(server_a.client.get(j["result_url"]).content, tmp_path / "ds")
    check_manifest(folder)
    index = json.loads((folder / "dataset" / "dataset.json").read_text())
    assert index  # the generator's index of the sets it rendered
    frames = list((folder / "dataset").rglob("frame_*.png"))
    assert frames, "no rendered frame in the dataset"


def test_blender_renderer_job_agrees_with_the_raymarcher(server_a, clean_run):
    """The same positions rendered by Blender (a second, independent renderer) through the service."""
    if importlib.util.find_spec("bpy") is None:
        pytest.skip("bpy is not installed: the blender renderer is not available")
    job_a, dem, _, clean = clean_run
    # 3 x 3 positions 10 m apart: a subset of the clean run's 2 m grid (same centre)
    spec = job_spec(dem, size_m=20, step_m=10, tile_size=2, renderer="blender")
    r = server_a.client.post("/v1/jobs", json=spec)
    assert r.status_code == 202, r.text
    j = server_a.wait_job(r.json()["id"], timeout=600)
    assert j["state"] == "done", j
    bl = SkyDB.open(server_a.data_dir / "jobs" / j["id"] / "db.zarr")
    assert bl.meta.renderer == "blender"
    rm = SkyDB.open(clean / "db.zarr")
    got, want = [], []
    for i in range(3):
        for k in range(3):
            x, y = bl.grid.xy(i, k)
            ri, rk = (int(round(v)) for v in rm.grid.ij(float(x), float(y)))
            np.testing.assert_allclose(rm.grid.xy(ri, rk), (x, y), atol=1e-6)
            got.append(bl.skyline(i, k))
            want.append(rm.skyline(ri, rk))
    diff = np.abs(np.array(got) - np.array(want))
    assert np.isfinite(diff).all()
    assert np.median(diff) <= 0.1 and diff.max() <= 1.0, (np.median(diff), diff.max())
