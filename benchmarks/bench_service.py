"""Render-service benchmark: database throughput through the service vs the CLI, and status latency.

Run with ``make bench-service`` (or ``python -m benchmarks.bench_service --help``).  Everything runs on
this machine and talks only to 127.0.0.1:

1. the CLI, ``skyloc db render`` in a subprocess (one process, numba threads on every core);
2. the service, ``skyloc serve`` in a subprocess with a LocalCluster of ``--workers`` processes: the same
   database job submitted over HTTP and polled until done (after a small warm-up job, as a long-running
   service would be), wall time from POST to done;
3. status latency: while a larger job renders, ``--rounds`` bursts of ``--concurrency`` simultaneous
   ``GET /v1/jobs/{id}`` requests; p50 / p99 / max of the response times.

Prints a markdown table.  The machine is shared: figures are noisy, the ratio of the two runs (same
run, same DEM, same grid) is the meaningful number.
"""
from __future__ import annotations

import argparse
import asyncio
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

TOKEN = "bench-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_cli(dem: Path, center: tuple[float, float], args, out: Path, height: float = 2.0) -> float:
    """Wall seconds of `skyloc db render` for the benchmark grid."""
    cmd = [sys.executable, "-m", "skyloc.cli", "db", "render", "--dem", str(dem),
           "--center", f"{center[0]},{center[1]}", "--size", str(args.size), "--step", str(args.step),
           "--azimuths", str(args.azimuths),
           "--tile", str(args.tile), "--height", str(height), "--out", str(out), "--no-progress"]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


class Service:
    def __init__(self, data: Path, workers: int) -> None:
        self.port = _free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        env = {**os.environ, "SKYLOC_TOKEN": TOKEN}
        self.proc = subprocess.Popen([sys.executable, "-m", "skyloc.cli", "serve", "--host", "127.0.0.1",
                                      "--port", str(self.port), "--data", str(data), "--workers", str(workers),
                                      "--log-level", "warning"], env=env, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL, start_new_session=True)
        self.client = httpx.Client(base_url=self.url, headers=AUTH, timeout=60)
        t_end = time.monotonic() + 120
        while time.monotonic() < t_end:
            try:
                if self.client.get("/healthz").status_code == 200:
                    return
            except httpx.HTTPError:
                time.sleep(0.2)
        raise RuntimeError("the service did not start")

    def submit(self, spec: dict) -> str:
        r = self.client.post("/v1/jobs", json=spec)
        r.raise_for_status()
        return r.json()["id"]

    def wait(self, job_id: str, states=("done", "failed")) -> dict:
        while True:
            j = self.client.get(f"/v1/jobs/{job_id}").json()
            if j["state"] in states:
                return j
            time.sleep(0.1)

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)


def status_latency(svc: Service, job_id: str, *, concurrency: int, rounds: int) -> tuple[np.ndarray, bool]:
    lat: list[float] = []
    for _ in range(rounds):
        lat += asyncio.run(_burst_path(svc.url, f"/v1/jobs/{job_id}", concurrency))
    seq: list[float] = []
    for _ in range(100):  # one request at a time: the floor under the same rendering load
        seq += asyncio.run(_burst_path(svc.url, f"/v1/jobs/{job_id}", 1))
    still_running = svc.client.get(f"/v1/jobs/{job_id}").json()["state"] == "running"
    return np.array(lat), np.array(seq), still_running


async def _burst_path(base: str, path: str, n: int) -> list[float]:
    """``n`` simultaneous GETs, each on its own new connection (raw asyncio sockets: the client adds
    almost nothing to the measured time); seconds from connect to the last byte of each response."""
    host, port = base.split("//")[1].split(":")
    request = (f"GET {path} HTTP/1.1\r\nHost: {host}\r\nAuthorization: {AUTH['Authorization']}\r\n"
               "Connection: close\r\n\r\n").encode()

    async def one() -> float:
        t0 = time.perf_counter()
        reader, writer = await asyncio.open_connection(host, int(port))
        writer.write(request)
        await writer.drain()
        data = await reader.read()
        writer.close()
        if not data.startswith(b"HTTP/1.1 200"):
            raise RuntimeError(f"status request failed: {data[:200]!r}")
        return time.perf_counter() - t0

    return list(await asyncio.gather(*[one() for _ in range(n)]))


