"""The Blender skyline renderer: database skylines from binary Cycles panoramas.

The same tile contract as the ray-marcher::

    render_tile(terrain, grid, tile, spec) -> SkylineTile (elevation_deg, distance_m)

(``spec`` is any object with the fields of ``render_service.renderers.base.RenderSpec``; the
service's adapter :mod:`render_service.renderers.blender` turns the result into its
``TileResult``: the add-on never imports the service).

The terrain is built once per process into a persistent Blender scene (curvature from
``spec.body_radius_m`` / ``spec.refraction_k``); for each position only the camera moves.  A
position costs two binary equirectangular renders whose column ``j`` is centred exactly on the
skyline azimuth ``start + j * step`` (a point sample, as the database defines it):

1. a coarse pass over all elevations (``coarse_deg_per_px``) brackets the terrain/sky boundary of
   every column (below the boundary everything is terrain: the terrain is a height field seen
   from above it);
2. a fine pass at ``deg_per_px`` over that bracket only.

The previous position's skyline range (plus ``band_margin_deg``) is tried first as the band: when
every column has sky in its top row and terrain in the band, the boundaries are all inside it and
the coarse pass is skipped (one render per position instead of two).  Band rows sit on multiples
of ``deg_per_px`` so both paths give the same pixels.

Per column the boundary is the top edge of the first terrain pixel, refined to sub-pixel
precision by the coverage of the boundary pixels when the image is anti-aliased (``samples > 1``):
``el = el_top - deg_per_px * (a + sum(1 - v[a:b]))`` with ``a`` the first row with any terrain and
``b`` the first fully-terrain row.  With one sample (exact binary pixels) the error is within half
a pixel.

Elevations are degrees above the camera's local horizontal (the sphere's tangent plane at the
position); positions are in the terrain's projected CRS (metres).  bpy is imported lazily, so the
numpy helpers here work without Blender.
"""
from __future__ import annotations

import atexit
import logging
import math
import shutil
import tempfile
import threading
import uuid
import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from blender_addon.core.terrain_mesh import sample_height
from blender_addon.terrain.model import MultiResTerrain
from board.errors import InvalidInputError, NoDataError

log = logging.getLogger(__name__)

__version__ = "1"
RENDERER_NAME = "blender"


@dataclass(frozen=True)
class BlenderSkylineOptions:
    """Sampling of the Blender skyline renderer.

    deg_per_px : elevation resolution of the fine pass, degrees per pixel
    coarse_deg_per_px : elevation resolution of the bracketing pass, degrees per pixel
    columns_per_sample : image columns per skyline azimuth sample (1: one column exactly on each sample)
    samples : Cycles samples per pixel (1: exact binary; > 1: box-filtered coverage, sub-pixel)
    refine : split near-field cells into quads on the bilinear surface (rings, see terrain_mesh)
    band_margin_deg : margin around the previous position's skyline range tried before a coarse pass
    chunk_cells : terrain mesh chunk size, quads a side
    """

    deg_per_px: float = 0.1
    coarse_deg_per_px: float = 1.0
    columns_per_sample: int = 1
    samples: int = 1
    refine: bool = True
    band_margin_deg: float = 1.0
    chunk_cells: int = 256

    def __post_init__(self) -> None:
        if not (0 < self.deg_per_px <= self.coarse_deg_per_px <= 10):
            raise InvalidInputError("need 0 < deg_per_px <= coarse_deg_per_px <= 10 degrees")
        if self.columns_per_sample < 1 or self.samples < 1:
            raise InvalidInputError("columns_per_sample and samples must be >= 1")


DEFAULT_OPTIONS = BlenderSkylineOptions()


# ---------------------------------------------------------------- bpy-free helpers

