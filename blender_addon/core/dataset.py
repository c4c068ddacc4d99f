"""Render the test sets of a scene file into a dataset folder.

Layout of ``out_dir``::

    dataset.json            the whole dataset: scene, sites (DEM, hash, CRS), sets and their acquisitions
    scene.toml              copy of the scene file it was made from
    sites/<site>.tif        flattened DEMs of sites with z_scale != 1 (the DEM to build databases from)
    <SET>/manifest.json     the set: description, camera, plan, degradations, every acquisition's truth
    <SET>/acq_000/          acquisition folders (board.acquisition format, truth in the manifest)

Same scene file, same seed: same images (Cycles' sampling seed, rocks, textures and sensor
noise all derive from it).  An interrupted run resumes: an acquisition whose folder already
holds a manifest made from the same job (``meta.job_key``) is kept.

``generate_dataset`` is what the render service runs for dataset jobs; ``progress`` follows
:mod:`board.progress`: ``progress(done, total, message)`` with ``done`` counting acquisitions, called
after each acquisition and, with the current step in ``message``, while one is built and rendered.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import time
from dataclasses import replace
from pathlib import Path
from typing import Sequence

from blender_addon.core.acquire import AcquisitionJob, Simulator, job_dict
from blender_addon.core.degrade import check_look_body
from blender_addon.core.scene_spec import SceneSpec, SiteSpec, load_scene, set_jobs, set_seed
from board.acquisition import ACQUISITION_MANIFEST
from board.atomic import write_json_atomic
from board.errors import InvalidInputError
from board.progress import Progress, report

log = logging.getLogger(__name__)

DATASET_FORMAT = "skyloc-dataset"
DATASET_VERSION = 1
DATASET_MANIFEST = "dataset.json"
SET_MANIFEST = "manifest.json"


def _write_json(path: Path, doc: dict) -> None:
    write_json_atomic(path, doc, indent=1)


def scaled_dem(src: Path, z_scale: float, out: Path) -> Path:
    """A copy of DEM ``src`` with heights multiplied by ``z_scale`` (GeoTIFF, kept if already there)."""
    if out.is_file():
        return out
    from osgeo import gdal

    gdal.UseExceptions()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.stem + ".part.tif")
    ds = gdal.Open(str(src))
    band = ds.GetRasterBand(1)
    nodata = band.GetNoDataValue()
    drv = gdal.GetDriverByName("GTiff")
    dst = drv.Create(str(tmp), ds.RasterXSize, ds.RasterYSize, 1, gdal.GDT_Float32,
                     ["TILED=YES", "COMPRESS=DEFLATE", "PREDICTOR=3"])
    dst.SetGeoTransform(ds.GetGeoTransform())
    dst.SetProjection(ds.GetProjectionRef())
    ob = dst.GetRasterBand(1)
    if nodata is not None:
        ob.SetNoDataValue(nodata)
    step = 512
    for r0 in range(0, ds.RasterYSize, step):
        rows = min(step, ds.RasterYSize - r0)
        a = band.ReadAsArray(0, r0, ds.RasterXSize, rows).astype("float32")
        keep = a == nodata if nodata is not None else None
        a = a * float(z_scale)
        if keep is not None:
            a[keep] = nodata
        ob.WriteArray(a, 0, r0)
    ob.FlushCache()
    dst = None
    ds = None
    os.replace(tmp, out)
    return out


def _site_dem(site: SiteSpec, out_dir: Path, cache_dir: Path | None) -> tuple[str, Path]:
    """(DEM spec recorded in the truth, DEM path to render) of a site."""
    from blender_addon.terrain.dem import resolve_dem

    path = resolve_dem(site.dem, cache_dir=cache_dir)
    if site.z_scale == 1.0:
        return site.dem, path
    scaled = scaled_dem(path, site.z_scale, out_dir / "sites" / f"{site.name}.tif")
    return str(scaled), scaled


def job_key(job: AcquisitionJob, dem_sha256: str) -> str:
    """Stable hash of everything that determines an acquisition's bytes."""
    doc = {"job": job_dict(job), "degradation": job.degradation.to_dict(), "dem": dem_sha256,
           "imu": job.imu_sigma_deg, "denoise": job.denoise}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


def _done(folder: Path, key: str) -> bool:
    m = folder / ACQUISITION_MANIFEST
    if not m.is_file():
        return False
    try:
        return json.loads(m.read_text()).get("meta", {}).get("job_key") == key
    except (OSError, json.JSONDecodeError):
        return False