_DEM_MEMORY_SCRIPT = """
import json, resource, sys
from fastapi.testclient import TestClient
from render_service.main import create_app
from render_service.settings import ServiceSettings
data, tif, token, cache = sys.argv[1:5]
if cache == "unbounded":
    from osgeo import gdal
    import render_service.main as m
    m._limit_gdal_cache = lambda nbytes: None  # the behaviour before the bound
    import render_service.api.routes.dems as d, contextlib
    d.validation_cache = lambda *a, **k: contextlib.nullcontext()
s = ServiceSettings(data_dir=data, token=token, start_cluster=False)
with TestClient(create_app(s)) as c:
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with open(tif, "rb") as fh:
        r = c.post("/v1/dems", files={"file": ("sparse.tif", fh.read())}, headers={"Authorization": "Bearer " + token})
    after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"status": r.status_code, "before_mb": before / 1024, "peak_mb": after / 1024}))
"""


def dem_memory(size: int = 30_000) -> list[str]:
    """Peak RSS of a fresh API process validating a ``size`` x ``size`` sparse GeoTIFF upload (bounded vs not)."""
    import json

    from osgeo import gdal, osr

    work = Path(tempfile.mkdtemp(prefix="skyloc-bench-demmem-"))
    try:
        tif = work / "sparse.tif"
        opts = ["TILED=YES", "BLOCKXSIZE=1024", "BLOCKYSIZE=1024", "SPARSE_OK=TRUE", "BIGTIFF=YES"]
        ds = gdal.GetDriverByName("GTiff").Create(str(tif), size, size, 1, gdal.GDT_Float32, options=opts)
        ds.SetGeoTransform((500000.0, 1.0, 0.0, 4000000.0, 0.0, -1.0))
        srs = osr.SpatialReference()
        srs.ImportFromEPSG(32633)
        ds.SetProjection(srs.ExportToWkt())
        ds = None
        rows = []
        for cache in ("bounded", "unbounded"):
            out = subprocess.run([sys.executable, "-c", _DEM_MEMORY_SCRIPT, str(work / f"data-{cache}"), str(tif),
                                  TOKEN, cache], capture_output=True, text=True, check=True)
            rows.append((cache, json.loads(out.stdout.strip().splitlines()[-1])))
        lines = [f"\nSparse GeoTIFF {size} x {size} float32 ({tif.stat().st_size:,} bytes on disk) uploaded to a fresh "
                 "API process (peak RSS, `ru_maxrss`):\n",
                 "| GDAL block cache | answer | RSS before upload (MB) | peak (MB) |", "| --- | ---: | ---: | ---: |"]
        for cache, r in rows:
            label = "bounded (64 MiB + 4 blocks while validating), block-by-block scan" if cache == "bounded" else "GDAL default (5 % of RAM)"
            lines.append(f"| {label} | {r['status']} | {r['before_mb']:.0f} | {r['peak_mb']:.0f} |")
        return lines
    finally:
        shutil.rmtree(work, ignore_errors=True)


def schemathesis_counts(max_examples: int) -> list[str]:
    """Generated requests per operation against the in-process app (authenticated): cases and status codes."""
    from collections import Counter

    import schemathesis
    from fastapi.testclient import TestClient
    from hypothesis import HealthCheck, given, settings
    from schemathesis.checks import not_a_server_error

    from blender_addon.terrain.procedural import synthesize
    from render_service.main import create_app
    from render_service.settings import ServiceSettings

    work = Path(tempfile.mkdtemp(prefix="skyloc-bench-schema-"))
    try:
        dem = synthesize("mars", size_m=400.0, res_m=1.0, seed=7, out_path=work / "dem.tif")
        app = create_app(ServiceSettings(data_dir=work / "data", token=TOKEN, start_cluster=False,
                                         max_upload_bytes=4_000_000))
        with TestClient(app) as c:
            assert c.post("/v1/dems", files={"file": ("dem.tif", dem.read_bytes())}, headers=AUTH).status_code == 201
        schema = schemathesis.openapi.from_asgi("/openapi.json", app)
        codes: Counter = Counter()
        n_ops = 0
        for result in schema.get_all_operations():
            op = result.ok()
            n_ops += 1

            @given(op.as_strategy())
            @settings(max_examples=max_examples, deadline=None, database=None, suppress_health_check=list(HealthCheck))
            def run(case):
                r = case.call_and_validate(headers=AUTH, checks=[not_a_server_error])
                codes[r.status_code] += 1

            run()
        total = sum(codes.values())
        return [f"\nschemathesis: {n_ops} operations x up to {max_examples} examples = {total:,} requests, "
                f"{sum(n for k, n in codes.items() if k >= 500)} answered 5xx; statuses "
                + ", ".join(f"{k}: {n:,}" for k, n in sorted(codes.items())) + "."]
    finally:
        shutil.rmtree(work, ignore_errors=True)