def column_boundaries(image: np.ndarray, el_top_deg: float, deg_per_px: float, *,
                      eps: float = 1e-3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Elevation (degrees) of the terrain/sky boundary in every column of an equirect band.

    image : (H, W) float in [0, 1], 1 = terrain; row 0's top edge is at ``el_top_deg``
    Returns (elevation (W,), clipped_top (W,) bool: terrain in the first row, no_terrain (W,) bool).
    Columns without terrain get the band's bottom edge; columns with terrain in row 0 get at
    least ``el_top_deg`` minus that row's sky fraction.
    """
    img = np.asarray(image, dtype=np.float64)
    h, w = img.shape
    any_t = img > eps
    full_t = img >= 1.0 - eps
    has = any_t.any(axis=0)
    a = np.where(has, np.argmax(any_t, axis=0), h)
    # first fully-terrain row at or below a (h if none)
    below = full_t & (np.arange(h)[:, None] >= a[None, :])
    b = np.where(below.any(axis=0), np.argmax(below, axis=0), h)
    rows = np.arange(h)[:, None]
    partial = (rows >= a[None, :]) & (rows < b[None, :])
    sky_in_window = np.where(partial, 1.0 - img, 0.0).sum(axis=0)
    pos = np.where(has, a + sky_in_window, h)
    el = el_top_deg - deg_per_px * pos
    return el, has & (a == 0), ~has


def bracket_band(image: np.ndarray, deg_per_px: float, *, pad_deg: float) -> tuple[float, float]:
    """Elevation band (lo, hi) degrees holding every column's boundary of a full-sphere binary pass.

    image : (H, W) binary-ish, rows spanning -90..90 degrees (row 0 at the top).
    """
    t = np.asarray(image) >= 0.5
    h = t.shape[0]
    has = t.any(axis=0)
    first = np.where(has, np.argmax(t, axis=0), h)
    # boundary of column c lies between the centre of row first-1 (sky) and of row first (terrain)
    hi = 90.0 - (first - 0.5) * deg_per_px
    lo = 90.0 - (first + 0.5) * deg_per_px
    return max(-90.0, float(lo.min()) - pad_deg), min(90.0, float(hi.max()) + pad_deg)


def sample_columns(az_cols_deg: np.ndarray, el_cols: np.ndarray, az_samples_deg: np.ndarray) -> np.ndarray:
    """Periodic linear interpolation of per-column elevations at the sample azimuths (degrees)."""
    period = 360.0
    x = np.mod(az_cols_deg - az_cols_deg[0], period)
    order = np.argsort(x)
    x, y = x[order], el_cols[order]
    xp = np.concatenate([x - period, x, x + period])
    yp = np.concatenate([y, y, y])
    return np.interp(np.mod(az_samples_deg - az_cols_deg[0], period), xp, yp)


# ---------------------------------------------------------------- the Blender session

class _Session:
    """The persistent scene: which terrain is built, with which curvature and options."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.terrain_ref: weakref.ref | None = None
        self.key: tuple | None = None
        self.token = uuid.uuid4().hex
        self.last_band: tuple[float, float] | None = None
        self.tmpdir = Path(tempfile.mkdtemp(prefix="skyloc-blender-"))
        atexit.register(shutil.rmtree, self.tmpdir, ignore_errors=True)


_SESSION = _Session()


def _ensure_scene(terrain: MultiResTerrain, radius_m: float, refraction_k: float,
                  refine_half_m: float | None, options: BlenderSkylineOptions) -> None:
    import bpy  # noqa: TID251

    from blender_addon import scene as S

    key = (id(terrain), float(radius_m), float(refraction_k), refine_half_m, options)
    scene = bpy.context.scene
    current = (_SESSION.terrain_ref is not None and _SESSION.terrain_ref() is terrain and _SESSION.key == key
               and scene.get("skyloc_renderer_token") == _SESSION.token)
    if not current:
        S.reset_scene()
        S.build_terrain(terrain, curvature=True, radius_m=radius_m, refraction_k=refraction_k,
                        refine=options.refine, refine_half_m=refine_half_m,
                        chunk_cells=options.chunk_cells)
        S.configure_binary(samples=options.samples)
        _SESSION.terrain_ref = weakref.ref(terrain)
        _SESSION.key = key
        bpy.context.scene["skyloc_renderer_token"] = _SESSION.token


def render_position(terrain: MultiResTerrain, x: float, y: float, azimuths_deg: np.ndarray, *,
                    camera_height_m: float, radius_m: float, refraction_k: float = 0.0,
                    max_distance_m: float | None = None, refine_half_m: float | None = None,
                    options: BlenderSkylineOptions = DEFAULT_OPTIONS) -> tuple[np.ndarray, np.ndarray]:
    """Skyline at world (x, y) metres: (elevation_deg, distance_m), one per azimuth of ``azimuths_deg``.

    Elevations are degrees above the local horizontal; distances are the horizontal distance (m) to
    the terrain just below the boundary (NaN when the column has no terrain).

    The eye is ``camera_height_m`` above the ground (bilinear on the finest level).
    refine_half_m : half-side (metres) of the square around the site whose cells are refined to
        the bilinear surface (default: the terrain's grid_half_m); keep the position inside it.
    """
    from blender_addon import scene as S

    az = np.asarray(azimuths_deg, dtype=float)
    n_az = az.size
    try:
        z = sample_height(terrain, x, y) + camera_height_m
    except NoDataError as exc:
        raise InvalidInputError(f"position ({x:.1f}, {y:.1f}) m has no ground height: {exc}") from None
    with _SESSION.lock:
        _ensure_scene(terrain, radius_m, refraction_k, refine_half_m, options)
        w = n_az * options.columns_per_sample
        col_step = 360.0 / w
        # column c is centred on az[0] + c * col_step: heading in the image centre
        heading = float(az[0]) + 180.0 - 0.5 * col_step
        cam = S.place_camera(x, y, z, heading, 0.0, 0.0)
        clip = float(max_distance_m) if max_distance_m else 1.0e8     # ray length ~ horizontal distance
        if cam.data.clip_end != clip:
            cam.data.clip_end = clip
        dpp = options.deg_per_px
        fine = None
        if _SESSION.last_band is not None:     # try the previous position's band first: skylines are similar
            lo, hi = _snap_band(_SESSION.last_band[0] - options.band_margin_deg,
                                _SESSION.last_band[1] + options.band_margin_deg, dpp)
            fine, top = _render_band(S, w, lo, hi, dpp, options.samples)
            el_cols, clipped, empty = column_boundaries(fine, top, dpp)
            if (clipped.any() and top < 90.0 - 1e-9) or (empty.any() and lo > -90.0 + 1e-9):
                fine = None                    # some boundary lies outside: bracket it properly
        if fine is None:
            hc = int(round(180.0 / options.coarse_deg_per_px))
            coarse = S.read_image(S.render_equirect(_SESSION.tmpdir / "coarse.png", width=w, height=hc,
                                                    el_range_deg=(-90.0, 90.0)))
            lo, hi = _snap_band(*bracket_band(coarse, 180.0 / hc, pad_deg=2 * dpp), dpp)
            fine, top = _render_band(S, w, lo, hi, dpp, options.samples)
            el_cols, clipped, empty = column_boundaries(fine, top, dpp)
        if (~empty).any():
            _SESSION.last_band = (float(el_cols[~empty].min()), float(el_cols[~empty].max()))
        az_cols = float(az[0]) + np.arange(w) * col_step
        dist_cols = _horizon_distances(cam, az_cols - heading, el_cols - 0.5 * dpp, empty, clip)
    if options.columns_per_sample == 1:
        return el_cols.astype(np.float32), dist_cols.astype(np.float32)
    return (sample_columns(az_cols, el_cols, az).astype(np.float32),
            sample_columns(az_cols, dist_cols, az).astype(np.float32))


def _snap_band(lo: float, hi: float, dpp: float) -> tuple[float, float]:
    """Band edges on multiples of ``dpp`` (the same pixel rows whatever the band), within [-90, 90]."""
    lo = max(-90.0, math.floor(lo / dpp) * dpp)
    hi = min(90.0, math.ceil(hi / dpp) * dpp)
    return lo, max(hi, lo + dpp)


def _render_band(S, w: int, lo: float, hi: float, dpp: float, samples: int) -> tuple[np.ndarray, float]:
    """Binary (or coverage) band image of rows ``dpp`` tall from ``lo`` up; returns (image, top edge)."""
    h = max(1, int(round((hi - lo) / dpp)))
    top = lo + h * dpp
    path = S.render_equirect(_SESSION.tmpdir / "fine.png", width=w, height=h, el_range_deg=(lo, top),
                             color_depth="16" if samples > 1 else "8")
    return S.read_image(path), top


def _horizon_distances(cam, az_rel_deg: np.ndarray, el_deg: np.ndarray, empty: np.ndarray,
                       max_dist: float) -> np.ndarray:
    """Horizontal distance (m) to the terrain hit just below each column's boundary (NaN: none).

    One ``scene.ray_cast`` per column along the camera-frame direction (azimuth from the heading,
    clockwise; elevation above the camera's horizontal), from the camera.
    """
    import bpy  # noqa: TID251

    m = np.array(cam.matrix_world)
    a, e = np.radians(az_rel_deg), np.radians(el_deg)
    # camera-body frame (x forward, y left, z up) -> Blender camera axes -> scene
    body = np.stack([np.cos(e) * np.cos(a), -np.cos(e) * np.sin(a), np.sin(e)], axis=1)
    from blender_addon.scene.camera import BODY_FROM_BLENDER_CAM

    dirs = body @ (m[:3, :3] @ BODY_FROM_BLENDER_CAM.T).T
    origin = m[:3, 3]
    depsgraph = bpy.context.evaluated_depsgraph_get()
    scene = bpy.context.scene
    out = np.full(len(a), np.nan)
    for j in np.nonzero(~empty)[0]:
        hit, loc, *_ = scene.ray_cast(depsgraph, origin.tolist(), dirs[j].tolist(), distance=max_dist)
        if hit:
            out[j] = float(np.hypot(loc[0] - origin[0], loc[1] - origin[1]))
    return out


@dataclass
class SkylineTile:
    """A rendered tile: elevation_deg (degrees above the eye's local horizontal) and distance_m (horizontal
    distance to the horizon point, metres, NaN where none), both (nrows, ncols, n_azimuth) float32."""

    elevation_deg: np.ndarray
    distance_m: np.ndarray


def render_tile(terrain: MultiResTerrain, grid, tile, spec, *,
                options: BlenderSkylineOptions = DEFAULT_OPTIONS) -> SkylineTile:
    """Render every position of ``tile`` of ``grid`` (a :class:`board.skydb.GridSpec` and
    :class:`board.skydb.Tile`) with ``spec``'s camera height, azimuths, body radius and refraction.

    Returns SkylineTile with elevation_deg and distance_m, (nrows, ncols, n_azimuth) float32.
    """
    rows = np.arange(tile.row0, tile.row0 + tile.nrows)
    cols = np.arange(tile.col0, tile.col0 + tile.ncols)
    jj, ii = np.meshgrid(cols, rows)
    xs, ys = grid.xy(ii, jj)
    az = spec.azimuths_deg()
    # refine the whole grid's neighbourhood (same value for every tile of a grid: one scene build)
    gx0, gy0, gx1, gy1 = grid.bounds()
    sx, sy = terrain.site_xy
    half = float(max(abs(gx0 - sx), abs(gx1 - sx), abs(gy0 - sy), abs(gy1 - sy)))
    out = np.full((tile.nrows, tile.ncols, az.size), np.nan, dtype=np.float32)
    dist = np.full_like(out, np.nan)
    for r in range(tile.nrows):
        for c in range(tile.ncols):
            out[r, c], dist[r, c] = render_position(terrain, float(xs[r, c]), float(ys[r, c]), az,
                                        camera_height_m=spec.camera_height_m, radius_m=spec.body_radius_m,
                                        refraction_k=spec.refraction_k, max_distance_m=spec.max_distance_m,
                                        refine_half_m=half, options=options)
    return SkylineTile(elevation_deg=out, distance_m=dist)
