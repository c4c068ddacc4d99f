"""Simulated NavCam acquisitions: terrain + dressing + pan-tilt frames + degradations -> acquisition folder.

This module holds no bpy code itself; it drives the Blender layer (imported when a
:class:`Simulator` is created) and the numpy degradations.  One :class:`Simulator` keeps a
site's terrain built in Blender and renders any number of acquisitions at poses near it:

    sim = Simulator("procedural:mars:7", site_xy=(0.0, 0.0), grid_half_m=300)
    sim.acquire(AcquisitionJob(Pose(10, 20, heading_deg=45), get_preset("exomars"),
                               plan_frames(13, 360, 65), get_degradation("realistic"), seed=1), "out/acq")

Geometry: the optical centre is ``mast_height_m`` above the ground at (x, y), whatever the
pitch and roll (the skyline database's model); pitch and roll rotate the camera about it.
Each frame is rendered as an ideal pinhole slightly larger than the camera
(:func:`blender_addon.core.degrade.render_camera_for`), then distorted, dispersed and made
noisy in numpy.  Ground truth and the degradation parameters go into the manifest
(:mod:`board.acquisition`); the calibrated camera carries the Brown-Conrady coefficients.
"""
from __future__ import annotations

import logging
import math
import os
import shutil
import tempfile
import time
import uuid
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from blender_addon.core.cameras import CameraPreset
from blender_addon.core.degrade import Degradation, decode_render, degrade_frame, render_camera_for
from blender_addon.core.plans import PanTiltPlan
from board.acquisition import Acquisition, FrameInfo, GroundTruth, write_acquisition
from board.camera import rotation_enu_from_frame
from board.errors import InvalidInputError

log = logging.getLogger(__name__)

#: Cycles samples per pixel at the default quality.
DEFAULT_SAMPLES = 16

Progress = Callable[[int, int, str], None]


@dataclass(frozen=True)
class Pose:
    """Rover pose: position (metres, the DEM's metric CRS) and attitude (degrees)."""

    x: float
    y: float
    heading_deg: float
    pitch_deg: float = 0.0
    roll_deg: float = 0.0


@dataclass(frozen=True)
class AcquisitionJob:
    """Everything that defines one simulated acquisition (same job, same seed: same bytes).

    samples : Cycles samples per pixel; denoise : OpenImageDenoise on the render
    imu_sigma_deg : standard deviation of the attitude error written as the measured attitude
    """

    pose: Pose
    camera: CameraPreset
    plan: PanTiltPlan
    degradation: Degradation
    seed: int = 0
    samples: int = DEFAULT_SAMPLES
    denoise: bool = False
    imu_sigma_deg: float = 0.0
    meta: dict = field(default_factory=dict)


def frame_seed_sequence(seed: int, index: int) -> np.random.SeedSequence:
    """Independent, reproducible random stream of frame ``index`` of an acquisition seeded ``seed``."""
    return np.random.SeedSequence([int(seed) & 0xFFFFFFFF, 0xF0A3, int(index)])


def load_terrain(dem_path: str | os.PathLike, site_xy: tuple[float, float], *, grid_half_m: float,
                 max_radius_m: float | None = None, body: str | float | None = None):
    """Multi-resolution terrain around ``site_xy`` (metres): :func:`~blender_addon.terrain.multires.build_multires`."""
    from blender_addon.terrain.multires import build_multires

    return build_multires(dem_path, site_xy, grid_half_m=grid_half_m, max_radius_m=max_radius_m, body=body)


