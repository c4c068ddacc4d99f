"""The Dask tasks of the render service (run on workers: importable there, arguments picklable).

* :func:`build_terrain_task` builds a job's multi-resolution terrain once, into ``jobs/<id>/terrain``;
* :func:`terrain_levels_task` describes that terrain's levels (the ``terrain_levels`` metadata the CLI
  writes into every database);
* :func:`render_tile_task` renders one tile, writes its own Zarr chunk through
  :class:`board.skydb.SkyDBWriter` (which marks the tile done in the store's ``tile_done`` array),
  then logs the render and the tile's completion in the SQLite job store;
* :func:`dataset_task` renders a simulator test set.

Every task writes beside its target and renames, and removes what it wrote beside when it fails.
"""
from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

from board.atomic import publish_dir
from board.skydb import Tile
from render_service.store import JobStore
from render_service.workers import worker_name, worker_terrain

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
    tmp = out.with_name(out.name + f".tmp-{os.getpid()}")     # runner.clean_job_temporaries sweeps ".tmp-"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        load_terrain(rjob, terrain_dir=tmp)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    publish_dir(tmp, out)           # another worker may have published it first
    return str(out)


def terrain_levels_task(terrain_dir: str) -> list[dict]:
    """The levels of a built terrain as the CLI records them: ``[{"cell_m", "bounds"}, ...]`` (metres)."""
    terrain = worker_terrain(terrain_dir)
    return [{"cell_m": float(lv.cell_m), "bounds": [float(b) for b in lv.bounds()]} for lv in terrain.levels]


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
    from blender_addon.sim import generate_dataset  # noqa: PLC0415

    out = Path(out_dir)
    partial = out.with_name(out.name + ".partial")
    generate_dataset(scene_toml, partial)
    if out.exists():
        shutil.rmtree(out)
    os.rename(partial, out)
    return str(out)