def latency_only(args) -> list[str]:
    """Status latency while a ``2 x --size`` job renders, on a fresh service (warm-up job first)."""
    from blender_addon.terrain.dem import dem_info, resolve_dem

    dem = resolve_dem(args.dem)
    b = dem_info(dem).bounds
    center = [(b[0] + b[2]) / 2, (b[1] + b[3]) / 2]
    work = Path(tempfile.mkdtemp(prefix="skyloc-bench-latency-"))
    try:
        svc = Service(work / "data", args.workers)
        try:
            with open(dem, "rb") as fh:
                d = svc.client.post("/v1/dems", files={"file": (Path(dem).name, fh)}).json()
            base = {"kind": "skyline_db", "dem_id": d["id"], "center": center, "azimuths": args.azimuths,
                    "tile_size": args.tile, "camera_height_m": 2.0}
            svc.wait(svc.submit({**base, "size_m": 20, "step_m": 10}))
            big = svc.submit({**base, "size_m": args.size * 2, "step_m": args.step})
            svc.wait(big, states=("running", "done", "failed"))
            time.sleep(1.0)
            lat, seq, running = status_latency(svc, big, concurrency=args.concurrency, rounds=args.rounds)
            svc.client.delete(f"/v1/jobs/{big}")
        finally:
            svc.stop()
    finally:
        shutil.rmtree(work, ignore_errors=True)
    q, qs = np.percentile(lat * 1000, [50, 99]), np.percentile(seq * 1000, [50, 99])
    note = "" if running else " (the job finished during the test)"
    return [f"| {args.rounds} bursts of {args.concurrency}{note}: p50 / p99 / max (ms) | {q[0]:.0f} / {q[1]:.0f} / "
            f"{lat.max() * 1000:.0f} | 100 one at a time: p50 / p99 (ms) | {qs[0]:.1f} / {qs[1]:.1f} |"]


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--dem", default="procedural:mars:7:6000:5", help="DEM path or procedural:PRESET:SEED:SIZE:RES")
    p.add_argument("--size", type=float, default=500.0, help="grid side, m")
    p.add_argument("--step", type=float, default=5.0, help="grid step, m")
    p.add_argument("--azimuths", type=int, default=360)
    p.add_argument("--tile", type=int, default=16,
                   help="tile side; small grids need small tiles or the last tile leaves a worker idle")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--concurrency", type=int, default=200)
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--repeats", type=int, default=3, help="interleaved CLI / service runs (medians reported)")
    p.add_argument("--latency-only", action="store_true",
                   help="only: status latency while a job renders (no CLI runs)")
    p.add_argument("--dem-memory", action="store_true",
                   help="only: peak memory of validating a 30000 x 30000 sparse GeoTIFF upload")
    p.add_argument("--schemathesis", type=int, default=0, metavar="N",
                   help="only: N generated requests per API operation, count the answers (no 5xx allowed)")
    args = p.parse_args(argv)
    if args.latency_only:
        print("\n".join(latency_only(args)))  # noqa: T201 (benchmark output)
        return
    if args.dem_memory or args.schemathesis:
        lines = dem_memory() if args.dem_memory else []
        lines += schemathesis_counts(args.schemathesis) if args.schemathesis else []
        print("\n".join(lines))  # noqa: T201 (benchmark output)
        return

    from blender_addon.terrain.dem import dem_info, resolve_dem

    dem = resolve_dem(args.dem)
    info = dem_info(dem)
    b = info.bounds
    center = ((b[0] + b[2]) / 2, (b[1] + b[3]) / 2)
    n = int(round(args.size / args.step)) + 1
    positions = n * n
    work = Path(tempfile.mkdtemp(prefix="skyloc-bench-service-"))
    try:
        # warm the numba cache once so neither side pays the first compilation, then measure the CLI's
        # fixed cost (interpreter, imports, DEM checks, terrain build) on a 3 x 3 grid
        tiny = argparse.Namespace(size=20, step=10, azimuths=args.azimuths, tile=args.tile)
        run_cli(dem, center, tiny, work / "warm.zarr")
        t_cli_fixed = run_cli(dem, center, tiny, work / "tiny.zarr")

        svc = Service(work / "data", args.workers)
        try:
            with open(dem, "rb") as fh:
                d = svc.client.post("/v1/dems", files={"file": (Path(dem).name, fh)}).json()
            base = {"kind": "skyline_db", "dem_id": d["id"], "center": list(center), "azimuths": args.azimuths,
                    "tile_size": args.tile, "camera_height_m": 2.0}
            t0 = time.perf_counter()
            svc.wait(svc.submit({**base, "size_m": 20, "step_m": 10}))  # warm-up: cluster up, workers compiled
            t_warm = time.perf_counter() - t0
            t0 = time.perf_counter()
            svc.wait(svc.submit({**base, "size_m": 20, "step_m": 10, "camera_height_m": 2.5}))  # fixed cost
            t_svc_fixed = time.perf_counter() - t0
            # interleaved: the shared machine's load drifts, pairs see about the same load
            t_clis, t_svcs = [], []
            for r in range(args.repeats):
                height = 2.0 + 0.1 * r  # a new job each time (same spec = same job)
                t_clis.append(run_cli(dem, center, args, work / f"cli{r}.zarr", height))
                t0 = time.perf_counter()
                job = svc.wait(svc.submit({**base, "size_m": args.size, "step_m": args.step,
                                           "camera_height_m": height}))
                t_svcs.append(time.perf_counter() - t0)
                assert job["state"] == "done", job
            t_cli, t_svc = float(np.median(t_clis)), float(np.median(t_svcs))
            # latency while a larger job renders
            big = svc.submit({**base, "size_m": args.size * 2, "step_m": args.step})
            svc.wait(big, states=("running", "done", "failed"))
            time.sleep(1.0)
            lat, seq, running = status_latency(svc, big, concurrency=args.concurrency, rounds=args.rounds)
            svc.client.delete(f"/v1/jobs/{big}")
        finally:
            svc.stop()
    finally:
        shutil.rmtree(work, ignore_errors=True)

    lines: list[str] = []
    out = lines.append
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    out(f"\n### Render service ({date}, {os.cpu_count()} cores shared, DEM {args.dem})\n")
    out(f"Grid {args.size:g} m at {args.step:g} m = {positions} positions x {args.azimuths} azimuths, "
          f"tiles of {args.tile}, service with {args.workers} worker processes.\n")
    r_cli, r_svc = positions / max(t_cli - t_cli_fixed, 1e-9), positions / max(t_svc - t_svc_fixed, 1e-9)
    out("| run | wall time (s) | fixed cost (s, 3 x 3 grid) | positions/s end to end | positions/s beyond fixed |")
    out("| --- | ---: | ---: | ---: | ---: |")
    out(f"| CLI `skyloc db render` (process start, imports, terrain build) | {t_cli:.1f} | {t_cli_fixed:.1f} | "
          f"{positions / t_cli:,.0f} | {r_cli:,.0f} |")
    out(f"| service: POST to done (terrain build as a task, warm workers) | {t_svc:.1f} | {t_svc_fixed:.1f} | "
          f"{positions / t_svc:,.0f} | {r_svc:,.0f} |")
    out(f"\nFirst tiny job after the service started (cluster start, workers load numba): {t_warm:.1f} s.")
    out("Per pair (CLI s / service s): " + ", ".join(f"{a:.1f} / {b:.1f}" for a, b in zip(t_clis, t_svcs)))
    out(f"Service overhead vs CLI (medians of {args.repeats}), end to end: {100 * (t_svc / t_cli - 1):+.1f} %; "
          "rendering throughput "
          f"beyond the fixed costs: {100 * (r_cli / r_svc - 1):+.1f} % (target <= +10 %).\n")
    q = np.percentile(lat * 1000, [50, 99])
    qs = np.percentile(seq * 1000, [50, 99])
    note = "" if running else " (the job finished during the test)"
    out("| status latency while a job renders, GET /v1/jobs/{id}, new connection each "
        "| p50 (ms) | p99 (ms) | max (ms) |")
    out("| --- | ---: | ---: | ---: |")
    out(f"| {args.rounds} bursts of {args.concurrency} concurrent requests{note} | {q[0]:.1f} | {q[1]:.1f} | "
          f"{lat.max() * 1000:.1f} |")
    out(f"| 100 requests one at a time | {qs[0]:.1f} | {qs[1]:.1f} | {seq.max() * 1000:.1f} |")

    print("\n".join(lines))  # noqa: T201 (benchmark output)


if __name__ == "__main__":
    main()
