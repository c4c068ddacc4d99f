"""Simulated NavCam acquisitions in Blender: terrain + dressing + pan-tilt frames + degradations -> folder.

One :class:`Simulator` keeps a site's terrain built in Blender and renders any number of
acquisitions at poses near it (the jobs, checks and manifests are :mod:`blender_addon.core.acquire`'s):

    sim = Simulator("procedural:mars:7", site_xy=(0.0, 0.0), grid_half_m=300)
    sim.acquire(AcquisitionJob(Pose(10, 20, heading_deg=45), get_preset("exomars"),
                               plan_frames(13, 360, 65), get_degradation("realistic"), seed=1), "out/acq")

Geometry: the optical centre is ``mast_height_m`` above the ground at (x, y), whatever the
pitch and roll (the skyline database's model); pitch and roll rotate the camera about it.
Each frame is rendered as an ideal pinhole slightly larger than the camera
(:func:`blender_addon.core.degrade.render_camera_for`), then distorted, dispersed and made
noisy in numpy.
"""
from __future__ import annotations

import logging
import os
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np

from blender_addon import scene as bscene
from blender_addon.core.acquire import (
    AcquisitionJob,
    Progress,
    acquisition_record,
    check_pose,
    frame_seed_sequence,
    load_terrain,
    simulation_meta,
    write_acquisition_folder,
)
from blender_addon.core.degrade import decode_render, degrade_frame, render_camera_for
from blender_addon.core.terrain_mesh import sample_height
from blender_addon.scene import dressing
from blender_addon.scene.pantilt import point_camera
from blender_addon.terrain.dem import resolve_dem
from board.camera import rotation_enu_from_frame

log = logging.getLogger(__name__)


