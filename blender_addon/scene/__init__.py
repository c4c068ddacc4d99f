"""The Blender scene layer (imports bpy): terrain meshes, cameras at ENU poses, Cycles renders.

Stable API used by the simulator (H5b's dressing and acquisitions) and the skyline renderer::

    reset_scene() -> Scene
    build_terrain(terrain, *, offset=None, curvature=True, radius_m=None, refraction_k=0.0, refine=True,
                  refine_half_m=None, chunk_cells=256, progress=None) -> SceneOffset
    place_camera(x, y, z, heading_deg, pitch_deg=0.0, roll_deg=0.0, *, name="SkylocCamera") -> Object
    configure_cycles(*, samples=16, denoise=False) / configure_binary(*, samples=1) / clear_binary()
    render_equirect(path, *, width, height, az_range_deg=(-180, 180), el_range_deg=(-90, 90)) -> Path
    render_frame(path, model: board.camera.CameraModel) -> Path
    read_image(path) -> ndarray float32 in [0, 1]

World coordinates are the DEM's projected CRS in metres; the scene origin sits at the stored
offset (``get_offset()``).
"""
from blender_addon.scene.camera import camera_world_matrix, place_camera, set_equirect, set_perspective
from blender_addon.scene.render import (clear_binary, configure_binary, configure_cycles, pixel_centres_deg,
                                        read_image, render_equirect, render_frame)
from blender_addon.scene.state import get_curvature, get_offset, reset_scene, set_curvature, set_offset
from blender_addon.scene.terrain import TERRAIN_COLLECTION, build_terrain, clear_terrain, mesh_from_arrays

__all__ = [
    "TERRAIN_COLLECTION", "build_terrain", "camera_world_matrix", "clear_binary", "clear_terrain",
    "configure_binary", "configure_cycles", "get_curvature", "get_offset", "mesh_from_arrays", "pixel_centres_deg",
    "place_camera", "read_image", "render_equirect", "render_frame", "reset_scene", "set_curvature",
    "set_equirect", "set_offset", "set_perspective",
]
