"""The multi-node layout of the service image, as separate processes from the installed environment.

A Dask scheduler, two Dask workers and the API server are started by the image's entry point
(``scripts/image_entrypoint.sh``, the ``scheduler`` / ``worker`` / ``api`` roles, exactly the commands
compose.yaml runs), with Dask TLS from a CA and node certificate made by the image's ``tls`` role.  A database
job is split across both workers (36 tiles), one worker (nanny and process) is killed with SIGKILL mid-job, the job
finishes on the other, and the database equals the single-process render of ``skyloc db render``'s code
path (:func:`render_service.dbrender.render_database`) tile for tile.  A client without the certificates
cannot connect to the scheduler.
"""
from __future__ import annotations

import os
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
import skyloc_service_test_helpers as H  # registered by tests/conftest.py

from board.skydb import SkyDB
from render_service.store import JobStore

pytestmark = [pytest.mark.service, pytest.mark.slow, pytest.mark.timeout(240)]

ENTRY = H.REPO / "scripts" / "image_entrypoint.sh"
# 40 m at 2 m: 21 x 21 positions in tiles of 4 -> 6 x 6 = 36 tiles, 36 azimuths (10 degrees)
JOB = {"kind": "skyline_db", "size_m": 40, "step_m": 2, "azimuths": 36, "tile_size": 4, "camera_height_m": 1.5}
N_TILES = 36


def make_tls(folder: Path) -> dict[str, Path]:
    """A CA and a node certificate for 127.0.0.1 made by the image's ``tls`` role (openssl), owned by us."""
    env = {**os.environ, "SKYLOC_TLS_OWNER": f"{os.getuid()}:{os.getgid()}", "SKYLOC_TLS_DAYS": "2"}
    subprocess.run(["sh", str(ENTRY), "tls", str(folder), "localhost"], check=True, capture_output=True, env=env)
    assert (folder / "node.key").stat().st_mode & 0o077 == 0  # the private keys are private
    return {"ca": folder / "ca.pem", "cert": folder / "node.pem", "key": folder / "node.key"}


