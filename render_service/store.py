"""The job store: one SQLite file (WAL) holding DEMs, jobs, tiles and the tile-render log.

No HTTP here.  Every public method takes keyword-only arguments.  Several processes may open
the same store at once (the API process and the Dask workers on this machine): each thread
has its own connection, writes are short transactions, readers never block writers (WAL).

Tables
    dems          uploaded DEMs by content hash and body (the same file for another body is another DEM)
    jobs          one row per job; ``spec`` is the canonical JSON of the request
    idem_keys     Idempotency-Key -> job (every key ever sent with a job, new or already known)
    tiles         one row per (job, tile): state ``pending`` or ``done``, attempts, last error
    tile_renders  one row per *completed* tile render (the audit log that proves no tile is
                  rendered twice); ``recovered`` tiles found done in the database after a crash
                  are marked in ``tiles`` without a render row
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import sqlite3
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

from board.errors import InvalidInputError, JobNotFoundError

log = logging.getLogger(__name__)

JOB_STATES = ("queued", "running", "done", "failed", "cancel-requested", "cancelled")
ACTIVE_STATES = ("queued", "running", "cancel-requested")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS dems (
    id TEXT PRIMARY KEY, sha256 TEXT NOT NULL, filename TEXT NOT NULL, path TEXT NOT NULL,
    body TEXT, info TEXT NOT NULL, created REAL NOT NULL);
CREATE INDEX IF NOT EXISTS dems_sha256 ON dems (sha256);
CREATE TABLE IF NOT EXISTS idem_keys (
    idem_key TEXT PRIMARY KEY, job_id TEXT NOT NULL, spec TEXT NOT NULL, created REAL NOT NULL);
CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY, kind TEXT NOT NULL, spec TEXT NOT NULL, idem_key TEXT UNIQUE,
    state TEXT NOT NULL, tiles_total INTEGER NOT NULL DEFAULT 0, positions_total INTEGER NOT NULL DEFAULT 0,
    error TEXT, created REAL NOT NULL, started REAL, finished REAL, updated REAL NOT NULL,
    run_started REAL, result_path TEXT, result_sha256 TEXT, result_bytes INTEGER);
CREATE TABLE IF NOT EXISTS tiles (
    job_id TEXT NOT NULL, tile_key TEXT NOT NULL, n_positions INTEGER NOT NULL,
    state TEXT NOT NULL DEFAULT 'pending', attempts INTEGER NOT NULL DEFAULT 0, error TEXT,
    done_at REAL, recovered INTEGER NOT NULL DEFAULT 0, PRIMARY KEY (job_id, tile_key));
CREATE TABLE IF NOT EXISTS tile_renders (
    id INTEGER PRIMARY KEY AUTOINCREMENT, job_id TEXT NOT NULL, tile_key TEXT NOT NULL,
    worker TEXT, pid INTEGER, started REAL NOT NULL, finished REAL NOT NULL);
CREATE INDEX IF NOT EXISTS tile_renders_job ON tile_renders (job_id, tile_key);
"""


@dataclass
class JobRecord:
    """A job row with its tile progress (times are UNIX seconds, UTC)."""

    id: str
    kind: str
    spec: dict
    state: str
    tiles_total: int
    tiles_done: int
    positions_total: int
    positions_done: int
    positions_done_this_run: int
    error: str | None
    created: float
    started: float | None
    finished: float | None
    run_started: float | None
    result_path: str | None
    result_sha256: str | None
    result_bytes: int | None
    idem_key: str | None


@dataclass
class DemRecord:
    """An uploaded DEM: ``info`` is the validation summary (JSON-able dict)."""

    id: str
    sha256: str
    filename: str
    path: str
    body: str | None
    info: dict
    created: float


