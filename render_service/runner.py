"""The job runner: a thread of the API process that runs queued jobs one at a time on Dask.

For a skyline-database job it

1. builds the job's multi-resolution terrain once, as a Dask task, into ``jobs/<id>/terrain``;
2. creates the Zarr store ``jobs/<id>/db.zarr`` (atomically: built beside, then renamed) with the
   CLI's metadata, the terrain's levels included;
3. keeps ``max_in_flight_per_worker x workers`` tile tasks in flight (:mod:`render_service.tasks`);
4. on restart, resumes: tiles found done in the Zarr store are never submitted again (a tile
   written just before a crash but not yet recorded in SQLite is recorded as *recovered*);
5. retries a failed tile ``max_tile_retries`` times, then fails the job with the tile's error;
6. on cancel, drops queued tiles; running tiles finish (whole tiles only) and nothing is published;
7. when every tile is written, marks the database complete and publishes ``result.zip``.

Faults: the thread survives any exception.  A job that fails ends ``failed`` with a reason a user
can act on and no server path (:func:`render_service.storage.public_reason`); its temporary files
are removed.  While the data directory is not writable or short of space
(:class:`render_service.storage.StorageMonitor`) no job is started and ``/healthz`` says
``degraded``; a failure that could not be written (the disk is full) is kept in memory, shown by the
API, and written as soon as the disk takes writes again; then the queue continues.
"""
from __future__ import annotations

import errno
import logging
import os
import shutil
import threading
import time
from collections import deque
from contextlib import ExitStack
from pathlib import Path

from board.errors import InvalidInputError
from board.skydb import SkyDB, SkyDBMeta, SkyDBWriter
from render_service.planning import parse_spec, plan_db_job, prepare_db_job
from render_service.result_zip import RESULT_NAME, write_result_zip
from render_service.schemas import DatasetJobIn, SkylineDbJobIn
from render_service.settings import ServiceSettings
from render_service.storage import StorageMonitor, is_storage_error, public_reason
from render_service.store import JobRecord, JobStore
from render_service.tasks import build_terrain_task, dataset_task, render_tile_task, terrain_levels_task
from render_service.workers import TerrainPlugin

log = logging.getLogger(__name__)

TLS_DIR_NAME = ".dask-tls"


class _Stop(Exception):
    """The runner is shutting down: leave the job as it is, it resumes on the next start."""


class _Cancelled(Exception):
    """The job was cancelled while it waited."""


class StorageUnavailable(OSError):
    """The data directory stopped taking writes while a job ran."""


def cluster_security(settings: ServiceSettings):
    """The ``Security`` for ``settings.scheduler`` from the ``tls_*`` settings, or None (Dask's config)."""
    if not settings.scheduler or not settings.tls_cert:
        return None
    from render_service.engine import security_from_files  # noqa: PLC0415

    return security_from_files(ca_file=settings.tls_ca_file or settings.tls_cert, cert_file=settings.tls_cert,
                               key_file=settings.tls_key)


def clean_job_temporaries(jdir: Path) -> None:
    """Remove what a failed or interrupted run left beside its targets in ``jobs/<id>``."""
    if not jdir.is_dir():
        return
    for p in jdir.iterdir():
        if p.name.endswith(".tmp") or ".tmp-" in p.name:
            if p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)


