"""Jobs to tiles to Dask: planning, per-tile tasks, and the job runner with resume, retries and cancel.

A skyline-database job is a square grid of positions (metres, in the DEM's metric CRS) split into
tiles of ``tile_size x tile_size`` positions (:func:`board.skydb.plan_tiles`).  The runner

1. builds the job's multi-resolution terrain once, as a Dask task, into ``jobs/<id>/terrain``;
2. creates the Zarr store ``jobs/<id>/db.zarr`` (atomically: built beside, then renamed);
3. submits every tile not yet written to Dask.  Each task (:func:`render_tile_task`) renders
   one tile on a worker, writes its own Zarr chunk through :class:`board.skydb.SkyDBWriter`
   (which marks the tile done in the store's ``tile_done`` array), then logs the render and
   the tile's completion in the SQLite job store;
4. on restart, resumes: tiles found done in the Zarr store are never submitted again (a tile
   written just before a crash but not yet recorded in SQLite is recorded as *recovered*);
5. retries a failed tile ``max_tile_retries`` times, then fails the job with the tile's error;
6. on cancel, drops queued tiles; running tiles finish (whole tiles only) and nothing is published;
7. when every tile is written, marks the database complete and publishes ``result.zip``
   (the store plus a ``MANIFEST.sha256``) by writing a temporary file and renaming it.
"""
from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import shutil
import threading
import time
import zipfile
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from board.errors import InvalidInputError, SkylocError
from board.skydb import GridSpec, SkyDB, SkyDBMeta, SkyDBWriter, Tile, plan_tiles
from render_service.settings import ServiceSettings
from render_service.store import DemRecord, JobRecord, JobStore
from render_service.workers import TerrainPlugin, worker_name, worker_terrain

log = logging.getLogger(__name__)

RESULT_NAME = "result.zip"
MANIFEST_NAME = "MANIFEST.sha256"
_ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)  # fixed entry times: same database, same zip bytes


# --------------------------------------------------------------------------------------------
# planning (runs in the API process, before a job is accepted)
# --------------------------------------------------------------------------------------------
def canonical_json(obj) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))


def job_id_for(spec: dict) -> str:
    """Deterministic job id of a validated spec: the same spec always gives the same job."""
    return hashlib.sha256(canonical_json(spec).encode()).hexdigest()[:20]


@dataclass(frozen=True)
class DbPlan:
    """A planned database job: the grid (metres, DEM metric CRS) and its tiles."""

    grid: GridSpec
    tiles: list[Tile]


def plan_db_job(spec: dict, dem: DemRecord, settings: ServiceSettings) -> DbPlan:
    """Check a database job against the limits and the DEM, and plan its tiles.

    Raises InvalidInputError naming the limit and the fix.
    """
    size_m, step_m = float(spec["size_m"]), float(spec["step_m"])
    if not (step_m > 0 and math.isfinite(step_m)):
        raise InvalidInputError(f"step_m must be a positive number of metres, got {step_m}")
    area_km2 = (size_m / 1000.0) ** 2
    if area_km2 > settings.max_area_km2:
        raise InvalidInputError(f"search area {size_m:g} x {size_m:g} m = {area_km2:.3g} km^2 exceeds this server's "
                                f"limit of {settings.max_area_km2:g} km^2: split it into smaller jobs")
    n_side = int(round(size_m / step_m)) + 1
    if n_side * n_side > settings.max_positions:
        raise InvalidInputError(f"{n_side} x {n_side} = {n_side * n_side} positions exceed this server's limit of "
                                f"{settings.max_positions}: use a larger step_m or a smaller size_m")
    if int(spec["azimuths"]) > settings.max_azimuths:
        raise InvalidInputError(f"{spec['azimuths']} azimuths exceed this server's limit of {settings.max_azimuths}")
    info = dem.info
    grid = GridSpec.from_center(tuple(spec["center"]), size_m, step_m, info["crs_wkt"])
    xmin, ymin, xmax, ymax = grid.bounds()
    bx0, by0, bx1, by1 = info["bounds"]
    if xmin < bx0 or ymin < by0 or xmax > bx1 or ymax > by1:
        raise InvalidInputError(
            f"the grid [{xmin:.1f}, {ymin:.1f}, {xmax:.1f}, {ymax:.1f}] is not inside the DEM's bounds "
            f"[{bx0:.1f}, {by0:.1f}, {bx1:.1f}, {by1:.1f}] (metres, its metric CRS): move the centre or shrink size_m")
    return DbPlan(grid, plan_tiles(grid, int(spec["tile_size"])))