class JobStore:
    """SQLite job/tile store at ``path`` (created with its schema on first open)."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._local = threading.local()
        con = self._con()
        _migrate_dems(con)
        con.executescript(_SCHEMA)

    # -- connections -------------------------------------------------------------------------
    def _con(self) -> sqlite3.Connection:
        con = getattr(self._local, "con", None)
        if con is None or getattr(self._local, "pid", None) != os.getpid():
            con = sqlite3.connect(str(self.path), timeout=60.0, isolation_level=None, check_same_thread=False)
            con.row_factory = sqlite3.Row
            con.execute("PRAGMA journal_mode=WAL")
            con.execute("PRAGMA synchronous=FULL")
            con.execute("PRAGMA busy_timeout=60000")
            self._local.con, self._local.pid = con, os.getpid()
        return con

    @contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        con = self._con()
        con.execute("BEGIN IMMEDIATE")
        try:
            yield con
        except BaseException:
            con.execute("ROLLBACK")
            raise
        con.execute("COMMIT")

    def close(self) -> None:
        con = getattr(self._local, "con", None)
        if con is not None:
            con.close()
            self._local.con = None

    # -- DEMs ----------------------------------------------------------------------------------
    def add_dem(self, *, sha256: str, filename: str, path: str, body: str | None,
                info: dict) -> tuple[DemRecord, bool]:
        """Insert a DEM; returns (record, created).

        The same file for the same body (``info["body"]``) is the existing record.  The same file for
        another body is a new DEM: its id is ``sha256[:16]`` when no body was asked for, else a hash of
        the content and the body.
        """
        key = _body_key(info)
        dem_id = sha256[:16] if body is None else hashlib.sha256(f"{sha256}|{key}".encode()).hexdigest()[:16]
        with self._tx() as con:
            for row in con.execute("SELECT * FROM dems WHERE sha256 = ?", (sha256,)).fetchall():
                if _body_key(json.loads(row["info"])) == key:
                    return _dem(row), False
            if con.execute("SELECT 1 FROM dems WHERE id = ?", (dem_id,)).fetchone() is not None:
                dem_id = hashlib.sha256(f"{sha256}|{key}".encode()).hexdigest()[:16]
            con.execute("INSERT INTO dems (id, sha256, filename, path, body, info, created) VALUES (?,?,?,?,?,?,?)",
                        (dem_id, sha256, filename, path, body, json.dumps(info), time.time()))
        return self.get_dem(dem_id=dem_id), True

    def get_dem(self, *, dem_id: str) -> DemRecord:
        """The DEM with this id; InvalidInputError when there is none."""
        row = self._con().execute("SELECT * FROM dems WHERE id = ?", (dem_id,)).fetchone()
        if row is None:
            raise InvalidInputError(f"no DEM with id {dem_id!r}: upload it first with POST /v1/dems")
        return _dem(row)

    def list_dems(self) -> list[DemRecord]:
        return [_dem(r) for r in self._con().execute("SELECT * FROM dems ORDER BY created")]

    # -- jobs ----------------------------------------------------------------------------------
    def create_job(self, *, job_id: str, kind: str, spec: dict, idem_key: str | None = None,
                   tile_keys: dict[str, int] | None = None) -> tuple[JobRecord, bool]:
        """Insert a queued job, or return the existing one with the same id or Idempotency-Key.

        ``tile_keys`` maps tile key -> number of positions.  A failed or cancelled job submitted
        again is queued again (it resumes from its finished tiles).  Returns (job, created).
        Raises InvalidInputError when ``idem_key`` was used for a different spec.
        """
        spec_json = json.dumps(spec, sort_keys=True)
        now = time.time()
        with self._tx() as con:
            if idem_key is not None:
                row = con.execute("SELECT job_id AS id, spec FROM idem_keys WHERE idem_key = ?", (idem_key,)).fetchone()
                if row is None:  # stores written before the idem_keys table
                    row = con.execute("SELECT id, spec FROM jobs WHERE idem_key = ?", (idem_key,)).fetchone()
                if row is not None and row["spec"] != spec_json:
                    raise InvalidInputError("this Idempotency-Key was used for a different job spec: "
                                            "use a new key for a new job")
                if row is not None:
                    job_id = row["id"]
                else:  # recorded whether the job is new or already known under another key
                    con.execute("INSERT INTO idem_keys (idem_key, job_id, spec, created) VALUES (?,?,?,?)",
                                (idem_key, job_id, spec_json, now))
                    if con.execute("SELECT 1 FROM jobs WHERE id = ?", (job_id,)).fetchone() is not None:
                        idem_key = None  # the job row keeps its first key; this one lives in idem_keys
            row = con.execute("SELECT state FROM jobs WHERE id = ?", (job_id,)).fetchone()
            if row is not None:
                if row["state"] in ("failed", "cancelled"):
                    con.execute("UPDATE jobs SET state='queued', error=NULL, finished=NULL, updated=? WHERE id=?",
                                (now, job_id))
                    con.execute("UPDATE tiles SET attempts=0, error=NULL WHERE job_id=? AND state='pending'",
                                (job_id,))
                created = False
            else:
                tiles = tile_keys or {}
                con.execute(
                    "INSERT INTO jobs (id, kind, spec, idem_key, state, tiles_total, positions_total, created, updated)"
                    " VALUES (?,?,?,?,?,?,?,?,?)",
                    (job_id, kind, spec_json, idem_key, "queued", len(tiles), sum(tiles.values()), now, now))
                con.executemany("INSERT INTO tiles (job_id, tile_key, n_positions) VALUES (?,?,?)",
                                [(job_id, k, n) for k, n in tiles.items()])
                created = True
        return self.get_job(job_id=job_id), created

    def get_job(self, *, job_id: str) -> JobRecord:
        """The job with this id; JobNotFoundError when there is none."""
        row = self._con().execute(_JOB_SELECT + " WHERE j.id = ?", (job_id,)).fetchone()
        if row is None:
            raise JobNotFoundError(f"no job with id {job_id!r}: list jobs with GET /v1/jobs")
        return _job(row)

    def list_jobs(self, *, limit: int = 100, states: tuple[str, ...] | None = None) -> list[JobRecord]:
        """Jobs, newest first (optionally only those in ``states``)."""
        sql, args = _JOB_SELECT, []
        if states:
            sql += " WHERE j.state IN (%s)" % ",".join("?" * len(states))
            args = list(states)
        sql += " ORDER BY j.created DESC LIMIT ?"
        return [_job(r) for r in self._con().execute(sql, (*args, int(limit)))]

    def next_active_job(self) -> JobRecord | None:
        """The oldest job that still needs the runner (queued, running or cancel-requested)."""
        row = self._con().execute(
            _JOB_SELECT + " WHERE j.state IN ('queued','running','cancel-requested') ORDER BY j.created LIMIT 1"
        ).fetchone()
        return _job(row) if row is not None else None

    def set_state(self, *, job_id: str, state: str, error: str | None = None, expect: tuple[str, ...] | None = None,
                  **fields: Any) -> bool:
        """Move a job to ``state`` (only from ``expect`` states when given); returns whether it changed.

        Extra ``fields`` update columns (started, finished, run_started, result_path, result_sha256, result_bytes).
        """
        if state not in JOB_STATES:
            raise InvalidInputError(f"unknown job state {state!r}")
        allowed = {"started", "finished", "run_started", "result_path", "result_sha256", "result_bytes"}
        bad = set(fields) - allowed
        if bad:
            raise InvalidInputError(f"cannot set job fields {sorted(bad)}")
        cols = ["state=?", "error=?", "updated=?"] + [f"{k}=?" for k in fields]
        args: list[Any] = [state, error, time.time(), *fields.values()]
        sql = f"UPDATE jobs SET {', '.join(cols)} WHERE id=?"
        args.append(job_id)
        if expect:
            sql += " AND state IN (%s)" % ",".join("?" * len(expect))
            args += list(expect)
        with self._tx() as con:
            n = con.execute(sql, args).rowcount
            if n == 0 and con.execute("SELECT 1 FROM jobs WHERE id=?", (job_id,)).fetchone() is None:
                raise JobNotFoundError(f"no job with id {job_id!r}")
        return n > 0

    def request_cancel(self, *, job_id: str) -> JobRecord:
        """Ask to cancel: queued/running -> cancel-requested.  Finished jobs are returned unchanged."""
        self.get_job(job_id=job_id)
        self.set_state(job_id=job_id, state="cancel-requested", expect=("queued", "running"))
        return self.get_job(job_id=job_id)

    # -- tiles ---------------------------------------------------------------------------------
    def done_tiles(self, *, job_id: str) -> set[str]:
        rows = self._con().execute("SELECT tile_key FROM tiles WHERE job_id=? AND state='done'", (job_id,))
        return {r[0] for r in rows}

    def mark_tile_done(self, *, job_id: str, tile_key: str, recovered: bool = False) -> bool:
        """Record a finished tile (idempotent); returns whether it was newly marked."""
        with self._tx() as con:
            n = con.execute("UPDATE tiles SET state='done', done_at=?, recovered=?, error=NULL "
                            "WHERE job_id=? AND tile_key=? AND state!='done'",
                            (time.time(), int(recovered), job_id, tile_key)).rowcount
        return n > 0

    def record_render(self, *, job_id: str, tile_key: str, worker: str, started: float, finished: float) -> None:
        """Log one completed render of a tile and mark it done, in one transaction."""
        with self._tx() as con:
            con.execute("INSERT INTO tile_renders (job_id, tile_key, worker, pid, started, finished) "
                        "VALUES (?,?,?,?,?,?)", (job_id, tile_key, worker, os.getpid(), started, finished))
            con.execute("UPDATE tiles SET state='done', done_at=?, error=NULL WHERE job_id=? AND tile_key=? "
                        "AND state!='done'", (finished, job_id, tile_key))

    def tile_failed(self, *, job_id: str, tile_key: str, error: str) -> int:
        """Count a failed attempt of a tile; returns its number of failed attempts so far."""
        with self._tx() as con:
            con.execute("UPDATE tiles SET attempts=attempts+1, error=? WHERE job_id=? AND tile_key=?",
                        (error[:2000], job_id, tile_key))
            row = con.execute("SELECT attempts FROM tiles WHERE job_id=? AND tile_key=?", (job_id, tile_key)).fetchone()
        return int(row[0]) if row else 0

    def render_counts(self, *, job_id: str) -> dict[str, int]:
        """Completed renders per tile key (every tile of the job, 0 when never rendered)."""
        con = self._con()
        counts = {r[0]: 0 for r in con.execute("SELECT tile_key FROM tiles WHERE job_id=?", (job_id,))}
        for key, n in con.execute("SELECT tile_key, COUNT(*) FROM tile_renders WHERE job_id=? GROUP BY tile_key",
                                  (job_id,)):
            counts[key] = int(n)
        return counts

    def recovered_tiles(self, *, job_id: str) -> set[str]:
        rows = self._con().execute("SELECT tile_key FROM tiles WHERE job_id=? AND recovered=1", (job_id,))
        return {r[0] for r in rows}


_JOB_SELECT = """
SELECT j.*,
  (SELECT COUNT(*) FROM tiles t WHERE t.job_id=j.id AND t.state='done') AS tiles_done,
  (SELECT COALESCE(SUM(t.n_positions),0) FROM tiles t WHERE t.job_id=j.id AND t.state='done') AS positions_done,
  (SELECT COALESCE(SUM(t.n_positions),0) FROM tiles t WHERE t.job_id=j.id AND t.state='done'
     AND t.recovered=0 AND j.run_started IS NOT NULL AND t.done_at >= j.run_started) AS positions_done_this_run