class JobRunner:
    """Runs queued jobs one at a time on a Dask cluster (a TLS LocalCluster unless ``settings.scheduler``)."""

    def __init__(self, *, store: JobStore, settings: ServiceSettings, monitor: StorageMonitor | None = None) -> None:
        self.store = store
        self.settings = settings
        self.monitor = monitor or StorageMonitor(settings.data_dir, min_free_bytes=settings.min_free_bytes)
        self.client = None
        self.local = settings.scheduler is None
        self.error: str | None = None
        #: failures not yet written to the store (job id -> reason), written when the disk takes writes
        self.pending_failures: dict[str, str] = {}
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

    def stop(self, timeout: float = 60.0) -> None:
        """Stop the thread; the Dask client (and a LocalCluster) close as it leaves."""
        self._stop.set()
        self._wake.set()
        self._thread.join(timeout)

    def alive(self) -> bool:
        return self._thread.is_alive()

    def n_workers(self) -> int | None:
        """Workers connected to the scheduler (refreshed by the runner thread about once a second)."""
        return self._n_workers

    def problem(self) -> str | None:
        """Why the runner cannot run jobs now (None when it can): Dask, the data directory, a stopped thread."""
        if self.error:
            return self.error
        if self._thread.ident is not None and not self._thread.is_alive() and not self._stop.is_set():
            return "the job runner stopped: see the server log, then restart the server"
        problem = self.monitor.problem()
        if problem is None and self.pending_failures:
            problem = (f"the job store does not take writes: {len(self.pending_failures)} job failure(s) not "
                       "recorded yet; new jobs wait")
        return problem

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

    def _connect(self, stack: ExitStack) -> None:
        from render_service.engine import dask_client  # noqa: PLC0415
        from render_service.security import load_token  # noqa: PLC0415

        s = self.settings
        self.client = stack.enter_context(dask_client(
            s.scheduler, n_workers=s.n_workers, threads_per_worker=s.threads_per_worker,
            security=cluster_security(s), dashboard=s.dashboard,
            dashboard_token=load_token(s) if s.dashboard else None, tls_dir=s.data_dir / TLS_DIR_NAME))
        numba_threads = max(1, (os.cpu_count() or 1) // s.n_workers) if self.local else None
        self.client.register_plugin(TerrainPlugin(numba_threads=numba_threads))

    def _main(self) -> None:
        with ExitStack() as stack:
            try:
                self._connect(stack)
            except Exception as exc:
                self.error = f"cannot start Dask: {public_reason(exc, self.settings.data_dir)}"
                log.exception("cannot start Dask; jobs stay queued")
                self._ready.set()
                return
            self._refresh_workers(force=True)
            self._ready.set()
            while not self._stop.is_set():
                try:
                    self._tick()
                except _Stop:
                    break
                except Exception:  # the loop itself must never die: log, wait, try again
                    log.exception("job runner: unexpected error; trying again in 1 s")
                    self._stop.wait(1.0)
            self.client = None

    def _idle(self, seconds: float) -> None:
        self._wake.wait(seconds)
        self._wake.clear()

    def _tick(self) -> None:
        self._refresh_workers()
        if self.monitor.problem() is not None:
            self._idle(1.0)
            return
        if self.pending_failures and not self._flush_failures():
            self._idle(1.0)
            return
        job = self.store.next_active_job()
        if job is None:
            self._idle(0.5)
            return
        jdir = self.settings.jobs_dir / job.id
        try:
            self._run(job)
        except _Stop:
            raise
        except _Cancelled:
            self.store.set_state(job_id=job.id, state="cancelled", finished=time.time())
            log.info("job %s cancelled", job.id)
        except Exception as exc:
            self._fail(job.id, exc)
        finally:
            clean_job_temporaries(jdir)

    def _fail(self, job_id: str, exc: BaseException) -> None:
        reason = public_reason(exc, self.settings.data_dir)
        if is_storage_error(exc):
            log.error("job %s failed: the data directory does not take writes (%s)", job_id, exc)
            self.monitor.problem(force=True)
        else:
            log.error("job %s failed: %s", job_id, exc, exc_info=exc)
        self.pending_failures[job_id] = reason
        self._flush_failures()

    def _flush_failures(self) -> bool:
        """Write the pending failures; False (and they stay pending) while the store cannot be written."""
        for job_id, reason in list(self.pending_failures.items()):
            try:
                self.store.set_state(job_id=job_id, state="failed", error=reason, finished=time.time())
            except Exception as exc:
                log.warning("cannot record the failure of job %s yet (%s); retrying", job_id, exc)
                self.monitor.problem(force=True)
                return False
            del self.pending_failures[job_id]
        return True

    # -- helpers -------------------------------------------------------------------------------
    def _check(self, job_id: str) -> None:
        self._refresh_workers()
        if self._stop.is_set():
            raise _Stop
        problem = self.monitor.problem()
        if problem is not None:
            raise StorageUnavailable(errno.ENOSPC if "space" in problem else errno.EROFS, problem)
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
        spec = parse_spec(job.kind, job.spec)
        if isinstance(spec, SkylineDbJobIn):
            self._run_db(job, spec)
        elif isinstance(spec, DatasetJobIn):
            self._run_dataset(job, spec)
        else:  # pragma: no cover (parse_spec knows every kind)
            raise InvalidInputError(f"unknown job kind {job.kind!r}")

    def _publish(self, job: JobRecord, folder: Path, arcroot: str) -> None:
        jdir = self.settings.jobs_dir / job.id
        sha, nbytes = write_result_zip(folder, jdir / RESULT_NAME, arcroot=arcroot)
        self.store.set_state(job_id=job.id, state="done", finished=time.time(), result_path=str(jdir / RESULT_NAME),
                             result_sha256=sha, result_bytes=nbytes)
        log.info("job %s done: %s (%d bytes)", job.id, jdir / RESULT_NAME, nbytes)

    def _run_dataset(self, job: JobRecord, spec: DatasetJobIn) -> None:
        jdir = self.settings.jobs_dir / job.id
        jdir.mkdir(parents=True, exist_ok=True)
        scene = self.settings.scenes_dir / f"{spec.scene}.toml"
        out = jdir / "dataset"
        if not (out.is_dir() and any(out.iterdir())):
            fut = self.client.submit(dataset_task, str(scene), str(out), pure=False,
                                     retries=self.settings.max_tile_retries)
            self._wait_one(fut, job.id)
        self.store.mark_tile_done(job_id=job.id, tile_key="dataset")
        self._publish(job, out, "dataset")

    def _ensure_store(self, db_path: Path, meta: SkyDBMeta) -> None:
        if db_path.exists():
            SkyDBWriter.create(db_path, meta)  # checks it is the same database
            return
        tmp = db_path.with_name(db_path.name + ".tmp")
        shutil.rmtree(tmp, ignore_errors=True)
        try:
            SkyDBWriter.create(tmp, meta, overwrite=True)
            os.rename(tmp, db_path)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise

    def _run_db(self, job: JobRecord, spec: SkylineDbJobIn) -> None:
        dem = self.store.get_dem(dem_id=spec.dem_id)
        plan = plan_db_job(spec, dem, self.settings)
        jdir = self.settings.jobs_dir / job.id
        jdir.mkdir(parents=True, exist_ok=True)
        terrain_dir, db_path = jdir / "terrain", jdir / "db.zarr"

        rjob = prepare_db_job(spec, dem)
        if not (terrain_dir / "terrain.json").is_file():
            self._wait_one(self.client.submit(build_terrain_task, rjob, str(terrain_dir), pure=False), job.id)
        rjob.meta.extra["terrain_levels"] = self._wait_one(
            self.client.submit(terrain_levels_task, str(terrain_dir), pure=False), job.id)
        self._ensure_store(db_path, rjob.meta)

        done = SkyDB.open(db_path).done_mask()
        recorded = self.store.done_tiles(job_id=job.id)
        for t in plan.tiles:
            if done[t.ti, t.tj] and t.key not in recorded:
                self.store.mark_tile_done(job_id=job.id, tile_key=t.key, recovered=True)
        queue = deque(t for t in plan.tiles if not done[t.ti, t.tj])
        log.info("job %s: %d of %d tiles to render", job.id, len(queue), len(plan.tiles))
        self._render_tiles(job, spec, queue, db_path=db_path, terrain_dir=terrain_dir, rspec=rjob.spec)

        SkyDBWriter.create(db_path, rjob.meta).finalize()
        self._publish(job, db_path, "db.zarr")

    def _render_tiles(self, job: JobRecord, spec: SkylineDbJobIn, queue: deque, *, db_path: Path,
                      terrain_dir: Path, rspec) -> None:
        from distributed import wait  # noqa: PLC0415

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
                                             spec=rspec, renderer=spec.renderer, pure=False,
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
                    if is_storage_error(exc):
                        raise exc  # a full or read-only disk: retrying cannot help
                    reason = public_reason(exc, self.settings.data_dir)
                    attempts = self.store.tile_failed(job_id=job.id, tile_key=tile.key, error=reason)
                    log.warning("job %s tile %s failed (attempt %d): %s", job.id, tile.key, attempts, exc)
                    if attempts > self.settings.max_tile_retries:
                        raise InvalidInputError(f"tile {tile.key} failed {attempts} times; last error: {reason}")
                    queue.append(tile)
        finally:
            if in_flight:
                self.client.cancel(list(in_flight))
