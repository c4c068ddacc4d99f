"""The Blender renderer's tile adapter: :func:`blender_addon.skyline_renderer.render_tile` under the service's
renderer contract (:mod:`render_service.renderers.base`).

The add-on renders (bpy is imported lazily there, on the first render) and returns its own ``SkylineTile``; this adapter
gives the service its ``TileResult``.  It lives here because the service may import the add-on,
never the other way round.
"""
from __future__ import annotations

from blender_addon import skyline_renderer
from blender_addon.terrain.model import MultiResTerrain
from board.skydb import GridSpec, Tile
from render_service.renderers.base import RenderSpec, TileResult

#: the Blender renderer's version (recorded in every database it renders)
__version__ = skyline_renderer.__version__


def render_tile(terrain: MultiResTerrain, grid: GridSpec, tile: Tile, spec: RenderSpec) -> TileResult:
    """Render every position of ``tile`` with Blender: elevation_deg and distance_m, (nrows, ncols, n_azimuth)
    float32 (degrees above the eye's local horizontal; metres)."""
    res = skyline_renderer.render_tile(terrain, grid, tile, spec)
    return TileResult(elevation_deg=res.elevation_deg, distance_m=res.distance_m)
