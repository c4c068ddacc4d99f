"""Pictures of terrains (matplotlib, Agg): hillshaded DEMs and the multi-resolution levels' layout."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from osgeo import gdal

from .dem import open_metric_source
from .model import MultiResTerrain

gdal.UseExceptions()


def hillshade(z: np.ndarray, cell_m: float, *, azimuth_deg: float = 315.0, altitude_deg: float = 35.0) -> np.ndarray:
    """Lambertian hillshade in [0, 1] of heights ``z`` (rows, cols; metres; row 0 north), sun at azimuth/altitude."""
    gy, gx = np.gradient(np.nan_to_num(z, nan=float(np.nanmean(z)) if np.isfinite(z).any() else 0.0), cell_m)
    # surface normal (east, north, up) with north = -row direction
    nx, ny, nz = -gx, gy, np.ones_like(z)
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    az, alt = np.radians(azimuth_deg), np.radians(altitude_deg)
    sx, sy, sz = np.sin(az) * np.cos(alt), np.cos(az) * np.cos(alt), np.sin(alt)
    shade = np.clip((nx * sx + ny * sy + nz * sz) / norm, 0.0, 1.0)
    return np.where(np.isnan(z), np.nan, shade)


def _figure():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_dem(dem_path: str | os.PathLike, out_png: str | os.PathLike, *, max_pixels: int = 1200, body=None,
             dpi: int = 110) -> Path:
    """Hillshade of a whole DEM (decimated to at most ``max_pixels`` per side) in its metric working CRS."""
    plt = _figure()
    src = open_metric_source(dem_path, body=body)
    cols, rows = src.size
    k = max(1, int(np.ceil(max(cols, rows) / max_pixels)))
    raw = src.dataset.GetRasterBand(1).ReadAsArray(0, 0, cols, rows, buf_xsize=max(1, cols // k), buf_ysize=max(1, rows // k))
    z = src.to_heights(raw)
    cell = src.cell_m * cols / z.shape[1]
    xmin, ymin, xmax, ymax = src.bounds()
    fig, ax = plt.subplots(figsize=(7, 7 * rows / cols + 0.5))
    ax.imshow(hillshade(z, cell), cmap="gray", extent=(xmin, xmax, ymin, ymax), vmin=0, vmax=1)
    im = ax.imshow(z, cmap="terrain", alpha=0.35, extent=(xmin, xmax, ymin, ymax))
    fig.colorbar(im, ax=ax, label="height (m)", shrink=0.8)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{Path(dem_path).name} ({src.body.name}, {src.cell_m:g} m cells)")
    out = Path(out_png)
    fig.savefig(out, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return out


def plot_multires(terrain: MultiResTerrain, out_png: str | os.PathLike, *, grid_half_m: float | None = None,
                  dpi: int = 110) -> Path:
    """The levels drawn coarse to fine (hillshaded), each outlined and labelled with its cell size and
    inner distance, with the search grid and the site."""
    plt = _figure()
    fig, ax = plt.subplots(figsize=(8, 8))
    inner = terrain.meta.get("inner_distance_m", [0.0] * len(terrain.levels))
    colors = plt.cm.viridis(np.linspace(0, 1, len(terrain.levels)))
    for k in range(len(terrain.levels) - 1, -1, -1):
        lvl = terrain.levels[k]
        xmin, ymin, xmax, ymax = lvl.bounds()
        step = max(1, int(np.ceil(max(lvl.array.shape) / 800)))
        ax.imshow(hillshade(lvl.array[::step, ::step], lvl.cell_m * step), cmap="gray", vmin=0, vmax=1,
                  extent=(xmin, xmax, ymin, ymax), interpolation="nearest")
        ax.add_patch(plt.Rectangle((xmin, ymin), xmax - xmin, ymax - ymin, fill=False, color=colors[k], lw=1.5,
                                   label=f"level {k}: {lvl.cell_m:g} m, beyond {inner[k]:.0f} m"))
    sx, sy = terrain.site_xy
    half = grid_half_m if grid_half_m is not None else terrain.meta.get("grid_half_m", 0.0)
    ax.add_patch(plt.Rectangle((sx - half, sy - half), 2 * half, 2 * half, fill=False, color="red", lw=1.5,
                               label=f"search grid {2 * half:g} m"))
    ax.plot([sx], [sy], "r+", ms=10)
    b = terrain.levels[-1].bounds()
    ax.set_xlim(b[0], b[2])
    ax.set_ylim(b[1], b[3])
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"multi-resolution terrain ({terrain.body.name}), max-downsampled levels")
    ax.legend(loc="upper right", fontsize=7, framealpha=0.8)
    out = Path(out_png)
    fig.savefig(out, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return out
