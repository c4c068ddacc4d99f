"""Cycles settings and renders to files: equirectangular panoramas and perspective frames.

Binary renders (terrain white, sky black): every object gets one white emission material
(view-layer material override), the world is black, one sample per pixel at the pixel centre
(pixel filter width ~0), no bounces, no denoising, "Standard" view transform and no dither, so a
pixel is exactly 255 where its centre ray hits geometry and 0 otherwise.  With ``samples > 1``
and a 1-pixel box filter a pixel holds the fraction of its area covered by terrain (anti-aliased
coverage), which the skyline renderer uses for sub-pixel boundaries.
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

import bpy  # noqa: TID251 (scene building is the bpy layer)
import numpy as np

from blender_addon.core.sampling import ADAPTIVE_MAX_FACTOR, ADAPTIVE_THRESHOLD
from blender_addon.scene import state
from blender_addon.scene.camera import CAMERA_NAME, set_equirect, set_perspective
from blender_addon.scene.quiet import native_stdout_captured
from board.camera import CameraModel
from board.errors import InvalidInputError
from board.atomic import atomic_path

log = logging.getLogger(__name__)

BINARY_MATERIAL = "SkylocBinaryWhite"


def configure_cycles(scene: bpy.types.Scene | None = None, *, samples: int = 16, denoise: bool = False,
                     persistent: bool = True, adaptive: bool = False) -> bpy.types.Scene:
    """Cycles on the CPU with ``samples`` per pixel; ``persistent`` keeps the BVH between renders.

    adaptive : ``samples`` becomes the minimum and noisy pixels get up to ``ADAPTIVE_MAX_FACTOR`` times
        more (Cycles' adaptive sampling at ``ADAPTIVE_THRESHOLD``: :mod:`blender_addon.core.sampling`);
        off for binary renders, whose pixels must be exact centre rays.
    """
    if samples < 1:
        raise InvalidInputError(f"samples must be >= 1, got {samples}")
    scene = state.get_scene(scene)
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    if adaptive:
        scene.cycles.samples = int(samples) * ADAPTIVE_MAX_FACTOR
        scene.cycles.use_adaptive_sampling = True
        scene.cycles.adaptive_min_samples = int(samples)
        scene.cycles.adaptive_threshold = ADAPTIVE_THRESHOLD
    else:
        scene.cycles.samples = int(samples)
        scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = bool(denoise)
    scene.render.use_persistent_data = bool(persistent)
    scene.render.resolution_percentage = 100
    scene.render.use_compositing = False
    scene.render.use_sequencer = False
    return scene


def _binary_material() -> bpy.types.Material:
    mat = bpy.data.materials.get(BINARY_MATERIAL)
    if mat is None:
        mat = bpy.data.materials.new(BINARY_MATERIAL)
        mat.use_nodes = True
        nt = mat.node_tree
        nt.nodes.clear()
        em = nt.nodes.new("ShaderNodeEmission")
        em.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        em.inputs["Strength"].default_value = 1.0
        out = nt.nodes.new("ShaderNodeOutputMaterial")
        nt.links.new(em.outputs["Emission"], out.inputs["Surface"])
    # Not a light: otherwise Cycles builds a light tree over every terrain triangle at each render.
    mat.cycles.emission_sampling = "NONE"
    return mat


def _black_world(scene: bpy.types.Scene) -> None:
    world = bpy.data.worlds.get("SkylocBlackWorld") or bpy.data.worlds.new("SkylocBlackWorld")
    world.use_nodes = True
    bg = world.node_tree.nodes.get("Background")
    if bg is not None:
        bg.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
        bg.inputs["Strength"].default_value = 0.0
    world.color = (0.0, 0.0, 0.0)
    scene.world = world


def configure_binary(scene: bpy.types.Scene | None = None, *, samples: int = 1) -> bpy.types.Scene:
    """Binary look: terrain (every object) white emission, sky black.

    samples : 1 gives exact binary pixels (centre ray); more gives box-filtered coverage.
    """
    if samples < 1:
        raise InvalidInputError(f"samples must be >= 1, got {samples}")
    scene = configure_cycles(scene, samples=samples, denoise=False)
    _black_world(scene)
    scene.view_layers[0].material_override = _binary_material()
    c = scene.cycles
    c.pixel_filter_type = "BOX"
    c.filter_width = 0.01 if samples == 1 else 1.0
    c.max_bounces = 0
    c.diffuse_bounces = c.glossy_bounces = c.transmission_bounces = c.volume_bounces = 0
    c.transparent_max_bounces = 0
    c.caustics_reflective = c.caustics_refractive = False
    c.use_light_tree = False
    c.seed = 0
    c.use_animated_seed = False
    scene.render.film_transparent = False
    scene.render.dither_intensity = 0.0
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.display_settings.display_device = "sRGB"
    scene.sequencer_colorspace_settings.name = "sRGB"
    return scene


def clear_binary(scene: bpy.types.Scene | None = None) -> None:
    """Undo the material override of :func:`configure_binary` (materials show again)."""
    state.get_scene(scene).view_layers[0].material_override = None


def _output(scene: bpy.types.Scene, path: Path, *, color_mode: str, color_depth: str) -> None:
    s = scene.render.image_settings
    s.file_format = "PNG"
    s.color_mode = color_mode
    s.color_depth = color_depth
    s.compression = 15
    scene.render.filepath = str(path)
    scene.render.use_file_extension = False


def _render_to(scene: bpy.types.Scene, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, suffix=f".part{path.suffix}") as tmp:
        scene.render.filepath = str(tmp)
        with native_stdout_captured() as blender_out:       # Blender prints "Saved: '...'" on fd 1
            bpy.ops.render.render(write_still=True, scene=scene.name)
        if not tmp.is_file():
            said = blender_out.text.strip() or "(nothing)"
            raise RuntimeError(f"Blender did not write {tmp}; it printed: {said}. Check the log above "
                               "and that the folder is writable")
    return path


def _camera(scene: bpy.types.Scene, camera: bpy.types.Object | None) -> bpy.types.Object:
    cam = camera or scene.camera or bpy.data.objects.get(CAMERA_NAME)
    if cam is None:
        raise InvalidInputError("no camera in the scene: call blender_addon.scene.place_camera first")
    if scene.camera != cam:          # assigning, even the same camera, forces a full Cycles resync
        scene.camera = cam
    return cam


def render_equirect(path: str | os.PathLike, *, width: int, height: int,
                    az_range_deg: tuple[float, float] = (-180.0, 180.0),
                    el_range_deg: tuple[float, float] = (-90.0, 90.0),
                    scene: bpy.types.Scene | None = None, camera: bpy.types.Object | None = None,
                    color_mode: str = "BW", color_depth: str = "8") -> Path:
    """Render an equirectangular image of the camera to ``path`` (PNG), return the path.

    az_range_deg : azimuths (degrees, relative to the camera heading, clockwise positive) of the
        left and right image edges; column ``c`` is centred on
        ``az0 + (c + 0.5) (az1 - az0) / width``
    el_range_deg : elevations (degrees, camera frame) of the bottom and top edges; row ``r`` is
        centred on ``el1 - (r + 0.5) (el1 - el0) / height``
    The image is in the camera's frame: with pitch/roll the columns are not world azimuths.
    """
    scene = state.get_scene(scene)
    cam = _camera(scene, camera)
    az0, az1 = (float(v) for v in az_range_deg)
    el0, el1 = (float(v) for v in el_range_deg)
    if not (az1 > az0 and az1 - az0 <= 360.0 + 1e-9 and -90.0 <= el0 < el1 <= 90.0):
        raise InvalidInputError(f"bad panorama ranges az {az_range_deg}, el {el_range_deg} (degrees)")
    if width < 1 or height < 1:
        raise InvalidInputError(f"image size must be positive, got {width} x {height}")
    # Blender's longitude grows to the left (counter-clockwise seen from above): negate.
    set_equirect(cam, lat_range_deg=(el0, el1), lon_range_deg=(-az1, -az0))
    scene.render.resolution_x, scene.render.resolution_y = int(width), int(height)
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    _output(scene, Path(path), color_mode=color_mode, color_depth=color_depth)
    return _render_to(scene, Path(path))


def render_frame(path: str | os.PathLike, model: CameraModel, *, scene: bpy.types.Scene | None = None,
                 camera: bpy.types.Object | None = None, color_mode: str = "RGB", color_depth: str = "8") -> Path:
    """Render a pinhole frame of ``model`` (size, focal, principal point) to ``path`` (PNG)."""
    scene = state.get_scene(scene)
    cam = _camera(scene, camera)
    set_perspective(cam, model, scene=scene)
    _output(scene, Path(path), color_mode=color_mode, color_depth=color_depth)
    return _render_to(scene, Path(path))


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read a rendered PNG as float32 in [0, 1]: (H, W) for grey, (H, W, 3) RGB otherwise."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InvalidInputError(f"cannot read image {path}")
    scale = 65535.0 if img.dtype == np.uint16 else 255.0
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    return img.astype(np.float32) / scale


def pixel_centres_deg(width: int, height: int, az_range_deg=(-180.0, 180.0), el_range_deg=(-90.0, 90.0)):
    """Azimuth of column centres and elevation of row centres (degrees) of :func:`render_equirect`."""
    az0, az1 = az_range_deg
    el0, el1 = el_range_deg
    az = az0 + (np.arange(width) + 0.5) * (az1 - az0) / width
    el = el1 - (np.arange(height) + 0.5) * (el1 - el0) / height
    return az, el


__all__ = ["configure_cycles", "configure_binary", "clear_binary", "render_equirect", "render_frame",
           "read_image", "pixel_centres_deg"]
