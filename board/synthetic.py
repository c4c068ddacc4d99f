"""Analytic test scenes: a known skyline function seen through the camera model.

Used by the tests and the benchmark as independent truth (and usable on board as a
self-test): the sky is a smooth gradient above ``el = f(az)``, the ground below is a
procedural texture fixed to directions (so overlapping frames agree), pixels on the line are
anti-aliased by their coverage.  Azimuths are relative to the heading, degrees.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from board.acquisition import Acquisition, FrameInfo, GroundTruth, PanoramaGeometry, write_acquisition
from board.camera import CameraModel, pixel_to_az_el


@dataclass(frozen=True)
class SkylineFunction:
    """el(az) = base + sum_k a_k sin(n_k az + phi_k) + sum of triangular peaks (degrees).

    Periodic in azimuth (n_k integers), so it is a valid 360-degree skyline.
    """

    base_deg: float
    harmonics: tuple[tuple[int, float, float], ...]     # (n, amplitude_deg, phase_rad)
    peaks: tuple[tuple[float, float, float], ...] = ()  # (azimuth_deg, height_deg, half_width_deg)

    @classmethod
    def random(cls, seed: int, *, base_deg: float = 3.0, amplitude_deg: float = 4.0, n_harmonics: int = 6,
               n_peaks: int = 3) -> "SkylineFunction":
        rng = np.random.default_rng(seed)
        ns = rng.choice(np.arange(1, 40), size=n_harmonics, replace=False)
        amps = amplitude_deg * rng.uniform(0.2, 1.0, n_harmonics) / np.sqrt(ns / ns.min())
        harm = tuple((int(n), float(a), float(p)) for n, a, p in zip(ns, amps, rng.uniform(0, 2 * np.pi, n_harmonics)))
        peaks = tuple((float(rng.uniform(0, 360)), float(rng.uniform(1.0, 4.0)), float(rng.uniform(0.5, 3.0)))
                      for _ in range(n_peaks))
        return cls(base_deg, harm, peaks)

    def __call__(self, az_deg) -> np.ndarray:
        az = np.asarray(az_deg, dtype=np.float64)
        a = np.radians(az)
        out = np.full(az.shape, self.base_deg)
        for n, amp, ph in self.harmonics:
            out = out + amp * np.sin(n * a + ph)
        for paz, h, hw in self.peaks:
            d = np.abs((az - paz + 180.0) % 360.0 - 180.0)
            out = out + h * np.clip(1.0 - d / hw, 0.0, None)
        return out


@dataclass(frozen=True)
class SceneLook:
    """Radiometry of a synthetic scene (values in [0, 1] of full scale)."""

    sky_top: float = 0.80
    sky_horizon: float = 0.70
    ground: float = 0.35
    texture: float = 0.12
    texture_seed: int = 7
    dust: tuple[tuple[float, float, float], ...] = field(default=())   # (az0, az1, strength 0..1): haze over the line


def _ground_texture(az: np.ndarray, el: np.ndarray, seed: int) -> np.ndarray:
    """Procedural texture in [-1, 1] fixed to directions: random plane waves on the unit sphere."""
    from board.conventions import enu_from_az_el_deg

    rng = np.random.default_rng(seed)
    d = enu_from_az_el_deg(az, el)
    t = np.zeros(d.shape[:-1])
    for _ in range(8):
        f = rng.uniform(0.3, 3.0)                    # cycles per degree
        k = rng.normal(size=3)
        k *= 2.0 * np.pi * f / math.radians(1.0) / np.linalg.norm(k)
        t += np.sin(d @ k + rng.uniform(0, 2 * np.pi))
    return np.clip(t / 3.0, -1.0, 1.0)


def render_directions(az_deg: np.ndarray, el_deg: np.ndarray, skyline: SkylineFunction, *,
                      pixel_deg: float | np.ndarray, look: SceneLook = SceneLook()) -> np.ndarray:
    """Radiance in [0, 1] of directions (az, el) (degrees): sky above ``skyline``, textured ground below.

    pixel_deg : angular pixel size (degrees) used to anti-alias the line by pixel coverage.
    """
    sky_el = skyline(az_deg)
    cov_ground = np.clip(0.5 + (sky_el - el_deg) / pixel_deg, 0.0, 1.0)
    sky = look.sky_horizon + (look.sky_top - look.sky_horizon) * np.clip((el_deg - sky_el) / 30.0, 0.0, 1.0)
    ground = look.ground * (1.0 + look.texture / look.ground * _ground_texture(az_deg, el_deg, look.texture_seed))
    ground = ground * (1.0 - 0.3 * np.clip((sky_el - el_deg) / 20.0, 0.0, 1.0))
    for az0, az1, strength in look.dust:
        inside = np.mod(np.asarray(az_deg) - az0, 360.0) <= np.mod(az1 - az0, 360.0)
        ground = np.where(inside, (1 - strength) * ground + strength * sky, ground)
    return cov_ground * ground + (1.0 - cov_ground) * sky


def synth_panorama(geometry: PanoramaGeometry, skyline: SkylineFunction, *, look: SceneLook = SceneLook(),
                   noise_sigma: float = 0.0, seed: int = 0) -> np.ndarray:
    """Float image (H, W) in [0, 1] of the scene on ``geometry``'s grid, with Gaussian noise ``noise_sigma``."""
    az = geometry.azimuths_deg()[None, :]
    el = geometry.elevations_deg()[:, None]
    img = render_directions(az, el, skyline, pixel_deg=geometry.elevation_step_deg, look=look)
    if noise_sigma:
        img = img + np.random.default_rng(seed).normal(0.0, noise_sigma, img.shape)
    return np.clip(img, 0.0, 1.0)


