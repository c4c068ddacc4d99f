"""Helpers for the render-service tests: a real `skyloc serve` subprocess on 127.0.0.1, test rasters and analytic
terrains."""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np

from blender_addon.terrain.model import MultiResTerrain, TerrainLevel
from board.conventions import Body

REPO = Path(__file__).resolve().parents[2]
TOKEN = "test-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """`python -m skyloc.cli serve` on a free loopback port, with a LocalCluster of ``workers`` processes."""

    def __init__(self, data_dir: Path, *, workers: int = 2, token: str | None = TOKEN,
                 env: dict[str, str] | None = None, log_dir: Path | None = None) -> None:
        self.data_dir = Path(data_dir)
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        full_env = dict(os.environ)
        full_env.pop("SKYLOC_TOKEN", None)
        if token is not None:
            full_env["SKYLOC_TOKEN"] = token
        full_env.update(env or {})
        env = full_env
        self.log_path = Path(log_dir or self.data_dir.parent) / f"server-{self.port}.log"
        self.log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "skyloc.cli", "serve", "--host", "127.0.0.1", "--port", str(self.port),
             "--data", str(self.data_dir), "--workers", str(workers), "--log-level", "warning"],
            cwd=REPO, env=env, stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True)
        self.client = httpx.Client(base_url=self.url, headers=AUTH, timeout=30.0)
        self.wait_up()

    def wait_up(self, timeout: float = 60.0) -> None:
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}: {self.read_log()}")
            try:
                if httpx.get(self.url + "/healthz", timeout=2).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        raise RuntimeError(f"server did not come up: {self.read_log()}")

    def read_log(self) -> str:
        self.log.flush()
        return self.log_path.read_text(errors="replace")[-4000:]

    def upload(self, path: Path, *, name: str | None = None, body: str | None = None) -> httpx.Response:
        data = {"body": body} if body else None
        with open(path, "rb") as fh:
            return self.client.post("/v1/dems", files={"file": (name or path.name, fh)}, data=data)

    def wait_job(self, job_id: str, *, states=("done", "failed", "cancelled"), timeout: float = 240.0) -> dict:
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            j = self.client.get(f"/v1/jobs/{job_id}").json()
            if j["state"] in states:
                return j
            time.sleep(0.2)
        raise TimeoutError(f"job {job_id} still {j['state']} after {timeout} s; log: {self.read_log()}")

    def wait_tiles(self, job_id: str, n: int, *, timeout: float = 240.0) -> dict:
        """Poll the job until at least ``n`` tiles are done (or ``timeout`` s); returns its last status."""
        t_end = time.monotonic() + timeout
        while True:
            j = self.client.get(f"/v1/jobs/{job_id}").json()
            if j["tiles_done"] >= n or time.monotonic() >= t_end:
                return j
            time.sleep(0.05)

    def kill9(self) -> None:
        """SIGKILL the server process only (its Dask workers notice their parent died and exit)."""
        os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.wait(10)
        self.client.close()

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(10)
        self.client.close()
        self.log.close()


def write_tif(path: Path, array: np.ndarray, *, epsg: int | None = None, wkt: str | None = None,
              gt=(500000.0, 10.0, 0.0, 4000000.0, 0.0, -10.0), nodata: float | None = None) -> Path:
    """A single-band float32 GeoTIFF (GDAL) of ``array`` with the given CRS and geotransform."""
    from osgeo import gdal, osr

    ds = gdal.GetDriverByName("GTiff").Create(str(path), array.shape[1], array.shape[0], 1, gdal.GDT_Float32)
    ds.SetGeoTransform(gt)
    if epsg is not None or wkt is not None:
        srs = osr.SpatialReference()
        srs.ImportFromEPSG(epsg) if epsg is not None else srs.ImportFromWkt(wkt)
        ds.SetProjection(srs.ExportToWkt())
    band = ds.GetRasterBand(1)
    if nodata is not None:
        band.SetNoDataValue(nodata)
    band.WriteArray(array.astype(np.float32))
    ds = None
    return path


def write_huge_sparse_tif(path: Path, size: int = 40_000) -> Path:
    """A tiny file declaring a size x size raster (sparse GeoTIFF: no tile is written)."""
    from osgeo import gdal

    opts = ["TILED=YES", "BLOCKXSIZE=1024", "BLOCKYSIZE=1024", "SPARSE_OK=TRUE", "BIGTIFF=YES"]
    ds = gdal.GetDriverByName("GTiff").Create(str(path), size, size, 1, gdal.GDT_Float32, options=opts)
    ds.SetGeoTransform((500000.0, 1.0, 0.0, 4000000.0, 0.0, -1.0))
    from osgeo import osr

    srs = osr.SpatialReference()
    srs.ImportFromEPSG(32633)
    ds.SetProjection(srs.ExportToWkt())
    ds = None
    return path


def analytic_terrain(fn, levels, *, center=(0.0, 0.0), radius_m=1e5) -> MultiResTerrain:
    """Nested square levels [(half_extent_m, cell_m), ...] (finest first) sampling fn(x, y) at cell centres."""
    out = []
    for half, cell in levels:
        n = int(round(2 * half / cell))
        x0, y0 = center[0] - half, center[1] + half
        xs = x0 + (np.arange(n) + 0.5) * cell
        ys = y0 - (np.arange(n) + 0.5) * cell
        X, Y = np.meshgrid(xs, ys)
        out.append(TerrainLevel(np.asarray(fn(X, Y), dtype=np.float32), x0, y0, cell))
    return MultiResTerrain(out, 'LOCAL_CS["analytic"]', Body("custom", radius_m), center)