def _replace_dir(tmp: Path, out: Path) -> None:
    """Move the finished folder ``tmp`` to ``out`` (replacing an earlier result)."""
    if out.exists():
        old = out.with_name(f".{out.name}.old{os.getpid()}")
        os.replace(out, old)
        os.replace(tmp, out)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, out)


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
        from blender_addon.terrain.dem import resolve_dem

        self.dem_spec = str(dem)
        self.dem_path = resolve_dem(dem, cache_dir=cache_dir)
        self.site_xy = (float(site_xy[0]), float(site_xy[1]))
        t0 = time.perf_counter()
        self.terrain = load_terrain(self.dem_path, self.site_xy, grid_half_m=grid_half_m, max_radius_m=max_radius_m,
                                    body=body)
        self.grid_half_m = float(grid_half_m)
        from blender_addon import scene as bscene

        self._scene = bscene
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
        from blender_addon import scene as bscene

        sim = cls.__new__(cls)
        sim.dem_spec = str(dem_spec)
        sim.dem_path = Path(dem_path) if dem_path is not None else Path(str(dem_spec))
        sim.site_xy = (float(terrain.site_xy[0]), float(terrain.site_xy[1]))
        sim.terrain = terrain
        sim.grid_half_m = float(grid_half_m)
        sim._scene = bscene
        sim._token = uuid.uuid4().hex
        bscene.state.get_scene()["skyloc_simulator"] = sim._token
        return sim

    def _build(self) -> None:
        """(Re)build the Blender scene: empty session, terrain meshes, and this simulator's token."""
        self._scene.reset_scene()
        self._scene.build_terrain(self.terrain)
        self._scene.state.get_scene()["skyloc_simulator"] = self._token

    def ensure_scene(self) -> None:
        """Rebuild the terrain if another Simulator (or anything else) reset the Blender session since
        (call it before rendering into the current scene directly, e.g. with ``make_panorama(build=False)``)."""
        if self._scene.state.get_scene().get("skyloc_simulator") != self._token:
            log.info("simulator: the Blender scene was replaced; rebuilding the terrain")
            self._build()

    def ground_z(self, x: float, y: float) -> float:
        """Ground height (metres) at world (x, y)."""
        from blender_addon.core.terrain_mesh import sample_height

        return sample_height(self.terrain, x, y)

    def _check_pose(self, pose: Pose) -> None:
        dx, dy = pose.x - self.site_xy[0], pose.y - self.site_xy[1]
        if max(abs(dx), abs(dy)) > self.grid_half_m + 1e-6:
            raise InvalidInputError(f"pose ({pose.x:.1f}, {pose.y:.1f}) is {max(abs(dx), abs(dy)):.0f} m from the "
                                    f"site, outside its {self.grid_half_m:.0f} m half-width: build the simulator with "
                                    "a larger grid_half_m")
        if abs(pose.pitch_deg) > 45 or abs(pose.roll_deg) > 45:
            raise InvalidInputError(f"pitch {pose.pitch_deg} / roll {pose.roll_deg} deg: a rover tilted beyond "
                                    "45 degrees is not simulated")

    def render_frames(self, job: AcquisitionJob, *, progress: Progress | None = None,
                      work_dir: str | os.PathLike | None = None) -> tuple[list[np.ndarray], dict]:
        """Render and degrade every frame of ``job``; returns (RGB images, simulation metadata)."""
        from blender_addon.scene import dressing
        from blender_addon.scene.pantilt import point_camera

        self._check_pose(job.pose)
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
                path = self._scene.render_frame(Path(tmp) / f"render_{i:03d}.png", pinhole,
                                                color_depth="8" if deg.binary else "16")
                raw = self._scene.read_image(path)
                lin = raw if deg.binary else decode_render(raw)
                R = rotation_enu_from_frame(pan, tilt, heading_deg=p.heading_deg, pitch_deg=p.pitch_deg,
                                            roll_deg=p.roll_deg)
                rng = np.random.default_rng(frame_seed_sequence(job.seed, i))
                images.append(degrade_frame(lin, pinhole, cam, deg, rng,
                                            sun_dir_cam=(sun_enu @ R) if sun_seen else None))
                if progress is not None:
                    progress(i + 1, job.plan.n_frames, f"frame {i + 1}/{job.plan.n_frames}")
        meta = {
            "simulator": "skyloc blender_addon",
            "camera_preset": job.camera.name,
            "camera_note": job.camera.note,
            "plan": {"n_frames": job.plan.n_frames, "arc_deg": job.plan.arc_deg, "hfov_deg": job.plan.hfov_deg,
                     "overlap": job.plan.overlap},
            "degradation": deg.to_dict(),
            "seed": int(job.seed),
            "samples": 1 if deg.binary else int(job.samples),
            "denoise": bool(job.denoise),
            "render_pinhole": pinhole.to_dict(),
            "dressing": {**info.to_dict(), "sun_visible": bool(sun_seen)},
            "dem_sha256": self.terrain.dem_sha256,
            "render_seconds": round(time.perf_counter() - t0, 3),
            **job.meta,
        }
        return images, meta

    def acquire(self, job: AcquisitionJob, out_dir: str | os.PathLike, *,
                progress: Progress | None = None) -> Path:
        """Render ``job`` into the acquisition folder ``out_dir`` (replaced atomically); returns its path."""
        out = Path(out_dir)
        out.parent.mkdir(parents=True, exist_ok=True)
        images, meta = self.render_frames(job, progress=progress)
        p = job.pose
        cam = job.camera.camera_model(**job.degradation.lens.distortion)
        frames = [FrameInfo(f"frame_{i:03d}.png", pan, tilt) for i, (pan, tilt) in enumerate(job.plan.frames())]
        rng = np.random.default_rng(np.random.SeedSequence([int(job.seed) & 0xFFFFFFFF, 0x1A0]))
        att_err = rng.normal(0.0, job.imu_sigma_deg, 2) if job.imu_sigma_deg > 0 else np.zeros(2)
        truth = GroundTruth(p.x, p.y, p.heading_deg, z=self.ground_z(p.x, p.y) + job.camera.mast_height_m,
                            pitch_deg=p.pitch_deg, roll_deg=p.roll_deg, crs=self.terrain.crs_wkt, dem=self.dem_spec)
        acq = Acquisition(cam, job.camera.mast_height_m, frames,
                          attitude=(p.pitch_deg + float(att_err[0]), p.roll_deg + float(att_err[1])),
                          truth=truth, meta=meta)
        tmp = out.with_name(f".{out.name}.partial{os.getpid()}")
        shutil.rmtree(tmp, ignore_errors=True)
        try:
            # board.acquisition writes with OpenCV: BGR channel order
            write_acquisition(tmp, acq, images=[np.ascontiguousarray(im[..., ::-1]) for im in images])
            _replace_dir(tmp, out)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        log.info("acquisition written to %s (%d frames)", out, len(frames))
        return out


def job_dict(job: AcquisitionJob) -> dict:
    """A JSON-able description of a job (for dataset manifests)."""
    return {"pose": asdict(job.pose), "camera": job.camera.name, "width": job.camera.width,
            "height": job.camera.height, "hfov_deg": job.camera.hfov_deg, "mast_height_m": job.camera.mast_height_m,
            "pan_deg": list(job.plan.pan_deg), "tilt_deg": list(job.plan.tilt_deg),
            "degradation": job.degradation.name, "seed": int(job.seed), "samples": int(job.samples)}


def wrap_heading(deg: float) -> float:
    """Validate and wrap a heading in degrees."""
    if not math.isfinite(deg):
        raise InvalidInputError(f"heading {deg} must be a finite number of degrees")
    return float(np.mod(deg, 360.0))