def frame_plan(n_pan: int, tilts_deg: Sequence[float] = (0.0,), *, pan0_deg: float = 0.0) -> list[tuple[float, float]]:
    """(pan, tilt) of a full-circle plan: ``n_pan`` evenly spaced pans for each tilt (degrees)."""
    return [(pan0_deg + i * 360.0 / n_pan, t) for t in tilts_deg for i in range(n_pan)]


def synth_frames(camera: CameraModel, plan: Sequence[tuple[float, float]], skyline: SkylineFunction, *,
                 look: SceneLook = SceneLook(), noise_sigma: float = 0.0, seed: int = 0, pitch_deg: float = 0.0,
                 roll_deg: float = 0.0, pan_error_deg: Sequence[float] | None = None,
                 bit_depth: int = 8) -> list[np.ndarray]:
    """Frames seen by ``camera`` (with its distortion) at each (pan, tilt) of ``plan`` for a body at
    heading 0 with ``pitch_deg``/``roll_deg``; ``pan_error_deg`` adds a true pan offset per frame that
    the manifest will not know (pan-tilt unit inaccuracy).  Returns uint8 or uint16 (H, W) images."""
    rng = np.random.default_rng(seed)
    u, v = camera.pixel_grid()
    pix = math.degrees(1.0 / camera.fx)
    out = []
    full = 255 if bit_depth == 8 else 65535
    for i, (pan, tilt) in enumerate(plan):
        dp = 0.0 if pan_error_deg is None else float(pan_error_deg[i])
        az, el = pixel_to_az_el(camera, u, v, pan + dp, tilt, pitch_deg=pitch_deg, roll_deg=roll_deg)
        img = render_directions(az, el, skyline, pixel_deg=pix, look=look)
        if noise_sigma:
            img = img + rng.normal(0.0, noise_sigma, img.shape)
        img = np.clip(img, 0.0, 1.0) * full + 0.5
        out.append(img.astype(np.uint8 if bit_depth == 8 else np.uint16))
    return out


def synth_acquisition(folder: str | Path, camera: CameraModel, plan: Sequence[tuple[float, float]],
                      skyline: SkylineFunction, *, mast_height_m: float = 2.0, attitude_known: bool = True,
                      pitch_deg: float = 0.0, roll_deg: float = 0.0, **frame_kw) -> Acquisition:
    """Write an acquisition folder of :func:`synth_frames` (truth: heading 0 at the origin); its values are
    linear in the light (``transfer: "linear"``)."""
    imgs = synth_frames(camera, plan, skyline, pitch_deg=pitch_deg, roll_deg=roll_deg, **frame_kw)
    frames = [FrameInfo(f"frame_{i:03d}.png", float(p), float(t)) for i, (p, t) in enumerate(plan)]
    acq = Acquisition(camera, mast_height_m, frames,
                      attitude=(pitch_deg, roll_deg) if attitude_known else None,
                      truth=GroundTruth(0.0, 0.0, 0.0, pitch_deg=pitch_deg, roll_deg=roll_deg),
                      meta={"synthetic": True}, transfer="linear")   # coverage anti-aliasing, linear values
    write_acquisition(folder, acq, images=imgs)
    return acq
