"""How far the multi-resolution terrain's horizons are from the full-resolution ones (`make bench-terrain`).

For each real DEM of ../shared/data/dems (skipped when missing): a 1 km search grid at the DEM's
centre (or ``--center``), ``--positions`` seeded random positions in it, the ray-marched horizon
(360 azimuths, 2 m mast) on the all-native terrain (one level: the whole DEM at its own cells) and
on the multi-resolution terrain built with ``cells_per_step`` = 1, 2, 4 (the default,
``multires.CELLS_PER_STEP``).  Per position: the RMS difference of the two horizons after removing
their mean offset (degrees; the offset is the part a heading-free matcher does not see either), and
the largest absolute one; the table gives the median over positions, the bytes of the levels and
the build time.

    python -m benchmarks.bench_terrain_levels [--positions 10] [--seed 0] [--dem NAME ...]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from benchmarks.bench_blender import DEMS

DEFAULT_DEMS = ("earth_oetztal_alps_srtm3.tif", "earth_sthelens_1980_usgs30m.dem",
                "earth_baltoro_karakoram_srtm3.tif", "moon_gld100_aristoteles_256ppd.tif")


def _horizons(terrain, xs, ys, body_radius_m: float) -> np.ndarray:
    from render_service.renderers import raymarch
    from render_service.renderers.base import RenderSpec

    spec = RenderSpec(camera_height_m=2.0, n_azimuth=360, body_radius_m=body_radius_m)
    return raymarch.render_positions(terrain, xs, ys, spec)[0].astype(np.float64)


def bench_dem(name: str, n_pos: int, seed: int, grid_half_m: float, cells: tuple[int, ...]) -> list[str]:
    """Table rows for one DEM (file name inside DEMS)."""
    from blender_addon.terrain.dem import read_dem
    from blender_addon.terrain.model import MultiResTerrain, TerrainLevel
    from blender_addon.terrain.multires import build_multires

    path = DEMS / name
    if not path.is_file():
        return [f"| {name} | missing | | | | |"]
    dem = read_dem(path)
    gt = dem.geotransform
    xmin, ymin, xmax, ymax = dem.bounds()
    site = (0.5 * (xmin + xmax), 0.5 * (ymin + ymax))
    native = MultiResTerrain([TerrainLevel(dem.array, gt[0], gt[3], gt[1])], dem.crs_wkt, dem.body, site)
    rng = np.random.default_rng(seed)
    xs = site[0] + rng.uniform(-grid_half_m, grid_half_m, n_pos)
    ys = site[1] + rng.uniform(-grid_half_m, grid_half_m, n_pos)
    truth = _horizons(native, xs, ys, dem.body.radius_m)
    rows = []
    for n in cells:
        t0 = time.perf_counter()
        mr = build_multires(path, site, grid_half_m=grid_half_m, cells_per_step=n)
        t_build = time.perf_counter() - t0
        h = _horizons(mr, xs, ys, dem.body.radius_m)
        d = h - truth
        d = d - np.nanmean(d, axis=1, keepdims=True)
        rms = np.sqrt(np.nanmean(d * d, axis=1))
        mx = np.nanmax(np.abs(d), axis=1)
        mb = sum(lv.array.nbytes for lv in mr.levels) / 2**20
        rows.append(f"| {name} ({dem.cell_m:.0f} m) | {n} | {len(mr.levels)} | {np.median(rms):.4f} | "
                    f"{np.median(mx):.3f} | {mb:.0f} MB, {t_build:.1f} s |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--positions", type=int, default=10, help="random positions per DEM")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--grid-half", type=float, default=500.0, help="half the search grid's side (m)")
    ap.add_argument("--cells", default="1,2,4", help="cells_per_step values to compare")
    ap.add_argument("--dem", action="append", default=None, help="DEM file name in ../shared/data/dems")
    a = ap.parse_args()
    cells = tuple(int(c) for c in a.cells.split(","))
    print(f"horizon of the multi-resolution terrain vs all native cells: {a.positions} positions, seed {a.seed}, "
          f"grid +-{a.grid_half:g} m, 360 azimuths")
    print("| DEM | cells per step | levels | RMS (deg), offset removed, median | max abs (deg), median | "
          "levels in memory, build |")
    print("|---|---|---|---|---|---|")
    for name in a.dem or DEFAULT_DEMS:
        for row in bench_dem(name, a.positions, a.seed, a.grid_half, cells):
            print(row, flush=True)


if __name__ == "__main__":
    main()
