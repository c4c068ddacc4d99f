"""Render the test sets of a scene file into a dataset folder (layout: :mod:`blender_addon.core.dataset`).

Same scene file, same seed: same images (Cycles' sampling seed, rocks, textures and sensor
noise all derive from it).  An interrupted run resumes: an acquisition whose folder already
holds a manifest made from the same job (``meta.job_key``) is kept.

``generate_dataset`` is what the render service runs for dataset jobs; ``progress`` follows
:mod:`board.progress`: ``progress(done, total, message)`` with ``done`` counting acquisitions, called
after each acquisition and, with the current step in ``message``, while one is built and rendered.
"""
from __future__ import annotations

import logging
import os
import shutil
import time
from pathlib import Path
from typing import Sequence

from blender_addon.core.acquire import AcquisitionJob, job_dict
from blender_addon.core.dataset import (
    DATASET_MANIFEST,
    SET_MANIFEST,
    dataset_manifest,
    grid_half_m,
    is_done,
    job_key,
    load_dataset_scene,
    set_manifest,
    site_dem,
    site_manifest,
    write_manifest,
)
from blender_addon.core.degrade import check_look_body
from blender_addon.sim.simulator import Simulator
from blender_addon.terrain.dem import dem_info
from board.progress import Progress, report

log = logging.getLogger(__name__)


def generate_dataset(scene_toml: str | os.PathLike, out_dir: str | os.PathLike, *, progress: Progress | None = None,
                     sets: Sequence[str] | None = None, cache_dir: str | os.PathLike | None = None,
                     resume: bool = True, limit: int | None = None, width: int | None = None,
                     samples: int | None = None) -> Path:
    """Render every set of ``scene_toml`` (or only ``sets``) into ``out_dir``; returns the dataset.json path.

    limit : at most this many acquisitions per set (the first ones: same poses and seeds)
    width : render every camera at this width (same fields of view), e.g. for a quick preview
    samples : Cycles samples per pixel instead of the scene's
    The overrides are recorded in dataset.json.  Raises InvalidInputError for a bad scene file
    or option before anything is rendered.
    """
    scene, chosen, jobs_by_set = load_dataset_scene(scene_toml, sets=sets, limit=limit, width=width, samples=samples)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cache = Path(cache_dir) if cache_dir is not None else None
    (out / "scene.toml").write_text(scene.text)
    total = sum(len(j) for j in jobs_by_set.values())
    done = 0
    t0 = time.perf_counter()
    site_docs: dict[str, dict] = {}
    set_docs: list[dict] = []
    for site_name in dict.fromkeys(s.site for s in chosen):
        site = scene.sites[site_name]
        site_sets = [s for s in chosen if s.site == site_name]
        all_jobs = [j for s in site_sets for j in jobs_by_set[s.name]]
        dem_spec, dem_path = site_dem(site, out, cache)
        info = dem_info(dem_path, body=site.body)
        warned: set[str] = set()
        sim: Simulator | None = None   # built only when something must be rendered
        for s in site_sets:
            set_dir = out / s.name
            set_dir.mkdir(exist_ok=True)
            for stale in set_dir.glob(".acq_*.part"):      # left by an interrupted run
                shutil.rmtree(stale, ignore_errors=True)
            entries = []
            for i, job in enumerate(jobs_by_set[s.name]):
                folder = set_dir / f"acq_{i:03d}"
                key = job_key(job, info.sha256)
                if resume and is_done(folder, key):
                    log.info("%s exists (same job): kept", folder)
                else:
                    if job.degradation.name not in warned:
                        warned.add(job.degradation.name)
                        check_look_body(job.degradation, info.body.name)
                    if sim is None:
                        report(progress, done, total, f"building the terrain of site {site.name}")
                        sim = Simulator(dem_path, site.center, grid_half_m=grid_half_m(scene, site, all_jobs),
                                        max_radius_m=site.max_radius_m, body=site.body, cache_dir=cache)
                        sim.dem_spec = dem_spec
                    job = AcquisitionJob(job.pose, job.camera, job.plan, job.degradation, job.seed, job.samples,
                                         job.denoise, job.imu_sigma_deg, {**job.meta, "job_key": key})
                    step = f"{s.name} {i + 1}/{len(jobs_by_set[s.name])}"
                    sim.acquire(job, folder, progress=lambda k, n, msg, step=step: report(
                        progress, done, total, f"{step}: {msg or f'frame {k}/{n}'}"))
                entries.append({"dir": f"{s.name}/{folder.name}", "job_key": key, **job_dict(job),
                                "imu_sigma_deg": job.imu_sigma_deg})
                done += 1
                report(progress, done, total, f"{s.name} {i + 1}/{len(jobs_by_set[s.name])}")
            doc = set_manifest(scene, s, site, entries)
            write_manifest(set_dir / SET_MANIFEST, doc)
            set_docs.append({k: doc[k] for k in ("name", "description", "site", "camera", "plan", "seed")}
                            | {"dir": s.name, "count": len(entries), "degradations": list(s.degradations)})
        site_docs[site.name] = site_manifest(site, dem_spec, info)
    manifest = dataset_manifest(scene, site_docs, set_docs, elapsed_s=time.perf_counter() - t0,
                                overrides={"limit": limit, "width": width, "samples": samples})
    path = write_manifest(out / DATASET_MANIFEST, manifest)
    log.info("dataset %s: %d acquisitions in %s", scene.name, total, out)
    return path