def _grid_half(scene: SceneSpec, site: SiteSpec, jobs: Sequence[AcquisitionJob]) -> float:
    rock_r = max([j.degradation.rocks.radius_m for j in jobs if j.degradation.rocks.density_per_m2 > 0] + [0.0])
    near = max([j.degradation.rocks.near_distance_m[1] for j in jobs] + [0.0])
    return site.pose_half_m + max(rock_r, near) + 20.0


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
    scene = load_scene(scene_toml)
    if limit is not None and limit < 1:
        raise InvalidInputError(f"limit must be >= 1 acquisition per set, got {limit}")
    if width is not None and width < 8:
        raise InvalidInputError(f"width must be at least 8 pixels, got {width}")
    if samples is not None and samples < 1:
        raise InvalidInputError(f"samples must be >= 1, got {samples}")
    if width is not None:
        scene = replace(scene, cameras={k: c.resized(width) for k, c in scene.cameras.items()})
    if samples is not None:
        scene = replace(scene, samples=int(samples))
    chosen = [s for s in scene.sets if sets is None or s.name in sets]
    if sets is not None:
        unknown = sorted(set(sets) - {s.name for s in scene.sets})
        if unknown:
            raise InvalidInputError(f"sets {', '.join(unknown)} are not in {scene_toml}; "
                                    f"it defines {', '.join(s.name for s in scene.sets)}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cache = Path(cache_dir) if cache_dir is not None else None
    (out / "scene.toml").write_text(scene.text)
    jobs_by_set = {s.name: set_jobs(scene, s)[:limit] for s in chosen}
    total = sum(len(j) for j in jobs_by_set.values())
    done = 0
    t0 = time.perf_counter()
    site_docs: dict[str, dict] = {}
    set_docs: list[dict] = []
    for site_name in dict.fromkeys(s.site for s in chosen):
        site = scene.sites[site_name]
        site_sets = [s for s in chosen if s.site == site_name]
        all_jobs = [j for s in site_sets for j in jobs_by_set[s.name]]
        dem_spec, dem_path = _site_dem(site, out, cache)
        from blender_addon.terrain.dem import dem_info

        info = dem_info(dem_path, body=site.body)
        warned: set[str] = set()
        sim: Simulator | None = None   # built only when something must be rendered
        for s in site_sets:
            set_dir = out / s.name
            set_dir.mkdir(exist_ok=True)
            for stale in set_dir.glob(".acq_*.partial*"):      # left by an interrupted run
                shutil.rmtree(stale, ignore_errors=True)
            entries = []
            for i, job in enumerate(jobs_by_set[s.name]):
                folder = set_dir / f"acq_{i:03d}"
                key = job_key(job, info.sha256)
                if resume and _done(folder, key):
                    log.info("%s exists (same job): kept", folder)
                else:
                    if job.degradation.name not in warned:
                        warned.add(job.degradation.name)
                        check_look_body(job.degradation, info.body.name)
                    if sim is None:
                        report(progress, done, total, f"building the terrain of site {site.name}")
                        sim = Simulator(dem_path, site.center, grid_half_m=_grid_half(scene, site, all_jobs),
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
            doc = {"format": DATASET_FORMAT + "-set", "version": DATASET_VERSION, "name": s.name,
                   "description": s.description, "site": site.name, "camera": scene.cameras[s.camera].name,
                   "plan": s.plan, "degradations": {d: (scene.degradations.get(d) or _preset(d)).to_dict()
                                                    for d in s.degradations},
                   "seed": set_seed(scene, s), "poses_from": s.poses_from, "acquisitions": entries}
            _write_json(set_dir / SET_MANIFEST, doc)
            set_docs.append({k: doc[k] for k in ("name", "description", "site", "camera", "plan", "seed")}
                            | {"dir": s.name, "count": len(entries), "degradations": list(s.degradations)})
        site_docs[site.name] = {"dem": dem_spec, "dem_sha256": info.sha256, "crs_wkt": info.crs_wkt,
                                "center": list(site.center), "pose_half_m": site.pose_half_m,
                                "z_scale": site.z_scale, "body": info.body.name,
                                "body_radius_m": info.body.radius_m}
    manifest = {"format": DATASET_FORMAT, "version": DATASET_VERSION, "name": scene.name,
                "description": scene.description, "seed": scene.seed, "samples": scene.samples,
                "scene_file": "scene.toml", "scene_sha256": hashlib.sha256(scene.text.encode()).hexdigest(),
                "sites": site_docs, "sets": set_docs, "elapsed_s": round(time.perf_counter() - t0, 1),
                "overrides": {"limit": limit, "width": width, "samples": samples}}
    path = out / DATASET_MANIFEST
    _write_json(path, manifest)
    log.info("dataset %s: %d acquisitions in %s", scene.name, total, out)
    return path


def _preset(name: str):
    from blender_addon.core.degrade import PRESETS

    return PRESETS[name]
