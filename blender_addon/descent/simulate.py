"""One trial of the descent simulator, end to end: terrain, motion, frames, IMU, altimeter -> a descent sequence.

``simulate_trial(config, out)`` is the one entry point of ``skyloc sim descent``, of the Dask
campaign (``render_service.descent_set``) and of the add-on panel.  Terrain and renderer are cached
per process (a campaign's worker builds them once for all its trials).
"""
from __future__ import annotations

import itertools
import logging
import math
from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

from board.camera import CameraModel
from board.descent.sequence import DescentCamera, write_sequence
from board.errors import InvalidInputError

from .constants import EUROPA_GRAVITY_MPS2, EUROPA_RADIUS_M
from .imu import AltimeterParams, ImuParams, simulate_altimeter, simulate_imu
from .lights import Light, default_lights
from .render import AppearanceOptions, DescentRenderer
from .sensors import ThermalSensor, VisibleSensor
from .terrain import DEFAULT_RES_M, DEFAULT_SIZE_M, DescentTerrain, load_terrain
from .trajectories import DEFAULT_DURATION_S, make_motion

log = logging.getLogger(__name__)

#: Camera image down = body backward, image right = body right, optical axis = body -z (image top = forward).
R_BODY_CAM_DOWN = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
DEFAULT_HFOV_DEG = 50.0


def default_camera(width: int = 640, height: int = 480, hfov_deg: float = DEFAULT_HFOV_DEG, *,
                   radiometric=None, bit_depth: int = 8) -> DescentCamera:
    """A downward camera 0.2 m below the body origin (both cameras share it: co-registered)."""
    return DescentCamera(CameraModel.from_fov(width, height, hfov_deg), R_BODY_CAM_DOWN,
                         np.array([0.0, 0.0, -0.2]), bit_depth, radiometric)


@dataclass(frozen=True)
class DescentConfig:
    """Everything one trial depends on (the sequence records it).

    terrain : "procedural:europa:SEED" or a DEM path; trajectory : 1..10; trial : 0..; seed : base seed of
    the noise; frames : number of frames (None: the whole trajectory at ``frame_rate_hz``); modes :
    cameras to render; duration_s : trajectory duration; appearance : BRDF and thermal models;
    visible_sensor, thermal_sensor : sensor models; width, height, hfov_deg : both cameras.
    """

    terrain: str = "procedural:europa:1"
    trajectory: int = 1
    trial: int = 0
    seed: int = 0
    frames: int | None = None
    modes: tuple[str, ...] = ("visible", "thermal")
    frame_rate_hz: float = 1.0
    duration_s: float = DEFAULT_DURATION_S
    appearance: AppearanceOptions = AppearanceOptions()
    visible_sensor: VisibleSensor = VisibleSensor()
    thermal_sensor: ThermalSensor = ThermalSensor()
    imu: ImuParams = ImuParams()
    altimeter: AltimeterParams = AltimeterParams()
    lights: tuple[Light, ...] = field(default_factory=lambda: tuple(default_lights()))
    width: int = 640
    height: int = 480
    hfov_deg: float = DEFAULT_HFOV_DEG
    terrain_res_m: float = DEFAULT_RES_M
    terrain_size_m: float = DEFAULT_SIZE_M
    noise_pos_m: float = 2.0
    noise_att_deg: float = 1.0

    def __post_init__(self) -> None:
        bad = [m for m in self.modes if m not in ("visible", "thermal")]
        if bad or not self.modes:
            raise InvalidInputError(f"modes {self.modes}: use visible, thermal or both")
        if self.frames is not None and self.frames < 1:
            raise InvalidInputError(f"--frames {self.frames}: at least one frame")
        if self.trial < 0 or self.seed < 0:
            raise InvalidInputError("trial and seed must be >= 0")
        if not self.frame_rate_hz > 0:
            raise InvalidInputError(f"frame rate {self.frame_rate_hz} Hz must be positive")

    @property
    def n_frames(self) -> int:
        full = int(math.floor(self.duration_s * self.frame_rate_hz + 1e-9)) + 1
        return full if self.frames is None else min(self.frames, full)

    @property
    def sequence_duration_s(self) -> float:
        return (self.n_frames - 1) / self.frame_rate_hz

    def cameras(self) -> dict[str, DescentCamera]:
        return {"visible": default_camera(self.width, self.height, self.hfov_deg,
                                          bit_depth=self.visible_sensor.bit_depth),
                "thermal": default_camera(self.width, self.height, self.hfov_deg,
                                          radiometric=self.thermal_sensor.radiometric,
                                          bit_depth=self.thermal_sensor.bit_depth)}


@lru_cache(maxsize=2)
def cached_terrain(spec: str, res_m: float, size_m: float) -> DescentTerrain:
    return load_terrain(spec, res_m=res_m, size_m=size_m)


