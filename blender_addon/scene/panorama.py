"""Panorama products: an equirectangular image at a rover pose, written as a panorama folder.

The panorama is in the mast's frame: column ``c`` of ``W`` is centred on azimuth
``-180 + (c + 0.5) * 360 / W`` degrees clockwise from the heading (the heading is the image's
vertical midline) and row ``r`` of ``H`` on elevation ``90 - (r + 0.5) * 180 / H`` above the
mast's horizontal, so with pitch or roll the terrain/sky boundary is tilted in the image, as a real
tilted rover would see it.  The folder format is :mod:`board.acquisition`'s (``panorama.json``).
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from blender_addon.core.acquire import Pose
from blender_addon.core.band import FULL_SPHERE_DEG, panorama_band
from blender_addon.core.sampling import sampling_meta
from blender_addon.core.terrain_mesh import sample_height
from blender_addon.scene import render as R
from blender_addon.scene import state
from blender_addon.scene.camera import place_camera
from blender_addon.scene.terrain import build_terrain
from blender_addon.terrain.model import MultiResTerrain
from board.acquisition import GroundTruth, PanoramaGeometry, write_panorama
from board.atomic import atomic_dir
from board.errors import InvalidInputError

log = logging.getLogger(__name__)


def panorama_geometry(width: int, *, binary: bool,
                      elevation_range_deg: tuple[float, float] = FULL_SPHERE_DEG) -> PanoramaGeometry:
    """Geometry of a 360-degree panorama ``width`` pixels wide, heading in the middle, square pixels.

    elevation_range_deg : bottom and top edges (degrees above the mast's horizontal); the default is the
        whole sphere (``width`` x ``width / 2``).  A band (e.g. -45..45) renders only the rows where the
        skyline can be, for a fraction of the render time; the rows outside are not in the image.
    """
    height, bottom, top = panorama_band(width, elevation_range_deg)
    return PanoramaGeometry.full_circle(width, height, elevation_top_deg=top, elevation_bottom_deg=bottom,
                                        azimuth_start_deg=-180.0, azimuth_reference="heading",
                                        kind="binary" if binary else "intensity")


def render_binary_panorama(pose: Pose, *, height_m: float, width: int, path: str | os.PathLike,
                           terrain: MultiResTerrain | None = None,
                           elevation_range_deg: tuple[float, float] = FULL_SPHERE_DEG) -> np.ndarray:
    """Render a binary (terrain 255, sky 0) panorama of the current scene; returns the uint8 image.

    The scene must already hold the terrain (:func:`build_terrain`); the eye is ``height_m`` above the
    ground under the rover, which ``terrain`` gives (default: above the scene origin).
    elevation_range_deg : the band rendered (:func:`panorama_geometry`).
    """
    geom = panorama_geometry(width, binary=True, elevation_range_deg=elevation_range_deg)
    z = _eye_z(pose, height_m, terrain)
    place_camera(pose.x, pose.y, z, pose.heading_deg, pose.pitch_deg, pose.roll_deg)
    R.configure_binary(samples=1)
    p = R.render_equirect(path, width=geom.width, height=geom.height, el_range_deg=_edges(geom))
    return (R.read_image(p) >= 0.5).astype(np.uint8) * 255


def _edges(geom: PanoramaGeometry) -> tuple[float, float]:
    """Bottom and top pixel-edge elevations (degrees) of a panorama geometry."""
    half = geom.elevation_step_deg / 2.0
    return (float(geom.el_of_row(geom.height - 1)) - half, float(geom.el_of_row(0)) + half)


def _eye_z(pose: Pose, height_m: float, terrain: MultiResTerrain | None) -> float:
    if terrain is None:
        return state.get_offset().z_m + height_m
    return sample_height(terrain, pose.x, pose.y) + height_m


def _dressed_image(terrain: MultiResTerrain, pose: Pose, height_m: float, preset, *, geom: PanoramaGeometry,
                   seed: int, samples: int, path: Path) -> tuple[np.ndarray, dict]:
    """Intensity panorama with H5b's dressing (regolith, rocks, sky, sun) and sensor noise.

    preset : a preset name or a :class:`~blender_addon.core.degrade.Degradation`
    geom : the panorama's geometry (:func:`panorama_geometry`: width and elevation band)
    """
    from blender_addon.core import degrade
    from blender_addon.scene import dressing

    deg = preset if isinstance(preset, degrade.Degradation) else degrade.get_degradation(preset)
    info = dressing.dress_scene(terrain, deg, center_xy=(pose.x, pose.y), heading_deg=pose.heading_deg,
                                seed=seed, samples=samples)
    place_camera(pose.x, pose.y, _eye_z(pose, height_m, terrain), pose.heading_deg, pose.pitch_deg, pose.roll_deg)
    p = R.render_equirect(path, width=geom.width, height=geom.height, el_range_deg=_edges(geom), color_mode="RGB",
                          color_depth="16")
    lin = degrade.decode_render(R.read_image(p))
    lin = degrade.apply_exposure(lin, deg.sensor.exposure_ev) if deg.sensor.exposure_ev else lin
    if deg.lens.blur_px > 0:
        lin = degrade.gaussian_blur(lin, deg.lens.blur_px)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, 0x9A40]))
    lin = degrade.add_sensor_noise(lin, rng, full_well_e=deg.sensor.full_well_e, read_noise_e=deg.sensor.read_noise_e)
    img = degrade.quantise(degrade.srgb_encode(lin), deg.sensor.bit_depth)
    img = np.ascontiguousarray(img[..., ::-1])          # board.acquisition writes with OpenCV: BGR order
    meta = {"preset": deg.name, "degradation": deg.to_dict(), "n_rocks": info.n_rocks,
            "sun_azimuth_deg": info.sun_azimuth_deg, "sun_elevation_deg": info.sun_elevation_deg,
            **sampling_meta(samples),
            "note": "lens distortion and dispersion apply to camera frames (skyloc sim acquire), "
                    "not to this equirectangular product"}
    return img, meta


def make_panorama(terrain: MultiResTerrain, pose: Pose, out_dir: str | os.PathLike, *, height_m: float,
                  width: int = 2048, binary: bool = True, preset=None, seed: int = 0, samples: int = 16,
                  dem: str = "", build: bool = True,
                  elevation_range_deg: tuple[float, float] = FULL_SPHERE_DEG) -> Path:
    """Build the scene (unless ``build`` is False), render and write a panorama folder atomically.

    pose : the rover pose (:class:`blender_addon.core.acquire.Pose`); height_m : the eye (mast) height above
        the ground under it, metres

    binary : the report's noise level 1 (terrain white, sky black); otherwise ``preset``
        (clean | realistic | distorted, H5b's dressing, or a ``Degradation`` such as a preset with
        another sun) gives an intensity image.
    elevation_range_deg : bottom and top of the rendered band (degrees, mast frame; default the whole
        sphere); rows outside it are not in the panorama (:func:`panorama_geometry`).
    Returns the folder path.
    """
    out = Path(out_dir)
    if not binary and not preset:
        raise InvalidInputError("choose --binary or a --preset (clean, realistic, distorted)")
    if build:
        state.reset_scene()
        build_terrain(terrain)
    with atomic_dir(out) as tmp:
        geom = panorama_geometry(width, binary=binary, elevation_range_deg=elevation_range_deg)
        if binary:
            img = render_binary_panorama(pose, height_m=height_m, width=width, path=tmp / "render.png",
                                         terrain=terrain, elevation_range_deg=elevation_range_deg)
            meta = {"preset": "binary", "renderer": "blender-cycles", **sampling_meta(1, binary=True)}
        else:
            img, meta = _dressed_image(terrain, pose, height_m, preset, geom=geom, seed=seed, samples=samples,
                                       path=tmp / "render.png")
        (tmp / "render.png").unlink(missing_ok=True)
        z = sample_height(terrain, pose.x, pose.y) + height_m
        truth = GroundTruth(x=pose.x, y=pose.y, heading_deg=pose.heading_deg, z=z, pitch_deg=pose.pitch_deg,
                            roll_deg=pose.roll_deg, crs=terrain.crs_wkt, dem=dem)
        meta.update({"seed": int(seed), "body_radius_m": float(terrain.body.radius_m), "curvature": True})
        # binary renders are 0 / max (light or none); dressed ones sRGB-encoded (_dressed_image)
        write_panorama(tmp, img, geom, mast_height_m=height_m, truth=truth, meta=meta,
                       transfer="linear" if binary else "srgb")
    log.info("panorama written to %s", out)
    return out