class Role:
    """One role of the image's entry point as its own process group (log in ``work/<name>.log``)."""

    def __init__(self, name: str, role: str, work: Path, env: dict[str, str], *args: str) -> None:
        self.name = name
        self.log_path = work / f"{name}.log"
        self._log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(["sh", str(ENTRY), role, *args], env=env, cwd=work, stdout=self._log,
                                     stderr=subprocess.STDOUT, start_new_session=True)

    def log(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors="replace")[-3000:]

    def alive(self) -> bool:
        return self.proc.poll() is None

    def kill9(self) -> None:
        """SIGKILL the whole process group (the node is gone: nanny and worker process)."""
        os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait(10)

    def stop(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(10)
        self._log.close()


def wait_port(port: int, role: Role, timeout: float = 60.0) -> None:
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        assert role.alive(), f"{role.name} exited: {role.log()}"
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return
        except OSError:
            time.sleep(0.2)
    raise TimeoutError(f"{role.name} not listening on {port}: {role.log()}")


@pytest.fixture(scope="module")
def deployment(tmp_path_factory):
    """Scheduler + 2 workers + API (TLS between them), each a process started by the image's entry point."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is needed to make the test's TLS certificates")
    work = tmp_path_factory.mktemp("multinode")
    tls = make_tls(work / "tls")
    base = {k: v for k, v in os.environ.items() if not k.startswith(("DASK_", "SKYLOC_"))}
    base.update(PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
                SKYLOC_TLS_CA_FILE=str(tls["ca"]), SKYLOC_TLS_CERT=str(tls["cert"]), SKYLOC_TLS_KEY=str(tls["key"]),
                SKYLOC_BIND_HOST="127.0.0.1", PYTHONPATH=str(H.REPO))
    sched_port, api_port = H.free_port(), H.free_port()
    scheduler_addr = f"tls://127.0.0.1:{sched_port}"
    roles: list[Role] = []
    try:
        sched = Role("scheduler", "scheduler", work, {**base, "SKYLOC_DASK_PORT": str(sched_port),
                                                        "SKYLOC_ROLE_FILE": str(work / "role-scheduler")})
        roles.append(sched)
        wait_port(sched_port, sched)
        workers = []
        for i in (1, 2):
            env = {**base, "SKYLOC_SCHEDULER": scheduler_addr, "SKYLOC_ROLE_FILE": str(work / f"role-w{i}"),
                   "SKYLOC_WORKER_DIR": str(work / f"w{i}")}
            w = Role(f"worker{i}", "worker", work, env, "--name", f"w{i}", "--host", "127.0.0.1")
            roles.append(w)
            workers.append(w)
        api = Role("api", "api", work, {**base, "SKYLOC_SCHEDULER": scheduler_addr, "SKYLOC_PORT": str(api_port),
                                        "SKYLOC_DATA_DIR": str(work / "data"), "SKYLOC_TOKEN": H.TOKEN,
                                        "SKYLOC_ROLE_FILE": str(work / "role-api")}, "--log-level", "warning")
        roles.append(api)
        url = f"http://127.0.0.1:{api_port}"
        t_end = time.monotonic() + 90
        health = None
        while time.monotonic() < t_end:
            for r in roles:
                assert r.alive(), f"{r.name} exited: {r.log()}"
            try:
                health = httpx.get(url + "/healthz", timeout=2).json()
                if health.get("workers") == 2:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.3)
        assert health and health.get("workers") == 2, (health, [r.log() for r in roles])
        client = httpx.Client(base_url=url, headers=H.AUTH, timeout=30.0)
        yield {"work": work, "tls": tls, "scheduler": scheduler_addr, "sched_port": sched_port, "roles": roles,
               "workers": workers, "api": api, "client": client, "data": work / "data", "health": health}
        client.close()
    finally:
        for r in reversed(roles):
            r.stop()


def renders_by_worker(store_path: Path, job_id: str) -> list[tuple[str, str, float]]:
    """(tile key, worker address, finish time) of every completed render of ``job_id``."""
    with sqlite3.connect(store_path) as con:
        return con.execute("SELECT tile_key, worker, finished FROM tile_renders WHERE job_id = ? ORDER BY finished",
                           (job_id,)).fetchall()


def worker_addresses(d) -> dict[str, str]:
    """Worker name -> address as the scheduler sees them (a TLS client with the deployment's certificates)."""
    from distributed import Client
    from distributed.security import Security

    sec = Security(tls_ca_file=str(d["tls"]["ca"]), tls_client_cert=str(d["tls"]["cert"]),
                   tls_client_key=str(d["tls"]["key"]), require_encryption=True)
    with Client(d["scheduler"], security=sec, timeout=20) as c:
        return {w["name"]: addr for addr, w in c.scheduler_info(n_workers=-1)["workers"].items()}


def test_scheduler_refuses_a_client_without_the_certificates(deployment):
    from distributed import Client
    from distributed.security import Security

    with pytest.raises((OSError, TimeoutError)):
        Client(f"tcp://127.0.0.1:{deployment['sched_port']}", timeout=3)
    rogue = make_tls(deployment["work"] / "rogue-tls")  # TLS, but certificates of another CA
    sec = Security(tls_ca_file=str(rogue["ca"]), tls_client_cert=str(rogue["cert"]), tls_client_key=str(rogue["key"]),
                   require_encryption=True)
    with pytest.raises((OSError, TimeoutError)):
        Client(deployment["scheduler"], timeout=3, security=sec)


def test_job_split_across_two_workers_survives_a_killed_worker(deployment, service_dem):
    d = deployment
    c = d["client"]
    assert d["health"]["status"] == "ok" and d["health"]["workers"] == 2
    names = worker_addresses(d)
    assert sorted(names) == ["w1", "w2"] and all(a.startswith("tls://") for a in names.values())

    up = c.post("/v1/dems", files={"file": (service_dem.path.name, service_dem.path.read_bytes())})
    assert up.status_code == 201, up.text
    dem = up.json()
    sub = c.post("/v1/jobs", json={**JOB, "dem_id": dem["id"], "center": dem["center"]})
    assert sub.status_code == 202, sub.text
    job_id = sub.json()["id"]
    store = d["data"] / "skyloc.sqlite"

    # wait until both workers have rendered tiles, then kill worker 1 (nanny and process) mid-job
    t_end = time.monotonic() + 120
    while time.monotonic() < t_end:
        done = renders_by_worker(store, job_id) if store.exists() else []
        if {w for _, w, _ in done} >= set(names.values()) and len(done) >= 4:
            break
        assert c.get(f"/v1/jobs/{job_id}").json()["state"] in ("queued", "running")
        time.sleep(0.05)
    else:
        pytest.fail(f"both workers never rendered: {renders_by_worker(store, job_id)}")
    d["workers"][0].kill9()
    t_kill = time.time()
    j = c.get(f"/v1/jobs/{job_id}").json()
    assert j["state"] == "running" and j["tiles_done"] < N_TILES, j  # the kill landed mid-job

    t_end = time.monotonic() + 150
    while (j := c.get(f"/v1/jobs/{job_id}").json())["state"] in ("queued", "running") and time.monotonic() < t_end:
        time.sleep(0.2)
    assert j["state"] == "done", (j, d["api"].log())
    assert j["tiles_done"] == N_TILES

    renders = renders_by_worker(store, job_id)
    counts = JobStore(store).render_counts(job_id=job_id)
    assert len(counts) == N_TILES  # every tile rendered (a tile killed mid-render is simply rendered again)
    by_worker = {w for _, w, _ in renders}
    assert by_worker == set(names.values()), by_worker  # split across both workers
    # after the kill only the survivor renders (a worker writes its render's row itself when it ends, so the killed
    # one can write none after the kill: 0.2 s of slack for the signal), and it renders what was left: under load
    # the rest may take it less than a second, so no margin on that side
    assert {w for _, w, f in renders if f > t_kill + 0.2} <= {names["w2"]}
    assert any(w == names["w2"] and f > t_kill for _, w, f in renders)
    t_end = time.monotonic() + 20
    while c.get("/healthz").json()["workers"] != 1 and time.monotonic() < t_end:
        time.sleep(0.3)
    assert c.get("/healthz").json()["workers"] == 1  # the scheduler saw the node go

    res = c.get(f"/v1/jobs/{job_id}/result")
    assert res.status_code == 200
    db = SkyDB.open(d["data"] / "jobs" / job_id / "db.zarr")
    assert db.complete

    # the single-process run of the same grid (the CLI's code path, no Dask, no service)
    from board.skydb import AZIMUTH_SUBSAMPLES
    from render_service.dbrender import render_database
    from render_service.renderers.base import RenderSpec

    ref = render_database(service_dem.path, center_xy=tuple(dem["center"]), size_m=JOB["size_m"],
                          step_m=JOB["step_m"], spec=RenderSpec(camera_height_m=JOB["camera_height_m"], n_azimuth=JOB["azimuths"],
                                          azimuth_subsamples=AZIMUTH_SUBSAMPLES),   # the job's default
                          out=d["work"] / "single.zarr", tile_size=JOB["tile_size"], progress=False)
    assert [t.key for t in ref.tiles] == [t.key for t in db.tiles]
    for t in ref.tiles:
        np.testing.assert_array_equal(db.read_tile_raw(t), ref.read_tile_raw(t), err_msg=t.key)
