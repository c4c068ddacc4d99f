"""Scene-wide state kept on the Blender scene as ID properties (readable without the add-on).

``scene["skyloc_offset"]`` : (x, y, z) world position of the scene origin, metres (projected CRS)
``scene["skyloc_curvature"]`` : (radius_m, refraction_k); radius 0 means a flat scene
``scene["skyloc_crs_wkt"]`` : the world CRS
"""
from __future__ import annotations

import logging

import bpy  # noqa: TID251 (scene building is the bpy layer)

from blender_addon.core.terrain_mesh import SceneOffset

log = logging.getLogger(__name__)


def reset_scene() -> bpy.types.Scene:
    """Empty the Blender session (factory settings, no objects) and return the scene."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


def remove_collection_objects(name: str, *, remove_collection: bool = False) -> None:
    """Delete the objects of collection ``name`` and their now unused meshes (the collection too if asked)."""
    coll = bpy.data.collections.get(name)
    if coll is None:
        return
    for obj in list(coll.objects):
        me = obj.data
        bpy.data.objects.remove(obj, do_unlink=True)
        if me is not None and me.users == 0:
            bpy.data.meshes.remove(me)
    if remove_collection:
        bpy.data.collections.remove(coll)


def get_scene(scene: bpy.types.Scene | None = None) -> bpy.types.Scene:
    return scene if scene is not None else bpy.context.scene


def set_offset(offset: SceneOffset, *, scene: bpy.types.Scene | None = None) -> None:
    get_scene(scene)["skyloc_offset"] = [offset.x_m, offset.y_m, offset.z_m]


def get_offset(scene: bpy.types.Scene | None = None) -> SceneOffset:
    """The stored scene offset; (0, 0, 0) when no terrain was built."""
    v = get_scene(scene).get("skyloc_offset")
    return SceneOffset(0.0, 0.0, 0.0) if v is None else SceneOffset(float(v[0]), float(v[1]), float(v[2]))


def set_curvature(radius_m: float | None, refraction_k: float = 0.0, *, scene: bpy.types.Scene | None = None) -> None:
    get_scene(scene)["skyloc_curvature"] = [float(radius_m or 0.0), float(refraction_k)]


def get_curvature(scene: bpy.types.Scene | None = None) -> tuple[float | None, float]:
    """(radius_m or None for a flat scene, refraction_k)."""
    v = get_scene(scene).get("skyloc_curvature")
    if v is None or not v[0]:
        return None, 0.0
    return float(v[0]), float(v[1])