@lru_cache(maxsize=4)
def cached_renderer(spec: str, res_m: float, size_m: float, lights: tuple[Light, ...],
                    appearance: AppearanceOptions) -> DescentRenderer:
    return DescentRenderer(cached_terrain(spec, res_m, size_m), list(lights), appearance)


def trial_motion(config: DescentConfig, terrain: DescentTerrain):
    xmin, ymin, xmax, ymax = terrain.bounds
    return make_motion(config.trajectory, config.trial, seed=config.seed, z_top=float(terrain.height.max()),
                       centre_xy=((xmin + xmax) / 2, (ymin + ymax) / 2),
                       scale_xy=min(xmax - xmin, ymax - ymin) / DEFAULT_SIZE_M, duration_s=config.duration_s,
                       noise_pos_m=config.noise_pos_m, noise_att_deg=config.noise_att_deg)


def frame_pairs(config: DescentConfig, renderer: DescentRenderer, motion, times, rng):
    """Yield (visible counts, thermal counts, render dict) per frame time."""
    cams = config.cameras()
    cam = cams["visible"]
    for t in times:
        R = motion.rotation([t])[0]
        p = motion.position([t])[0]
        out = renderer.render(cam, R, p)
        miss = np.isnan(out["range"]).mean()
        if miss > 0.0:
            log.warning("trial %d of trajectory %d, t=%.1f s: %.1f %% of the pixels see no terrain (beyond the DEM)",
                        config.trial, config.trajectory, t, 100 * miss)
        yield (config.visible_sensor.counts(out["visible"], rng), config.thermal_sensor.counts(out["thermal"], rng),
               out)


def sequence_meta(config: DescentConfig, terrain: DescentTerrain) -> dict:
    cams = config.cameras()
    trajectory = trial_motion(config, terrain).spec
    return {
        "body": {"name": "europa", "radius_m": EUROPA_RADIUS_M, "gravity_mps2": EUROPA_GRAVITY_MPS2},
        "terrain": {"dem": terrain.spec, "sha256": terrain.sha256, "size_m": terrain.size_m, "res_m": terrain.res_m,
                    "origin_m": [terrain.x0, terrain.y0]},
        "cameras": {m: cams[m].to_dict() for m in config.modes},
        "frame_rate_hz": config.frame_rate_hz,
        "imu": config.imu.to_dict(),
        "altimeter": config.altimeter.to_dict(),
        "lights": [s.to_dict() for s in config.lights],
        "trajectory": {"id": trajectory.id, "name": trajectory.name, "duration_s": config.duration_s,
                       "noise_pos_m": config.noise_pos_m, "noise_att_deg": config.noise_att_deg},
        "trial": config.trial, "seed": config.seed,
        "models": {"brdf": config.appearance.brdf, "thermal": config.appearance.thermal,
                   "shadows": config.appearance.cast_shadows,
                   "visible_sensor": config.visible_sensor.describe(),
                   "thermal_sensor": config.thermal_sensor.describe()},
        "meta": {"generator": "skyloc descent simulator (blender_addon.descent, fast ray-cast renderer)"},
    }


def simulate_trial(config: DescentConfig, out: str | Path, *, overwrite: bool = False) -> Path:
    """Render and write one trial as a descent-sequence folder ``out``; returns it."""
    renderer = cached_renderer(config.terrain, config.terrain_res_m, config.terrain_size_m, tuple(config.lights),
                               config.appearance)
    terrain = renderer.terrain
    motion = trial_motion(config, terrain)
    rng = np.random.Generator(np.random.PCG64([config.seed, config.trajectory, config.trial, 2024]))
    rng_imu, rng_alt, rng_img = rng.spawn(3)
    duration = config.sequence_duration_s
    imu, truth = simulate_imu(motion, config.imu, EUROPA_GRAVITY_MPS2, rng_imu, duration_s=duration)
    alt = simulate_altimeter(motion, config.altimeter, renderer.range_along, rng_alt, duration_s=duration)
    times = np.arange(config.n_frames) / config.frame_rate_hz
    pairs = frame_pairs(config, renderer, motion, times, rng_img)
    vis_it, th_it = itertools.tee(pairs, 2)
    vis = (p[0] for p in vis_it) if "visible" in config.modes else None
    th = (p[1] for p in th_it) if "thermal" in config.modes else None
    if vis is None:
        del vis_it
    if th is None:
        del th_it
    path = write_sequence(out, sequence_meta(config, terrain), vis, th, imu, alt, truth, frame_times=times,
                          overwrite=overwrite)
    log.info("trajectory %d trial %d: %d frames -> %s", config.trajectory, config.trial, config.n_frames, path)
    return path


def with_overrides(config: DescentConfig, **kw) -> DescentConfig:
    """A copy of ``config`` with fields replaced (None values are ignored)."""
    return replace(config, **{k: v for k, v in kw.items() if v is not None})
