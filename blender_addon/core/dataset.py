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

This module is the bpy-free part (layout, job keys, resume checks, scaled DEMs, the manifests);
:func:`blender_addon.sim.generate_dataset` renders with it (what the render service runs for dataset jobs).
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
from dataclasses import replace
from pathlib import Path
from typing import Sequence

from blender_addon.core.acquire import AcquisitionJob, job_dict
from blender_addon.core.scene_spec import SceneSpec, SiteSpec, load_scene, set_jobs, set_seed
from board.acquisition import ACQUISITION_MANIFEST
from board.atomic import atomic_path, write_json_atomic
from board.errors import InvalidInputError

log = logging.getLogger(__name__)

DATASET_FORMAT = "skyloc-dataset"
DATASET_VERSION = 1
DATASET_MANIFEST = "dataset.json"
SET_MANIFEST = "manifest.json"


def scaled_dem(src: Path, z_scale: float, out: Path) -> Path:
    """A copy of DEM ``src`` with heights multiplied by ``z_scale`` (GeoTIFF, kept if already there)."""
    if out.is_file():
        return out
    from osgeo import gdal

    gdal.UseExceptions()
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out, suffix=".part.tif") as tmp:
        _write_scaled(gdal, src, z_scale, tmp)
    return out


def _write_scaled(gdal, src: Path, z_scale: float, tmp: Path) -> None:
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


def site_dem(site: SiteSpec, out_dir: Path, cache_dir: Path | None) -> tuple[str, Path]:
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


def is_done(folder: Path, key: str) -> bool:
    m = folder / ACQUISITION_MANIFEST
    if not m.is_file():
        return False
    try:
        return json.loads(m.read_text()).get("meta", {}).get("job_key") == key
    except (OSError, json.JSONDecodeError):
        return False


def grid_half_m(scene: SceneSpec, site: SiteSpec, jobs: Sequence[AcquisitionJob]) -> float:
    rock_r = max([j.degradation.rocks.radius_m for j in jobs if j.degradation.rocks.density_per_m2 > 0] + [0.0])
    near = max([j.degradation.rocks.near_distance_m[1] for j in jobs] + [0.0])
    return site.pose_half_m + max(rock_r, near) + 20.0


def degradation_preset(name: str):
    from blender_addon.core.degrade import PRESETS

    return PRESETS[name]


def load_dataset_scene(scene_toml: str | os.PathLike, *, sets: Sequence[str] | None = None, limit: int | None = None,
                       width: int | None = None, samples: int | None = None):
    """The scene of ``scene_toml`` with the overrides applied, the chosen sets and their jobs.

    Returns (scene, chosen sets, {set name: jobs}); raises InvalidInputError for a bad scene file or
    option (before anything is rendered)."""
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
    return scene, chosen, {s.name: set_jobs(scene, s)[:limit] for s in chosen}


def set_manifest(scene: SceneSpec, s, site: SiteSpec, entries: list[dict]) -> dict:
    """The ``<SET>/manifest.json`` document of set ``s``."""
    return {"format": DATASET_FORMAT + "-set", "version": DATASET_VERSION, "name": s.name,
            "description": s.description, "site": site.name, "camera": scene.cameras[s.camera].name,
            "plan": s.plan, "degradations": {d: (scene.degradations.get(d) or degradation_preset(d)).to_dict()
                                             for d in s.degradations},
            "seed": set_seed(scene, s), "poses_from": s.poses_from, "acquisitions": entries}


def site_manifest(site: SiteSpec, dem_spec: str, info) -> dict:
    """A site's entry of ``dataset.json`` (``info``: the DEM's :func:`~blender_addon.terrain.dem.dem_info`)."""
    return {"dem": dem_spec, "dem_sha256": info.sha256, "crs_wkt": info.crs_wkt,
            "center": list(site.center), "pose_half_m": site.pose_half_m,
            "z_scale": site.z_scale, "body": info.body.name,
            "body_radius_m": info.body.radius_m}


def dataset_manifest(scene: SceneSpec, site_docs: dict, set_docs: list[dict], *, elapsed_s: float,
                     overrides: dict) -> dict:
    """The ``dataset.json`` document."""
    return {"format": DATASET_FORMAT, "version": DATASET_VERSION, "name": scene.name,
            "description": scene.description, "seed": scene.seed, "samples": scene.samples,
            "scene_file": "scene.toml", "scene_sha256": hashlib.sha256(scene.text.encode()).hexdigest(),
            "sites": site_docs, "sets": set_docs, "elapsed_s": round(elapsed_s, 1), "overrides": overrides}


def write_manifest(path: Path, doc: dict) -> Path:
    """Write a dataset or set manifest atomically."""
    return write_json_atomic(path, doc, indent=1)