def prepare_db_job(spec: dict, dem: DemRecord):
    """The render description of a database job (:func:`render_service.dbrender.prepare_job`).

    The metadata is the CLI's (``skyloc db render``) so both produce the same database; the server
    path of the DEM is replaced by its id.
    """
    from render_service.dbrender import prepare_job  # noqa: PLC0415
    from render_service.renderers.base import RenderSpec  # noqa: PLC0415

    rspec = RenderSpec(camera_height_m=float(spec["camera_height_m"]), n_azimuth=int(spec["azimuths"]),
                       azimuth_start_deg=float(spec["azimuth_start_deg"]), refraction_k=float(spec["refraction_k"]))
    job = prepare_job(dem.path, center_xy=tuple(spec["center"]), size_m=float(spec["size_m"]),
                      step_m=float(spec["step_m"]), spec=rspec, renderer=spec["renderer"],
                      tile_size=int(spec["tile_size"]), body=dem.body)
    job.meta.extra.pop("dem_path", None)
    job.meta.extra["dem_id"] = dem.id
    return job


# --------------------------------------------------------------------------------------------
# tasks (run on Dask workers; must be importable there, arguments picklable)
# --------------------------------------------------------------------------------------------
_STORES: dict[str, JobStore] = {}


def _store(path: str) -> JobStore:
    if path not in _STORES:
        _STORES[path] = JobStore(path)
    return _STORES[path]


