"""Procedural terrain: seeded synthetic DEMs for Mars, the Moon and Europa, written as GeoTIFF.

``synthesize(preset, size_m=, res_m=, seed=, out_path=)`` builds, from one
``numpy.random.Generator(PCG64(seed))``:

* fractal relief (spectral synthesis) and broad hills,
* ridges (a ridged multifractal) and valleys (smooth troughs along a slow field's zero lines),
* craters with a power-law size-frequency distribution, rim, ejecta, central peaks for
  large ones, plus one large "landmark" crater,
* blocks and boulders (ejecta blocks around fresh craters and a scattered population),
* for ``europa``: double ridges, broken-plate chaos terrain, crevasses and penitente fields.

The GeoTIFF is on the body's sphere in an equirectangular projection centred on (0, 0)
(x from -size/2 to +size/2 metres): a true-scale local metric frame.  Same seed and
arguments give the same bytes (no timestamps are written).
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from osgeo import gdal

from board.atomic import atomic_path
from board.conventions import BODIES
from board.errors import InvalidInputError

from ..crs import body_equirectangular_srs
from ..dem import available_memory_bytes as _available_memory_bytes
from . import craters as _craters
from . import features as _features
from .fields import ridged, smooth_mask, spectral_field

log = logging.getLogger(__name__)
gdal.UseExceptions()

#: Bumped whenever a preset or algorithm change alters the output for a given seed.
GENERATOR_VERSION = 1
#: Largest raster synthesised (cells per side): 20000^2 float32 is 1.6 GB.
MAX_CELLS_PER_SIDE = 20000
#: Measured peak memory of :func:`generate` per cell (about 700 MB for 4000^2), with a margin.
_PEAK_BYTES_PER_CELL = 56


@dataclass(frozen=True)
class Preset:
    """Parameters of a terrain type (heights and lengths in metres).

    relief_m : standard deviation of the small-scale fractal relief
    hills_m : standard deviation of the broad hills (wavelengths 2-20 km)
    ridge_m, valley_m : height of ridge crests / depth of valleys
    crater_density : craters larger than 1 km per km^2 (cumulative power law, exponent ``crater_slope``)
    transition_m : simple-to-complex crater transition diameter (central peaks above it)
    landmark_crater : relative diameter range (fraction of the size) of one large crater, or None
    boulders_per_km2, boulder_h_m : scattered blocks and their height range
    """

    body: str
    relief_m: float
    relief_beta: float
    hills_m: float
    ridge_m: float
    valley_m: float
    crater_density: float
    crater_slope: float
    transition_m: float
    landmark_crater: tuple[float, float] | None
    boulders_per_km2: float
    boulder_h_m: tuple[float, float]
    icy: bool = False


PRESETS: dict[str, Preset] = {
    "mars": Preset("mars", relief_m=6.0, relief_beta=2.8, hills_m=90.0, ridge_m=140.0, valley_m=70.0,
                   crater_density=0.006, crater_slope=2.0, transition_m=6000.0, landmark_crater=(0.2, 0.4),
                   boulders_per_km2=400.0, boulder_h_m=(0.5, 4.0)),
    "moon": Preset("moon", relief_m=4.0, relief_beta=3.0, hills_m=60.0, ridge_m=50.0, valley_m=20.0,
                   crater_density=0.03, crater_slope=2.0, transition_m=15000.0, landmark_crater=(0.25, 0.45),
                   boulders_per_km2=300.0, boulder_h_m=(0.5, 3.0)),
    "europa": Preset("europa", relief_m=3.0, relief_beta=2.6, hills_m=25.0, ridge_m=0.0, valley_m=0.0,
                     crater_density=0.0008, crater_slope=2.0, transition_m=5000.0, landmark_crater=None,
                     boulders_per_km2=150.0, boulder_h_m=(0.5, 3.0), icy=True),
}


def generate(preset: str, *, size_m: float, res_m: float, seed: int) -> np.ndarray:
    """Heights (rows, cols) float32 metres of a square procedural terrain (row 0 north).

    size_m : side length (m); res_m : cell size (m); seed : integer seed.
    """
    key = preset.strip().lower()
    if key not in PRESETS:
        raise InvalidInputError(f"unknown terrain preset {preset!r}: use one of {', '.join(PRESETS)}")
    if not (res_m > 0 and size_m > 0):
        raise InvalidInputError(f"size ({size_m}) and resolution ({res_m}) must be positive metres")
    n = int(round(size_m / res_m))
    if n < 16 or n > MAX_CELLS_PER_SIDE:
        raise InvalidInputError(
            f"{size_m:g} m at {res_m:g} m is {n} cells per side: use between 16 and {MAX_CELLS_PER_SIDE} "
            "(change --size or --res)"
        )
    need = _PEAK_BYTES_PER_CELL * n * n
    avail = _available_memory_bytes()
    if avail is not None and need > 0.7 * avail:
        raise InvalidInputError(
            f"{n} x {n} cells needs about {need / 1e9:.1f} GB of memory to synthesise, more than 70% of the "
            f"{avail / 1e9:.1f} GB available: use a smaller --size or a coarser --res"
        )
    p = PRESETS[key]
    rng = np.random.Generator(np.random.PCG64(seed))
    shape = (n, n)
    size = n * res_m
    span = min(size, 20000.0)

    # relief and hills
    z = p.relief_m * spectral_field(shape, rng, cell_m=res_m, wavelength_min_m=2 * res_m,
                                    wavelength_max_m=min(size, 2000.0), beta=p.relief_beta)
    z += p.hills_m * spectral_field(shape, rng, cell_m=res_m, wavelength_min_m=max(4 * res_m, 400.0),
                                    wavelength_max_m=max(span, 2000.0), beta=3.5)
    # ridges: a ridged multifractal (Musgrave) of three octaves, present where a slow mask says so
    ridge_mask = smooth_mask(spectral_field(shape, rng, cell_m=res_m, wavelength_min_m=max(4 * res_m, 2000.0),
                                            wavelength_max_m=max(span, 4000.0), beta=3.0), threshold=-0.2, width=1.2)
    if p.ridge_m:
        z += p.ridge_m * ridge_mask * ridged_multifractal(shape, rng, res_m=res_m, span=span)
    # valleys: smooth sinuous troughs along the zero lines of a slow field, away from the ridges
    valley_f = spectral_field(shape, rng, cell_m=res_m, wavelength_min_m=max(4 * res_m, 1200.0),
                              wavelength_max_m=max(span, 6000.0), beta=3.5)
    if p.valley_m:
        z -= p.valley_m * (1.0 - ridge_mask) * ridged(valley_f * 2.5, sharpness=3.0)
    del valley_f, ridge_mask

    if p.icy:
        _icy_features(z, rng, res_m=res_m, size=size)

    # craters
    diam = _craters.draw_diameters(
        rng, area_m2=size * size, density_per_km2_above_1km=p.crater_density, slope=p.crater_slope,
        d_min_m=4 * res_m, d_max_m=0.25 * size,
    )
    if p.landmark_crater is not None:
        diam = np.concatenate([[rng.uniform(*p.landmark_crater) * size], diam])
    craters = _craters.place_craters(rng, diam, width_m=size, height_m=size)
    if p.landmark_crater is not None and craters:
        # the landmark crater is fresh and fully inside the area, stamped first
        big = max(craters, key=lambda c: c.diameter_m)
        craters.remove(big)
        R = big.diameter_m / 2
        lx, ly = rng.uniform(R, size - R), rng.uniform(R, size - R)
        craters.insert(0, _craters.Crater(lx, ly, big.diameter_m, 1.0))
    _craters.stamp_craters(z, craters, cell_m=res_m, transition_m=p.transition_m)

    # blocks: ejecta blocks around fresh craters big enough to excavate them, and scattered boulders
    fresh = [c for c in craters if c.freshness > 0.8 and c.diameter_m > 20 * res_m]
    if fresh:
        centres = np.array([[c.y / res_m, c.x / res_m] for c in fresh])
        spread = np.array([c.diameter_m / res_m for c in fresh])
        n_blocks = int(sum(min(200.0, c.diameter_m / (4 * res_m)) for c in fresh))
        _features.add_blocks(z, rng, cell_m=res_m, count=n_blocks, h_min_m=p.boulder_h_m[0], h_max_m=3 * p.boulder_h_m[1],
                             centres_rc=centres, spread_cells=spread)
    n_boulders = int(p.boulders_per_km2 * size * size / 1e6)
    _features.add_blocks(z, rng, cell_m=res_m, count=n_boulders, h_min_m=p.boulder_h_m[0], h_max_m=p.boulder_h_m[1])
    return z.astype(np.float32, copy=False)


def ridged_multifractal(shape: tuple[int, int], rng: np.random.Generator, *, res_m: float, span: float) -> np.ndarray:
    """Ridged multifractal in [0, ~1.6]: sharp crests whose finer octaves grow only on the coarser crests.

    Octave wavelengths (m): 1.5-8 km, 400 m-1.5 km, 100-400 m (never below 4 cells).
    """
    bands = ((1500.0, 8000.0), (400.0, 1500.0), (100.0, 400.0))
    total = np.zeros(shape, np.float32)
    weight = np.ones(shape, np.float32)
    gain = 1.0
    for lo, hi in bands:
        lo = max(lo, 4 * res_m)
        hi = max(min(hi, span), 2 * lo)
        sig = ridged(spectral_field(shape, rng, cell_m=res_m, wavelength_min_m=lo, wavelength_max_m=hi, beta=3.0),
                     sharpness=2.0) * weight
        total += gain * sig
        weight = np.clip(sig * 2.0, 0.0, 1.0)
        gain *= 0.45
    return total


def _icy_features(z: np.ndarray, rng: np.random.Generator, *, res_m: float, size: float) -> None:
    """Europa: double ridges, chaos (broken plates), crevasses, penitentes."""
    area_km2 = size * size / 1e6
    _features.add_double_ridges(z, rng, cell_m=res_m, count=max(1, int(round(area_km2 / 100.0))))
    n_chaos = max(1, int(round(area_km2 / 250.0)))
    for _ in range(n_chaos):
        radius = rng.uniform(0.12, 0.25) * size
        centre = (rng.uniform(0.2, 0.8) * size, rng.uniform(0.2, 0.8) * size)
        _features.add_broken_plates(z, rng, cell_m=res_m, centre_xy_m=centre, radius_m=radius,
                                    plate_size_m=(max(10 * res_m, 0.03 * size), max(40 * res_m, 0.1 * size)))
    _features.add_crevasses(z, rng, cell_m=res_m, count=max(3, int(area_km2 / 4.0)),
                            length_m=(min(300.0, size / 4), min(4000.0, size / 2)))
    cover = spectral_field(z.shape, rng, cell_m=res_m, wavelength_min_m=max(4 * res_m, 500.0),
                           wavelength_max_m=max(size, 2000.0), beta=3.0)
    _features.add_penitentes(z, rng, cell_m=res_m, coverage_field=cover)


def write_geotiff(z: np.ndarray, out_path: str | os.PathLike, *, res_m: float, body_name: str, tags: dict[str, str]) -> Path:
    """Write heights as a deterministic, tiled, DEFLATE-compressed Float32 GeoTIFF centred on (0, 0).

    Written to a temporary file beside ``out_path`` and renamed (never half-written).
    """
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    rows, cols = z.shape
    srs = body_equirectangular_srs(BODIES[body_name])
    drv = gdal.GetDriverByName("GTiff")
    with atomic_path(out, suffix=".part.tif") as tmp:
        ds = drv.Create(str(tmp), cols, rows, 1, gdal.GDT_Float32,
                        options=["TILED=YES", "COMPRESS=DEFLATE", "PREDICTOR=3", "ZLEVEL=6", "BLOCKXSIZE=256",
                                 "BLOCKYSIZE=256"])
        ds.SetGeoTransform((-cols * res_m / 2.0, res_m, 0.0, rows * res_m / 2.0, 0.0, -res_m))
        ds.SetProjection(srs.ExportToWkt())
        ds.SetMetadata({k: str(v) for k, v in sorted(tags.items())})
        band = ds.GetRasterBand(1)
        band.SetUnitType("m")
        band.SetDescription("height above the body's reference sphere (m)")
        band.WriteArray(z)
        ds.FlushCache()
        ds = None
    return out


def synthesize(preset: str, *, size_m: float, res_m: float, seed: int, out_path: str | os.PathLike) -> Path:
    """Synthesise a procedural DEM and write it as GeoTIFF; same arguments give the same bytes.

    preset : "mars", "europa" or "moon"; size_m : side (m); res_m : cell (m); seed : integer.
    Returns the output path.
    """
    key = preset.strip().lower()
    z = generate(key, size_m=size_m, res_m=res_m, seed=seed)
    tags = {
        "SKYLOC_GENERATOR": f"skyloc.procedural v{GENERATOR_VERSION}",
        "SKYLOC_PRESET": key,
        "SKYLOC_SEED": str(int(seed)),
        "SKYLOC_BODY": PRESETS[key].body,
    }
    out = write_geotiff(z, out_path, res_m=res_m, body_name=PRESETS[key].body, tags=tags)
    log.info("synthesised %s terrain (seed %d, %g m at %g m) -> %s", key, seed, size_m, res_m, out)
    return out


__all__ = ["PRESETS", "Preset", "generate", "synthesize", "write_geotiff", "GENERATOR_VERSION"]
