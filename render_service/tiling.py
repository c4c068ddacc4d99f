"""Jobs to tiles to Dask (compatibility names): the code lives in four small modules.

* :mod:`render_service.planning` -- typed job specs, job ids, limits, the tile plan;
* :mod:`render_service.tasks` -- the Dask tasks (terrain, tile, dataset);
* :mod:`render_service.result_zip` -- the published ``result.zip`` with its ``MANIFEST.sha256``;
* :mod:`render_service.runner` -- the job runner thread (resume, retries, cancel, faults).
"""
from __future__ import annotations

from render_service.planning import DbPlan, canonical_json, job_id_for, parse_spec, plan_db_job, prepare_db_job
from render_service.result_zip import MANIFEST_NAME, RESULT_NAME, file_sha256, write_result_zip
from render_service.runner import JobRunner
from render_service.tasks import build_terrain_task, dataset_task, render_tile_task, terrain_levels_task

__all__ = ["DbPlan", "JobRunner", "MANIFEST_NAME", "RESULT_NAME", "build_terrain_task", "canonical_json",
           "dataset_task", "file_sha256", "job_id_for", "parse_spec", "plan_db_job", "prepare_db_job",
           "render_tile_task", "terrain_levels_task", "write_result_zip"]
