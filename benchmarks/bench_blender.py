"""Benchmark of the Blender core (issue 4): binary panoramas and the Blender skyline renderer.

Run with ``python -m benchmarks.bench_blender`` (``make bench-blender``).  Prints markdown tables:

1. terrain build and binary equirectangular panoramas (default 2048 x 1024) per position in a warm
   process (persistent scene: only the camera moves), on the procedural Mars site (20 km at 5 m);
2. skyline-database render rate of the Blender renderer versus the ray-marcher in the same run,
   and their agreement (median / 99th percentile of |difference|, degrees) with each other and
   with the brute-force reference, on real DEMs from ../shared/data/dems (single-level terrains so
   the reference sees the same surface).

The 2 cores are shared with other work: the load average is printed with the figures; compare
ratios measured in the same run rather than absolute times.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

DEMS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "dems"


def _load() -> str:
    return "load average %.1f / %.1f / %.1f" % os.getloadavg()


def bench_panorama(dem_spec: str, width: int, n: int) -> list[str]:
    from blender_addon import scene as S
    from blender_addon.core.terrain_mesh import sample_height
    from blender_addon.terrain.dem import resolve_dem
    from blender_addon.terrain.multires import build_multires

    path = resolve_dem(dem_spec)
    t0 = time.perf_counter()
    terrain = build_multires(path, (0.0, 0.0), grid_half_m=200.0)
    t_levels = time.perf_counter() - t0
    S.reset_scene()
    t0 = time.perf_counter()
    S.build_terrain(terrain)
    t_mesh = time.perf_counter() - t0
    S.configure_binary()
    rng = np.random.default_rng(0)
    times, cpu = [], []
    tmp = Path(tempfile.mkdtemp())
    for i in range(n + 1):
        x, y = rng.uniform(-200, 200, 2)
        S.place_camera(x, y, sample_height(terrain, x, y) + 2.0, rng.uniform(0, 360), rng.uniform(-10, 10),
                       rng.uniform(-10, 10))
        t0, c0 = time.perf_counter(), time.process_time()
        img = S.read_image(S.render_equirect(tmp / "p.png", width=width, height=width // 2))
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        assert img.shape == (width // 2, width)
    import bpy

    n_quads = sum(len(o.data.polygons) for o in bpy.data.collections[S.TERRAIN_COLLECTION].objects)
    rows = [f"| terrain levels ({dem_spec}, {len(terrain.levels)} levels) | {t_levels:.2f} s |",
            f"| terrain meshes (foreach_set{f', {n_quads:,} quads' if n_quads else ''}) | {t_mesh:.2f} s |",
            f"| first binary panorama {width} x {width // 2} (BVH build + render + PNG read) | {times[0]:.2f} s |",
            f"| warm binary panorama {width} x {width // 2}, median of {n} poses (pitch/roll +-10 deg) "
            f"| {np.median(times[1:]):.2f} s (min {min(times[1:]):.2f}, max {max(times[1:]):.2f}); "
            f"CPU {np.median(cpu[1:]):.2f} s |"]
    return rows


def _single_level(dem_path: Path, frac_xy=(0.5, 0.5)):
    from blender_addon.terrain.dem import read_dem
    from blender_addon.terrain.model import MultiResTerrain, TerrainLevel

    dem = read_dem(dem_path)
    gt = dem.geotransform
    xmin, ymin, xmax, ymax = dem.bounds()
    site = (xmin + frac_xy[0] * (xmax - xmin), ymin + frac_xy[1] * (ymax - ymin))
    return dem, MultiResTerrain([TerrainLevel(dem.array, gt[0], gt[3], gt[1])], dem.crs_wkt, dem.body, site), site


def bench_renderers(names: list[str], n_side: int, size_frac: float) -> list[str]:
    from blender_addon import skyline_renderer
    from board.skydb import GridSpec, Tile
    from render_service.renderers import raymarch, reference
    from render_service.renderers.base import RenderSpec

    rows = []
    for name in names:
        p = DEMS / name
        if not p.is_file():
            rows.append(f"| {name} | missing | | | | | | |")
            continue
        dem, terrain, site = _single_level(p)
        xmin, ymin, xmax, ymax = dem.bounds()
        size = size_frac * min(xmax - xmin, ymax - ymin)
        grid = GridSpec.from_center(site, size, size / (n_side - 1))
        terrain.meta["grid_half_m"] = size / 2
        tile = Tile(0, 0, 0, 0, grid.ny, grid.nx)
        spec = RenderSpec(camera_height_m=2.0, body_radius_m=dem.body.radius_m)
        raymarch.render_tile(terrain, grid, Tile(0, 0, 0, 0, 1, 1), spec)          # JIT warm-up
        t0 = time.perf_counter()
        rm = raymarch.render_tile(terrain, grid, tile, spec).elevation_deg
        t_rm = time.perf_counter() - t0
        skyline_renderer.render_tile(terrain, grid, Tile(0, 0, 0, 0, 1, 1), spec)  # scene build
        t0 = time.perf_counter()
        bl = skyline_renderer.render_tile(terrain, grid, tile, spec).elevation_deg
        t_bl = time.perf_counter() - t0
        ii, jj = np.meshgrid(np.arange(grid.ny), np.arange(grid.nx), indexing="ij")
        xs, ys = grid.xy(ii, jj)
        bf = np.stack([reference.brute_force_horizon(dem, x, y, spec, step_cells=0.01)[1]
                       for x, y in zip(xs.ravel(), ys.ravel())]).reshape(bl.shape)

        def stats(a, b):
            d = np.abs(a - b).ravel()
            d = d[np.isfinite(d)]
            return f"{np.median(d):.3f} / {np.percentile(d, 99):.3f}"

        n = grid.n_positions
        rows.append(f"| {name} ({dem.cell_m:.0f} m cells) | {n} | {n / t_bl:.2f} | {n / t_rm:.1f} | "
                    f"{t_bl / t_rm:.0f}x | {stats(bl, rm)} | {stats(bl, bf)} | {stats(rm, bf)} |")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dem", default="procedural:mars:7", help="DEM of the panorama benchmark")
    ap.add_argument("--width", type=int, default=2048, help="panorama width, pixels")
    ap.add_argument("--poses", type=int, default=5, help="warm panoramas to time")
    ap.add_argument("--grid", type=int, default=5, help="positions per grid side in the renderer comparison")
    ap.add_argument("--dems", default="earth_sthelens_1980_usgs30m.dem,mars_gale_hirise_1m_mmgis_missionDEM.tif")
    args = ap.parse_args()

    when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    lines = [f"Blender core benchmark, {when}, {_load()} (2 shared cores)",
             "", "| binary panoramas (Cycles CPU, 1 sample) | wall time (CPU time: both cores) |", "| --- | --- |"]
    lines += bench_panorama(args.dem, args.width, args.poses)
    lines += ["", f"Skyline databases, {args.grid} x {args.grid} positions, 360 azimuths, 0.1 deg/px "
              "(|difference| median / p99, degrees; bf = brute-force reference, 0.01-cell steps)", "",
              "| DEM | positions | Blender pos/s | ray-marcher pos/s | time ratio | Blender vs ray-marcher "
              "| Blender vs bf | ray-marcher vs bf |", "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    lines += bench_renderers([s for s in args.dems.split(",") if s], args.grid, 0.5)
    lines += ["", f"end: {_load()}"]
    print("\n".join(lines))  # noqa: T201 (benchmark output)


if __name__ == "__main__":
    main()
