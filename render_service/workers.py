"""Dask worker side of the render service: a WorkerPlugin that loads each terrain once per worker.

A database job's tiles all need the same multi-resolution terrain (written by the job under
``DATA/jobs/<id>/terrain``).  :class:`TerrainPlugin` keeps the last few loaded terrains per
worker process, so every worker reads a terrain from disk once however many tiles it renders.
Workers also get a numba thread budget so that N single-threaded worker processes do not
oversubscribe the machine's cores.
"""
from __future__ import annotations

import logging
import os
import threading
from collections import OrderedDict

from distributed import WorkerPlugin, get_worker

log = logging.getLogger(__name__)

PLUGIN_NAME = "skyloc-terrain"


def _load_multires(terrain_dir: str):
    from blender_addon.terrain.multires import load_multires  # noqa: PLC0415 (heavy, worker-only)

    return load_multires(terrain_dir)


class TerrainPlugin(WorkerPlugin):
    """Per-worker cache of multi-resolution terrains keyed by their folder.

    numba_threads : numba threads in each worker (None: leave numba's default)
    cache_size : terrains kept in memory per worker (least recently used dropped)
    """

    name = PLUGIN_NAME

    def __init__(self, *, numba_threads: int | None = None, cache_size: int = 2) -> None:
        self.numba_threads = numba_threads
        self.cache_size = cache_size
        self._cache: OrderedDict[str, object] = OrderedDict()
        self._lock = threading.Lock()
        self.loads = 0

    def __getstate__(self) -> dict:  # sent to workers: settings only, no cache or lock
        return {"numba_threads": self.numba_threads, "cache_size": self.cache_size}

    def __setstate__(self, state: dict) -> None:
        self.__init__(**state)

    def setup(self, worker) -> None:  # noqa: D102 (Dask hook)
        if self.numba_threads:
            os.environ["NUMBA_NUM_THREADS"] = str(self.numba_threads)
            try:
                import numba  # noqa: PLC0415

                numba.set_num_threads(min(self.numba_threads, numba.config.NUMBA_NUM_THREADS))
            except Exception as exc:  # numba missing or already initialised differently: not fatal
                log.debug("numba thread budget not applied: %s", exc)

    def terrain(self, terrain_dir: str):
        """The MultiResTerrain stored in ``terrain_dir``, loaded on first use in this worker."""
        key = os.path.abspath(terrain_dir)
        with self._lock:
            if key in self._cache:
                self._cache.move_to_end(key)
                return self._cache[key]
            terrain = _load_multires(key)
            self.loads += 1
            self._cache[key] = terrain
            while len(self._cache) > self.cache_size:
                self._cache.popitem(last=False)
            log.info("worker loaded terrain %s", key)
            return terrain


def worker_terrain(terrain_dir: str):
    """The terrain of ``terrain_dir`` from this worker's plugin (loaded directly outside a worker)."""
    try:
        worker = get_worker()
    except ValueError:
        return _load_multires(terrain_dir)
    plugin = worker.plugins.get(PLUGIN_NAME)
    if plugin is None:  # a worker of a foreign cluster that missed the registration
        plugin = TerrainPlugin()
        worker.plugins[PLUGIN_NAME] = plugin
    return plugin.terrain(terrain_dir)


def worker_name() -> str:
    """Address of the current Dask worker, or ``local:<pid>`` outside one."""
    try:
        return str(get_worker().address)
    except ValueError:
        return f"local:{os.getpid()}"
