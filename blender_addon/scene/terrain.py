"""Terrain meshes in the Blender scene, one object per level chunk, built with ``foreach_set``.

The arrays come from :mod:`blender_addon.core.terrain_mesh` (bpy-free); this module only turns
them into mesh data blocks.  Scene coordinates are world coordinates minus the scene offset
stored on the scene (see :mod:`blender_addon.scene.state`).
"""
from __future__ import annotations

import logging
import time
from typing import Callable

import bpy  # noqa: TID251 (scene building is the bpy layer)
import numpy as np

from blender_addon.core.terrain_mesh import (MeshChunk, SceneOffset, default_offset, refine_near_field,
                                              terrain_chunks)
from blender_addon.scene import state
from blender_addon.terrain.model import MultiResTerrain

log = logging.getLogger(__name__)

TERRAIN_COLLECTION = "SkylocTerrain"
TERRAIN_MATERIAL = "SkylocTerrainMaterial"


def mesh_from_arrays(name: str, vertices: np.ndarray, quads: np.ndarray) -> bpy.types.Mesh:
    """A mesh from (n, 3) float vertices (scene metres) and (m, 4) int quads, via foreach_set."""
    n, m = len(vertices), len(quads)
    me = bpy.data.meshes.new(name)
    me.vertices.add(n)
    me.vertices.foreach_set("co", np.ascontiguousarray(vertices, dtype=np.float32).ravel())
    me.loops.add(4 * m)
    me.loops.foreach_set("vertex_index", np.ascontiguousarray(quads, dtype=np.int32).ravel())
    me.polygons.add(m)
    me.polygons.foreach_set("loop_start", np.arange(0, 4 * m, 4, dtype=np.int32))
    me.update(calc_edges=True)
    return me


def _collection(scene: bpy.types.Scene, name: str) -> bpy.types.Collection:
    coll = bpy.data.collections.get(name)
    if coll is None:
        coll = bpy.data.collections.new(name)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    return coll


def default_material() -> bpy.types.Material:
    """A plain grey diffuse material for terrain (H5b's dressing replaces it)."""
    mat = bpy.data.materials.get(TERRAIN_MATERIAL)
    if mat is None:
        mat = bpy.data.materials.new(TERRAIN_MATERIAL)
        mat.use_nodes = True
        bsdf = mat.node_tree.nodes.get("Principled BSDF")
        if bsdf is not None:
            bsdf.inputs["Base Color"].default_value = (0.45, 0.32, 0.22, 1.0)
            bsdf.inputs["Roughness"].default_value = 0.95
    return mat


def clear_terrain(scene: bpy.types.Scene | None = None) -> None:
    """Remove the terrain collection, its objects and meshes."""
    state.remove_collection_objects(TERRAIN_COLLECTION, remove_collection=True)


def build_terrain(terrain: MultiResTerrain, *, scene: bpy.types.Scene | None = None,
                  offset: SceneOffset | None = None, curvature: bool = True, radius_m: float | None = None,
                  refraction_k: float = 0.0, refine: bool = True, refine_half_m: float | None = None,
                  chunk_cells: int = 256, skirt_depth_m: float | None = None,
                  progress: Callable[[float, str], None] | None = None) -> SceneOffset:
    """Build the terrain meshes of every level into the collection ``SkylocTerrain``.

    Parameters
    ----------
    terrain : levels finest first, world coordinates in the DEM's projected CRS (metres)
    offset : world position of the scene origin (default: the site at its ground height)
    curvature : drop vertices by ``r^2 (1 - k) / 2R`` (R = ``radius_m``, default the terrain's body radius)
    refraction_k : refraction coefficient (0 on airless bodies)
    refine, refine_half_m : split level-0 cells around the site (rings out from the square of
        half-side ``refine_half_m``) into quads on the bilinear surface
        (see :func:`blender_addon.core.terrain_mesh.refine_near_field`)
    chunk_cells : at most this many quads a side per object (bounds memory)
    progress : called with (fraction 0..1, message) after each chunk

    Returns the scene offset, also stored on the scene with the curvature and CRS.
    """
    scene = state.get_scene(scene)
    clear_terrain(scene)
    off = offset if offset is not None else default_offset(terrain)
    radius = (float(radius_m) if radius_m else float(terrain.body.radius_m)) if curvature else None
    state.set_offset(off, scene=scene)
    state.set_curvature(radius, refraction_k, scene=scene)
    scene["skyloc_crs_wkt"] = terrain.crs_wkt or ""
    coll = _collection(scene, TERRAIN_COLLECTION)
    mat = default_material()
    t0 = time.perf_counter()
    n_levels = len(terrain.levels)
    n_verts = n_quads = 0
    if refine:
        terrain = refine_near_field(terrain, half_m=refine_half_m)
    chunk: MeshChunk
    for chunk in terrain_chunks(terrain, offset=off, radius_m=radius, refraction_k=refraction_k,
                                chunk_cells=chunk_cells, skirt_depth_m=skirt_depth_m):
        me = mesh_from_arrays(f"Terrain_{chunk.name}", chunk.vertices, chunk.quads)
        me.materials.append(mat)
        obj = bpy.data.objects.new(f"Terrain_{chunk.name}", me)
        obj["skyloc_level"] = chunk.level
        coll.objects.link(obj)
        n_verts += len(chunk.vertices)
        n_quads += len(chunk.quads)
        if progress is not None:
            progress((chunk.level + 0.5) / n_levels, f"level {chunk.level}: {chunk.name}")
    log.info("terrain: %d vertices, %d quads in %.2f s (offset %.1f, %.1f, %.1f m)",
             n_verts, n_quads, time.perf_counter() - t0, off.x_m, off.y_m, off.z_m)
    if progress is not None:
        progress(1.0, "terrain built")
    return off