class Simulator:
    """A Blender session holding one site's terrain, rendering acquisitions near the site.

    dem : a DEM path or ``procedural:PRESET:SEED[...]`` spec (resolved with
        :func:`blender_addon.terrain.dem.resolve_dem`)
    site_xy : centre of the terrain's finest level (metres, the DEM's metric CRS)
    grid_half_m : half-width of the area (around the site) where poses may lie, metres
    max_radius_m : terrain kept beyond that area, metres (default: to the DEM's edge)
    """

    def __init__(self, dem: str | os.PathLike, site_xy: tuple[float, float], *, grid_half_m: float = 200.0,
                 max_radius_m: float | None = None, body: str | float | None = None,
                 cache_dir: str | os.PathLike | None = None, progress: Progress | None = None) -> None:
        self.dem_spec = str(dem)
        self.dem_path = resolve_dem(dem, cache_dir=cache_dir)
        self.site_xy = (float(site_xy[0]), float(site_xy[1]))
        t0 = time.perf_counter()
        self.terrain = load_terrain(self.dem_path, self.site_xy, grid_half_m=grid_half_m, max_radius_m=max_radius_m,
                                    body=body)
        self.grid_half_m = float(grid_half_m)
        self._token = uuid.uuid4().hex
        self._build()
        log.info("simulator: terrain of %s around (%.1f, %.1f) built in %.1f s", self.dem_spec, *self.site_xy,
                 time.perf_counter() - t0)

    @classmethod
    def adopt(cls, terrain, *, dem_spec: str, dem_path: str | os.PathLike | None = None,
              grid_half_m: float = 200.0) -> "Simulator":
        """A Simulator over ``terrain`` already built in the current Blender scene (by
        :func:`blender_addon.scene.build_terrain`), without resetting the session: safe inside an
        operator, where a factory reset would free the operator's own context."""
        sim = cls.__new__(cls)
        sim.dem_spec = str(dem_spec)
        sim.dem_path = Path(dem_path) if dem_path is not None else Path(str(dem_spec))
        sim.site_xy = (float(terrain.site_xy[0]), float(terrain.site_xy[1]))
        sim.terrain = terrain
        sim.grid_half_m = float(grid_half_m)
        sim._token = uuid.uuid4().hex
        bscene.state.get_scene()["skyloc_simulator"] = sim._token
        return sim

    def _build(self) -> None:
        """(Re)build the Blender scene: empty session, terrain meshes, and this simulator's token."""
        bscene.reset_scene()
        bscene.build_terrain(self.terrain)
        bscene.state.get_scene()["skyloc_simulator"] = self._token

    def ensure_scene(self) -> None:
        """Rebuild the terrain if another Simulator (or anything else) reset the Blender session since
        (call it before rendering into the current scene directly, e.g. with ``make_panorama(build=False)``)."""
        if bscene.state.get_scene().get("skyloc_simulator") != self._token:
            log.info("simulator: the Blender scene was replaced; rebuilding the terrain")
            self._build()

    def ground_z(self, x: float, y: float) -> float:
        """Ground height (metres) at world (x, y)."""
        return sample_height(self.terrain, x, y)

    def render_frames(self, job: AcquisitionJob, *, progress: Progress | None = None,
                      work_dir: str | os.PathLike | None = None) -> tuple[list[np.ndarray], dict]:
        """Render and degrade every frame of ``job``; returns (RGB images, simulation metadata)."""
        check_pose(job.pose, self.site_xy, self.grid_half_m)
        self.ensure_scene()
        deg = job.degradation
        p = job.pose
        cam = job.camera.camera_model(**deg.lens.distortion)
        pinhole = render_camera_for(cam, dispersion=deg.lens.dispersion)
        info = dressing.dress_scene(self.terrain, deg, center_xy=(p.x, p.y), heading_deg=p.heading_deg,
                                    seed=job.seed, samples=job.samples, denoise=job.denoise)
        z = self.ground_z(p.x, p.y) + job.camera.mast_height_m
        sun_enu = np.asarray(info.sun_dir_enu)
        sun_seen = (not deg.binary) and info.sun_elevation_deg > 0 and dressing.sun_visible(p.x, p.y, z, sun_enu)
        images = []
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory(prefix="skyloc-frames-", dir=work_dir) as tmp:
            for i, (pan, tilt) in enumerate(job.plan.frames()):
                point_camera(p.x, p.y, z, p.heading_deg, p.pitch_deg, p.roll_deg, pan, tilt)
                path = bscene.render_frame(Path(tmp) / f"render_{i:03d}.png", pinhole,
                                           color_depth="8" if deg.binary else "16")
                raw = bscene.read_image(path)
                lin = raw if deg.binary else decode_render(raw)
                R = rotation_enu_from_frame(pan, tilt, heading_deg=p.heading_deg, pitch_deg=p.pitch_deg,
                                            roll_deg=p.roll_deg)
                rng = np.random.default_rng(frame_seed_sequence(job.seed, i))
                images.append(degrade_frame(lin, pinhole, cam, deg, rng,
                                            sun_dir_cam=(sun_enu @ R) if sun_seen else None))
                if progress is not None:
                    progress(i + 1, job.plan.n_frames, f"frame {i + 1}/{job.plan.n_frames}")
        meta = simulation_meta(job, render_pinhole=pinhole.to_dict(), dressing=info.to_dict(), sun_visible=sun_seen,
                               dem_sha256=self.terrain.dem_sha256, render_seconds=time.perf_counter() - t0)
        return images, meta

    def acquire(self, job: AcquisitionJob, out_dir: str | os.PathLike, *,
                progress: Progress | None = None) -> Path:
        """Render ``job`` into the acquisition folder ``out_dir`` (replaced atomically); returns its path."""
        images, meta = self.render_frames(job, progress=progress)
        acq = acquisition_record(job, meta, eye_z_m=self.ground_z(job.pose.x, job.pose.y) + job.camera.mast_height_m,
                                 crs_wkt=self.terrain.crs_wkt, dem_spec=self.dem_spec)
        return write_acquisition_folder(out_dir, acq, images)
