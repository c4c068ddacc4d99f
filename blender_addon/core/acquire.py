"""Simulated NavCam acquisitions, the bpy-free part: what to simulate, and what gets written.

:class:`Pose` (the rover pose to simulate, the one pose type of the simulator), :class:`AcquisitionJob`
(everything that defines one acquisition), the per-frame random streams, the pose checks, the
simulation metadata and the acquisition folder written from rendered images.  The Blender side that
renders the frames is :class:`blender_addon.sim.Simulator` (the add-on's bpy layer), which calls these;
its docstring has the usage and the frame geometry.  Ground truth and the degradation parameters go
into the manifest (:mod:`board.acquisition`); the calibrated camera carries the Brown-Conrady
coefficients.
"""
from __future__ import annotations

import logging
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from blender_addon.core.cameras import CameraPreset
from blender_addon.core.degrade import Degradation
from blender_addon.core.plans import PanTiltPlan
from blender_addon.core.sampling import sampling_meta
from board.acquisition import Acquisition, FrameInfo, GroundTruth, write_acquisition
from board.atomic import atomic_dir
from board.errors import InvalidInputError

log = logging.getLogger(__name__)

#: Cycles samples per pixel at the default quality.
DEFAULT_SAMPLES = 16

Progress = Callable[[int, int, str], None]


@dataclass(frozen=True)
class Pose:
    """Rover pose in the world frame: position (metres, the DEM's metric CRS), heading (degrees clockwise from
    grid north) and mast tilt (pitch, roll, degrees).  The eye height is not part of it: the camera's
    ``mast_height_m`` gives it for acquisitions, ``height_m`` for panoramas
    (:func:`blender_addon.scene.panorama.make_panorama`)."""

    x: float
    y: float
    heading_deg: float
    pitch_deg: float = 0.0
    roll_deg: float = 0.0


@dataclass(frozen=True)
class AcquisitionJob:
    """Everything that defines one simulated acquisition (same job, same seed: same bytes).

    samples : Cycles samples per pixel (at least: adaptive sampling, blender_addon.core.sampling);
        denoise : OpenImageDenoise on the render
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


def check_pose(pose: Pose, site_xy: tuple[float, float], grid_half_m: float) -> None:
    """Refuse a pose outside the ``grid_half_m`` half-width around ``site_xy`` or tilted beyond 45 degrees."""
    dx, dy = pose.x - site_xy[0], pose.y - site_xy[1]
    if max(abs(dx), abs(dy)) > grid_half_m + 1e-6:
        raise InvalidInputError(f"pose ({pose.x:.1f}, {pose.y:.1f}) is {max(abs(dx), abs(dy)):.0f} m from the "
                                f"site, outside its {grid_half_m:.0f} m half-width: build the simulator with "
                                "a larger grid_half_m")
    if abs(pose.pitch_deg) > 45 or abs(pose.roll_deg) > 45:
        raise InvalidInputError(f"pitch {pose.pitch_deg} / roll {pose.roll_deg} deg: a rover tilted beyond "
                                "45 degrees is not simulated")


def simulation_meta(job: AcquisitionJob, *, render_pinhole: dict, dressing: dict, sun_visible: bool,
                    dem_sha256: str, render_seconds: float) -> dict:
    """The ``meta`` of a simulated acquisition's manifest (what made it, to reproduce it)."""
    deg = job.degradation
    return {
        "simulator": "skyloc blender_addon",
        "camera_preset": job.camera.name,
        "camera_note": job.camera.note,
        "plan": {"n_frames": job.plan.n_frames, "arc_deg": job.plan.arc_deg, "hfov_deg": job.plan.hfov_deg,
                 "overlap": job.plan.overlap},
        "degradation": deg.to_dict(),
        "seed": int(job.seed),
        **sampling_meta(job.samples, binary=deg.binary),
        "denoise": bool(job.denoise),
        "render_pinhole": render_pinhole,
        "dressing": {**dressing, "sun_visible": bool(sun_visible)},
        "dem_sha256": dem_sha256,
        "render_seconds": round(float(render_seconds), 3),
        **job.meta,
    }


def acquisition_record(job: AcquisitionJob, meta: dict, *, eye_z_m: float, crs_wkt: str,
                       dem_spec: str) -> Acquisition:
    """The :class:`board.acquisition.Acquisition` of ``job``: camera, frames, measured attitude (truth +
    the IMU error drawn from the job's seed) and the ground truth (``eye_z_m``: optical centre height)."""
    p = job.pose
    cam = job.camera.camera_model(**job.degradation.lens.distortion)
    frames = [FrameInfo(f"frame_{i:03d}.png", pan, tilt) for i, (pan, tilt) in enumerate(job.plan.frames())]
    rng = np.random.default_rng(np.random.SeedSequence([int(job.seed) & 0xFFFFFFFF, 0x1A0]))
    att_err = rng.normal(0.0, job.imu_sigma_deg, 2) if job.imu_sigma_deg > 0 else np.zeros(2)
    truth = GroundTruth(p.x, p.y, p.heading_deg, z=float(eye_z_m), pitch_deg=p.pitch_deg, roll_deg=p.roll_deg,
                        crs=crs_wkt, dem=dem_spec)
    return Acquisition(cam, job.camera.mast_height_m, frames,
                       attitude=(p.pitch_deg + float(att_err[0]), p.roll_deg + float(att_err[1])),
                       truth=truth, meta=meta,   # degrade_frame encodes sRGB; binary looks are 0 / max
                       transfer="linear" if job.degradation.binary else "srgb")


def write_acquisition_folder(out_dir: str | os.PathLike, acq: Acquisition, images: list[np.ndarray]) -> Path:
    """Write ``acq`` with its RGB ``images`` as the folder ``out_dir``, replacing an earlier one atomically."""
    out = Path(out_dir)
    with atomic_dir(out) as tmp:
        # board.acquisition writes with OpenCV: BGR channel order
        write_acquisition(tmp, acq, images=[np.ascontiguousarray(im[..., ::-1]) for im in images])
    log.info("acquisition written to %s (%d frames)", out, len(acq.frames))
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