FROM jobs j"""


def _job(row: sqlite3.Row) -> JobRecord:
    return JobRecord(
        id=row["id"], kind=row["kind"], spec=json.loads(row["spec"]), state=row["state"],
        tiles_total=row["tiles_total"], tiles_done=row["tiles_done"], positions_total=row["positions_total"],
        positions_done=row["positions_done"], positions_done_this_run=row["positions_done_this_run"],
        error=row["error"], created=row["created"], started=row["started"], finished=row["finished"],
        run_started=row["run_started"], result_path=row["result_path"], result_sha256=row["result_sha256"],
        result_bytes=row["result_bytes"], idem_key=row["idem_key"])


def _body_key(info: dict) -> str:
    body = info.get("body") or {}
    return f"{body.get('name')}:{float(body.get('radius_m') or 0.0)!r}"


def _migrate_dems(con: sqlite3.Connection) -> None:
    """Stores made before DEMs were keyed by body had ``sha256 UNIQUE``: rebuild that table without it."""
    row = con.execute("SELECT sql FROM sqlite_master WHERE type='table' AND name='dems'").fetchone()
    if row is None or "UNIQUE" not in row[0].upper():
        return
    con.execute("BEGIN IMMEDIATE")
    try:
        con.execute("ALTER TABLE dems RENAME TO dems_old")
        con.execute("CREATE TABLE dems (id TEXT PRIMARY KEY, sha256 TEXT NOT NULL, filename TEXT NOT NULL, "
                    "path TEXT NOT NULL, body TEXT, info TEXT NOT NULL, created REAL NOT NULL)")
        con.execute("INSERT INTO dems SELECT id, sha256, filename, path, body, info, created FROM dems_old")
        con.execute("DROP TABLE dems_old")
    except BaseException:
        con.execute("ROLLBACK")
        raise
    con.execute("COMMIT")
    log.info("job store: DEM table migrated (one record per file and body)")


def _dem(row: sqlite3.Row) -> DemRecord:
    return DemRecord(id=row["id"], sha256=row["sha256"], filename=row["filename"], path=row["path"],
                     body=row["body"], info=json.loads(row["info"]), created=row["created"])
