"""The renderer contract: ``render_tile(terrain, grid, tile, spec) -> TileResult``.

Every skyline-database renderer (the numba ray-marcher, the Blender renderer) exposes a
function of this signature so that the CLI and the service's Dask workers can farm tiles
out without knowing which renderer runs.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from board.conventions import BODIES
from board.errors import InvalidInputError
from board.skydb import MAX_AZIMUTH_SUBSAMPLES, GridSpec, Tile, box_offsets_deg


@dataclass(frozen=True)
class RenderSpec:
    """What to render at every position.

    camera_height_m : eye height above the ground at the position, metres
    n_azimuth : number of azimuth samples (360 -> 1 degree)
    azimuth_start_deg : azimuth of sample 0, degrees clockwise from grid north
    body_radius_m : sphere radius for the curvature drop d^2/2R, metres
    refraction_k : refraction coefficient (0 on airless bodies)
    max_distance_m : stop marching beyond this distance (None: the terrain's edge)
    azimuth_subsamples : rays per sample, spread evenly across the sample's azimuth step; the sample is
        their mean, i.e. the horizon averaged over the step centred on the sample's azimuth (a box of one
        step), which is what an extracted skyline's sample measures (a camera's pixels average the
        horizon over their width and :func:`board.extraction.panorama_line_to_skyline` fits a line over
        the columns within half a step).  1: point samples (the horizon exactly at the azimuth).  See
        docs/renderer.md, "Point or box samples".
    """

    camera_height_m: float = 2.0
    n_azimuth: int = 360
    azimuth_start_deg: float = 0.0
    body_radius_m: float = BODIES["mars"].radius_m
    refraction_k: float = 0.0
    max_distance_m: float | None = None
    azimuth_subsamples: int = 1

    def __post_init__(self) -> None:
        if not (self.n_azimuth > 0):
            raise InvalidInputError(f"n_azimuth must be positive, got {self.n_azimuth}")
        if not (isinstance(self.azimuth_subsamples, (int, np.integer))
                and 1 <= self.azimuth_subsamples <= MAX_AZIMUTH_SUBSAMPLES):
            raise InvalidInputError(f"azimuth_subsamples must be a whole number of rays from 1 to "
                                    f"{MAX_AZIMUTH_SUBSAMPLES}, got "
                                    f"{self.azimuth_subsamples!r} (1: point samples; 4: the database default)")
        if not (self.body_radius_m > 0):
            raise InvalidInputError(f"body radius must be positive, got {self.body_radius_m}")
        if not (self.camera_height_m >= 0):
            raise InvalidInputError(f"camera height must be >= 0 m, got {self.camera_height_m}")

    def azimuths_deg(self) -> np.ndarray:
        return self.azimuth_start_deg + np.arange(self.n_azimuth) * (360.0 / self.n_azimuth)

    def ray_spec(self) -> "RenderSpec":
        """The point-sampled spec whose rays a renderer traces for this one: ``n_azimuth * azimuth_subsamples``
        azimuths, ray ``j * K + k`` at sample j's azimuth + ``board.skydb.box_offsets_deg(K, step)[k]``."""
        k = int(self.azimuth_subsamples)
        if k == 1:
            return self
        step = 360.0 / self.n_azimuth
        return replace(self, n_azimuth=self.n_azimuth * k, azimuth_start_deg=self.azimuth_start_deg
                       + float(box_offsets_deg(k, step)[0]), azimuth_subsamples=1)

    def box_mean(self, rays: np.ndarray) -> np.ndarray:
        """``rays`` (..., n_azimuth * K) rendered on :meth:`ray_spec` -> (..., n_azimuth): each sample the mean of
        its K rays (NaN if any of them is NaN), float32."""
        k = int(self.azimuth_subsamples)
        a = np.asarray(rays, dtype=np.float32)
        if k == 1:
            return a
        return a.reshape(*a.shape[:-1], self.n_azimuth, k).mean(axis=-1, dtype=np.float64).astype(np.float32)


@dataclass
class TileResult:
    """A rendered tile: elevation_deg and distance_m, both (nrows, ncols, n_azimuth) float32.

    elevation_deg : horizon elevation, degrees above the eye's local horizontal
    distance_m : horizontal distance to the point that forms the horizon, metres (NaN if none)
    """

    elevation_deg: np.ndarray
    distance_m: np.ndarray | None = None


#: a renderer's tile function: ``render_tile(terrain, grid, tile, spec) -> TileResult``
RenderTile = Callable[[object, GridSpec, Tile, RenderSpec], TileResult]


def _raymarch() -> RenderTile:
    from render_service.renderers.raymarch import render_tile  # noqa: PLC0415 - numba, loaded on use

    return render_tile


def _blender() -> RenderTile:
    from render_service.renderers.blender import render_tile  # noqa: PLC0415 - bpy, loaded on use

    return render_tile


_LOADERS: dict[str, Callable[[], RenderTile]] = {"raymarch": _raymarch, "blender": _blender}

#: renderer name -> "module:function" of its tile function (documentation, and what the service checks is
#: installed); :func:`get_renderer` loads it through a plain import
RENDERERS: dict[str, str] = {
    "raymarch": "render_service.renderers.raymarch:render_tile",
    "blender": "render_service.renderers.blender:render_tile",
}


def render_tile_sampled(render_tile: RenderTile, terrain, grid: GridSpec, tile: Tile, spec: RenderSpec) -> TileResult:
    """``render_tile`` (any renderer's) for ``spec`` with its ``azimuth_subsamples``: the renderer traces the
    rays of :meth:`RenderSpec.ray_spec` and each sample is the mean of its rays (elevation and distance)."""
    if spec.azimuth_subsamples == 1:
        return render_tile(terrain, grid, tile, spec)
    res = render_tile(terrain, grid, tile, spec.ray_spec())
    dist = None if res.distance_m is None else spec.box_mean(res.distance_m)
    return TileResult(elevation_deg=spec.box_mean(res.elevation_deg), distance_m=dist)


def get_renderer(name: str) -> RenderTile:
    """Resolve a renderer name to its ``render_tile`` function (ImportError when its component is missing)."""
    if name not in RENDERERS:
        raise InvalidInputError(f"unknown renderer {name!r}: choose one of {', '.join(RENDERERS)}")
    return _LOADERS[name]()