def build_terrain_task(rjob, out_dir: str) -> str:
    """Build a job's multi-resolution terrain into ``out_dir`` (atomically); returns ``out_dir``.

    ``rjob`` is the :class:`render_service.dbrender.RenderJob`; the terrain is planned exactly as
    ``skyloc db render`` plans it (:func:`render_service.dbrender.load_terrain`).
    """
    from render_service.dbrender import load_terrain  # noqa: PLC0415

    out = Path(out_dir)
    if (out / "terrain.json").is_file():
        return str(out)
    tmp = out.with_name(out.name + f".tmp-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    load_terrain(rjob, terrain_dir=tmp)
    try:
        os.rename(tmp, out)
    except OSError:
        if not (out / "terrain.json").is_file():
            raise
        shutil.rmtree(tmp, ignore_errors=True)  # another worker published it first
    return str(out)


def render_tile_task(*, job_id: str, store_path: str, db_path: str, terrain_dir: str, tile: Tile, spec,
                     renderer: str) -> dict:
    """Render one tile and write its Zarr chunk; render nothing when the tile is already written.

    Returns {"tile", "rendered", "seconds"}.  The render is logged in the job store only after the
    chunk and its ``tile_done`` flag are on disk.
    """
    from render_service.dbrender import render_and_write_tile  # noqa: PLC0415

    store = _store(store_path)
    t0 = time.time()
    terrain = worker_terrain(terrain_dir)
    rendered = render_and_write_tile(db_path, terrain, tile, spec, renderer)
    t1 = time.time()
    if rendered:
        store.record_render(job_id=job_id, tile_key=tile.key, worker=worker_name(), started=t0, finished=t1)
    else:
        store.mark_tile_done(job_id=job_id, tile_key=tile.key, recovered=True)
    return {"tile": tile.key, "rendered": rendered, "seconds": t1 - t0}


def dataset_task(scene_toml: str, out_dir: str) -> str:
    """Generate a simulator test set from a scene file into ``out_dir``.

    Rendered into ``<out_dir>.partial`` (which the generator resumes after a crash), renamed when complete.
    """
    from blender_addon.core.dataset import generate_dataset  # noqa: PLC0415

    out = Path(out_dir)
    partial = out.with_name(out.name + ".partial")
    generate_dataset(scene_toml, partial)
    if out.exists():
        shutil.rmtree(out)
    os.rename(partial, out)
    return str(out)


# --------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------
def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def write_result_zip(folder: Path, zip_path: Path, *, arcroot: str) -> tuple[str, int]:
    """Zip ``folder`` under ``arcroot/`` with a ``MANIFEST.sha256`` (sha256sum format); atomic.

    Entries are sorted and carry a fixed time, so the same content gives the same zip bytes.
    Returns (sha256 of the zip, size in bytes).
    """
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    manifest = []
    tmp = zip_path.with_name(zip_path.name + ".tmp")
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as zf:
        for p in files:
            arc = f"{arcroot}/{p.relative_to(folder).as_posix()}"
            manifest.append(f"{file_sha256(p)}  {arc}")
            zf.writestr(zipfile.ZipInfo(arc, _ZIP_EPOCH), p.read_bytes())
        zf.writestr(zipfile.ZipInfo(MANIFEST_NAME, _ZIP_EPOCH), "\n".join(manifest) + "\n")
    with open(tmp, "rb+") as fh:
        os.fsync(fh.fileno())
    os.replace(tmp, zip_path)
    return file_sha256(zip_path), zip_path.stat().st_size


# --------------------------------------------------------------------------------------------
# the runner (a thread of the API process)
# --------------------------------------------------------------------------------------------
class _Stop(Exception):
    """The runner is shutting down: leave the job as it is, it resumes on the next start."""


class _Cancelled(Exception):
    """The job was cancelled while it waited."""


class JobRunner:
    """Runs queued jobs one at a time on a Dask cluster (a LocalCluster unless ``settings.scheduler``)."""

    def __init__(self, *, store: JobStore, settings: ServiceSettings) -> None:
        self.store = store
        self.settings = settings
        self.client = None
        self.cluster = None
        self.error: str | None = None
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._main, name="skyloc-job-runner", daemon=True)
        self._n_workers: int | None = None
        self._workers_checked = 0.0

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> None:
        self._thread.start()

    def wake(self) -> None:
        """A job was submitted or cancelled: look at the queue now."""
        self._wake.set()

    def wait_ready(self, timeout: float | None = None) -> bool:
        return self._ready.wait(timeout)

    def stop(self, timeout: float = 30.0) -> None:
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout)
        try:
            if self.client is not None:
                self.client.close(timeout=10)
            if self.cluster is not None:
                self.cluster.close(timeout=10)
        except Exception as exc:  # shutting down: report, do not raise
            log.warning("closing Dask: %s", exc)

    def n_workers(self) -> int | None:
        """Workers connected to the scheduler (refreshed by the runner thread about once a second)."""
        return self._n_workers

    def _refresh_workers(self, *, force: bool = False) -> None:
        now = time.monotonic()
        if self.client is None or (not force and now - self._workers_checked < 1.0):
            return
        self._workers_checked = now
        try:
            self._n_workers = len(self.client.scheduler_info(n_workers=-1)["workers"])
        except Exception as exc:  # scheduler unreachable: report unknown, keep going
            log.debug("cannot count workers: %s", exc)
            self._n_workers = None

    def _start_dask(self) -> None:
        from distributed import Client, LocalCluster  # noqa: PLC0415

        s = self.settings
        if s.scheduler:
            log.info("connecting to the Dask scheduler %s", s.scheduler)
            self.client = Client(s.scheduler, timeout=30)
            numba_threads = None
        else:
            self.cluster = LocalCluster(n_workers=s.n_workers, threads_per_worker=s.threads_per_worker,
                                        processes=True, host="127.0.0.1", scheduler_port=0,
                                        dashboard_address=None, silence_logs=logging.WARNING)
            self.client = Client(self.cluster)
            numba_threads = max(1, (os.cpu_count() or 1) // s.n_workers)
            log.info("started a LocalCluster: %d workers x %d thread(s)", s.n_workers, s.threads_per_worker)
        self.client.register_plugin(TerrainPlugin(numba_threads=numba_threads))

    def _main(self) -> None:
        try:
            self._start_dask()
        except Exception as exc:
            self.error = f"cannot start Dask: {exc}"
            log.exception("cannot start Dask; jobs stay queued")
            self._ready.set()
            return
        self._refresh_workers(force=True)
        self._ready.set()
        while not self._stop.is_set():
            self._refresh_workers()
            job = self.store.next_active_job()
            if job is None:
                self._wake.wait(0.5)
                self._wake.clear()
                continue
            try:
                self._run(job)
            except _Stop:
                return
            except _Cancelled:
                self.store.set_state(job_id=job.id, state="cancelled", finished=time.time())
                log.info("job %s cancelled", job.id)
            except Exception as exc:
                reason = str(exc) if isinstance(exc, SkylocError) else f"{type(exc).__name__}: {exc}"
                log.exception("job %s failed", job.id)
                self.store.set_state(job_id=job.id, state="failed", error=reason, finished=time.time())

    # -- helpers -------------------------------------------------------------------------------
    def _check(self, job_id: str) -> None:
        self._refresh_workers()
        if self._stop.is_set():
            raise _Stop
        if self.store.get_job(job_id=job_id).state == "cancel-requested":
            raise _Cancelled

    def _wait_one(self, future, job_id: str):
        from distributed import wait  # noqa: PLC0415

        while True:
            self._check(job_id)
            try:
                wait([future], timeout=0.5)
            except TimeoutError:
                continue
            return future.result()

    def _run(self, job: JobRecord) -> None:
        if job.state == "cancel-requested":
            raise _Cancelled
        now = time.time()
        self.store.set_state(job_id=job.id, state="running", expect=("queued", "running"),
                             started=job.started or now, run_started=now)
        log.info("job %s (%s) running", job.id, job.kind)
        if job.kind == "skyline_db":
            self._run_db(job)
        elif job.kind == "dataset":
            self._run_dataset(job)
        else:
            raise InvalidInputError(f"unknown job kind {job.kind!r}")

    def _run_dataset(self, job: JobRecord) -> None:
        jdir = self.settings.jobs_dir / job.id
        jdir.mkdir(parents=True, exist_ok=True)
        scene = self.settings.scenes_dir / f"{job.spec['scene']}.toml"
        out = jdir / "dataset"
        if not (out.is_dir() and any(out.iterdir())):
            fut = self.client.submit(dataset_task, str(scene), str(out), pure=False,
                                     retries=self.settings.max_tile_retries)
            self._wait_one(fut, job.id)
        sha, nbytes = write_result_zip(out, jdir / RESULT_NAME, arcroot="dataset")
        self.store.mark_tile_done(job_id=job.id, tile_key="dataset")
        self.store.set_state(job_id=job.id, state="done", finished=time.time(), result_path=str(jdir / RESULT_NAME),
                             result_sha256=sha, result_bytes=nbytes)

    def _ensure_store(self, db_path: Path, meta: SkyDBMeta) -> None:
        if db_path.exists():
            SkyDBWriter.create(db_path, meta)  # checks it is the same database
            return
        tmp = db_path.with_name(db_path.name + ".tmp")
        shutil.rmtree(tmp, ignore_errors=True)
        SkyDBWriter.create(tmp, meta, overwrite=True)
        os.rename(tmp, db_path)

    def _run_db(self, job: JobRecord) -> None:
        from distributed import wait  # noqa: PLC0415

        spec = job.spec
        dem = self.store.get_dem(dem_id=spec["dem_id"])
        plan = plan_db_job(spec, dem, self.settings)
        jdir = self.settings.jobs_dir / job.id
        jdir.mkdir(parents=True, exist_ok=True)
        terrain_dir, db_path = jdir / "terrain", jdir / "db.zarr"

        rjob = prepare_db_job(spec, dem)
        if not (terrain_dir / "terrain.json").is_file():
            fut = self.client.submit(build_terrain_task, rjob, str(terrain_dir), pure=False)
            self._wait_one(fut, job.id)
        self._ensure_store(db_path, rjob.meta)

        done = SkyDB.open(db_path).done_mask()
        recorded = self.store.done_tiles(job_id=job.id)
        for t in plan.tiles:
            if done[t.ti, t.tj] and t.key not in recorded:
                self.store.mark_tile_done(job_id=job.id, tile_key=t.key, recovered=True)
        queue = deque(t for t in plan.tiles if not done[t.ti, t.tj])
        log.info("job %s: %d of %d tiles to render", job.id, len(queue), len(plan.tiles))

        rspec = rjob.spec
        self._refresh_workers(force=True)
        limit = max(1, (self.n_workers() or 1) * self.settings.max_in_flight_per_worker)
        in_flight: dict = {}
        try:
            while queue or in_flight:
                self._check(job.id)
                while queue and len(in_flight) < limit:
                    tile = queue.popleft()
                    fut = self.client.submit(render_tile_task, job_id=job.id, store_path=str(self.store.path),
                                             db_path=str(db_path), terrain_dir=str(terrain_dir), tile=tile,
                                             spec=rspec, renderer=spec["renderer"], pure=False,
                                             key=f"tile-{job.id}-{tile.key}-{time.monotonic_ns()}")
                    in_flight[fut] = tile
                try:
                    finished, _ = wait(list(in_flight), timeout=0.5, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    continue
                for fut in finished:
                    tile = in_flight.pop(fut)
                    if fut.status == "finished":
                        self.store.mark_tile_done(job_id=job.id, tile_key=tile.key)
                        continue
                    exc = fut.exception() if fut.status == "error" else RuntimeError(f"task {fut.status}")
                    reason = f"{type(exc).__name__}: {exc}"
                    attempts = self.store.tile_failed(job_id=job.id, tile_key=tile.key, error=reason)
                    log.warning("job %s tile %s failed (attempt %d): %s", job.id, tile.key, attempts, reason)
                    if attempts > self.settings.max_tile_retries:
                        raise InvalidInputError(f"tile {tile.key} failed {attempts} times; last error: {reason}")
                    queue.append(tile)
        finally:
            if in_flight:
                self.client.cancel(list(in_flight))

        writer = SkyDBWriter.create(db_path, rjob.meta)
        writer.finalize()
        sha, nbytes = write_result_zip(db_path, jdir / RESULT_NAME, arcroot="db.zarr")
        self.store.set_state(job_id=job.id, state="done", finished=time.time(), result_path=str(jdir / RESULT_NAME),
                             result_sha256=sha, result_bytes=nbytes)
        log.info("job %s done: %s (%d bytes)", job.id, jdir / RESULT_NAME, nbytes)
