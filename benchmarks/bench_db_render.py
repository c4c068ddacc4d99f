"""Benchmark of the skyline-database renderer (issue 2): `make bench-db`.

1. A 20 x 20 km procedural Mars DEM at 5 m (procedural:mars:7, cached) and its prepared
   multi-resolution terrain around the grid.
2. The 1 x 1 km grid at 5 m (201 x 201 = 40,401 positions), 360 azimuths, camera 2 m, rendered
   with `render_database` (tiles of 64, Zarr store): positions per second, wall and CPU.
3. Accuracy on that DEM: ray-marcher vs the brute-force reference at random grid positions.
4. GRASS r.horizon on the same DEM and positions (a block of grid positions; the grid is centred
   so its positions are cell centres, where r.horizon computes), 360 directions: positions per
   second in the same run, the speed ratio, and the median difference at ground level.
5. A 7 x 7 km grid at 5 m (1401 x 1401 = 1.96 M positions): extrapolated render time, and the
   measured size of a full store written with the rendered tiles of step 2 repeated.

The machine is shared (2 cores, other jobs running): figures are noisy; the ratio to GRASS is
measured in the same run.  Prints a markdown table.

Usage: python -m benchmarks.bench_db_render [--quick] [--grass-block N] [--no-grass] [--no-7x7]
"""
from __future__ import annotations

import argparse
import datetime as dt
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from blender_addon.terrain.dem import read_dem, resolve_dem
from board.skydb import GridSpec, SkyDB, SkyDBMeta, SkyDBWriter, plan_tiles
from render_service import dbrender
from render_service.renderers import raymarch
from render_service.renderers.base import RenderSpec
from render_service.renderers.grass import grass_available, r_horizon
from render_service.renderers.reference import brute_force_horizon

DEM_SPEC = "procedural:mars:7"          # 20 km at 5 m
CENTER = (2.5, 2.5)                       # grid positions on cell centres (cells at 5 k metres)


def _cpu_s() -> float:
    return time.process_time()


def _children_cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a 300 m grid instead of 1 km")
    ap.add_argument("--grass-block", type=int, default=8, help="side of the block of positions given to GRASS")
    ap.add_argument("--no-grass", action="store_true")
    ap.add_argument("--no-7x7", action="store_true", help="skip writing the 7 x 7 km store")
    ap.add_argument("--accuracy-points", type=int, default=20)
    args = ap.parse_args()
    rows: list[tuple[str, str]] = []
    load0 = os.getloadavg()
    work = Path(tempfile.mkdtemp(prefix="skyloc-bench-db-"))
    try:
        t = time.time()
        dem_path = resolve_dem(DEM_SPEC)
        rows.append(("DEM", f"`{DEM_SPEC}` 20 x 20 km at 5 m ({time.time() - t:.1f} s incl. cache)"))
        size_m = 300.0 if args.quick else 1000.0
        step_m = 5.0
        spec = RenderSpec(camera_height_m=2.0, n_azimuth=360)
        job = dbrender.prepare_job(dem_path, center_xy=CENTER, size_m=size_m, step_m=step_m, spec=spec)
        t = time.time()
        terrain = dbrender.load_terrain(job, terrain_dir=work / "terrain")
        levels = ", ".join(f"{lv.cell_m:g} m x {lv.array.shape[1]}" for lv in terrain.levels)
        rows.append(("multi-resolution terrain", f"{len(terrain.levels)} levels ({levels}); prepared in {time.time() - t:.1f} s"))
        # compile once (numba caches on disk; the first process compiles)
        grid = job.grid
        raymarch.render_tile(terrain, grid, plan_tiles(grid, 4)[0], job.spec)

        # --- the database render
        out = work / "db.zarr"
        t, c = time.time(), _cpu_s()
        db = dbrender.render_database(dem_path, center_xy=CENTER, size_m=size_m, step_m=step_m, spec=spec, out=out,
                                      tile_size=64, terrain_dir=work / "terrain", progress=True)
        wall, cpu = time.time() - t, _cpu_s() - c
        n = grid.n_positions
        rate_wall = n / wall
        rate_cpu2 = n / cpu * 2.0
        rows.append(("grid", f"{grid.nx} x {grid.ny} = {n:,} positions, 360 azimuths, camera 2 m, tiles of 64"))
        rows.append(("skyloc render (wall)", f"{wall:.1f} s -> **{rate_wall:,.0f} positions/s** "
                                             f"({rate_wall * 360:,.0f} rays/s)"))
        rows.append(("skyloc render (CPU)", f"{cpu:.1f} CPU-s -> {rate_cpu2:,.0f} positions/s on 2 dedicated cores "
                                            f"({n / cpu:,.0f} per core)"))
        rows.append(("database size", f"{db.size_bytes() / 1e6:.1f} MB (elevation int16 + distance uint16)"))

        # --- accuracy vs brute force on the same DEM
        dem = read_dem(dem_path, bounds=(CENTER[0] - 10000, CENTER[1] - 10000, CENTER[0] + 10000, CENTER[1] + 10000))
        rng = np.random.default_rng(0)
        ii = rng.integers(0, grid.ny, args.accuracy_points)
        jj = rng.integers(0, grid.nx, args.accuracy_points)
        diffs = []
        for i, j in zip(ii, jj):
            x, y = grid.xy(i, j)
            _, ref = brute_force_horizon(dem, float(x), float(y), job.spec)
            diffs.append(np.abs(db.skyline(int(i), int(j)) - ref))
        d = np.concatenate(diffs)
        rows.append(("accuracy vs brute force", f"{args.accuracy_points} random positions x 360: median "
                                                f"{np.median(d):.3f} deg, p99 {np.percentile(d, 99):.3f} deg, "
                                                f"max {d.max():.2f} deg (incl. 0.005 deg quantisation)"))

        # --- GRASS r.horizon on the same DEM and positions
        if not args.no_grass and grass_available():
            b = args.grass_block
            i0, j0 = grid.ny // 2 - b // 2, grid.nx // 2 - b // 2
            bi, bj = np.meshgrid(np.arange(i0, i0 + b), np.arange(j0, j0 + b), indexing="ij")
            px, py = grid.xy(bi.ravel(), bj.ravel())
            pts = np.stack([px, py], axis=1)
            c = _children_cpu_s()
            g = r_horizon(dem, pts, step_deg=1.0, workdir=work)
            gcpu = _children_cpu_s() - c
            g_rate = g.n_cells / g.seconds
            rows.append(("GRASS r.horizon (wall)", f"{g.n_cells} cells x 360 directions in {g.seconds:.1f} s -> "
                                                   f"**{g_rate:,.1f} positions/s**"))
            g_cpu_rate = g.n_cells / max(gcpu, 1e-9)      # GRASS runs on one core; CPU includes its import
            rows.append(("speed ratio skyloc / GRASS", f"**{rate_wall / g_rate:,.0f} x** wall (same run); "
                                                       f"{n / cpu / g_cpu_rate:,.0f} x per CPU-second "
                                                       f"(GRASS {g_cpu_rate:,.1f} positions per CPU-s)"))
            spec0 = RenderSpec(camera_height_m=0.0, n_azimuth=360, body_radius_m=job.spec.body_radius_m)
            el, _ = raymarch.render_positions(terrain, pts[:, 0], pts[:, 1], spec0)
            med = {s: float(np.median(np.abs(np.roll(g.elevation_deg, s, axis=1) - el))) for s in (-1, 0, 1)}
            p90 = float(np.percentile(np.abs(g.elevation_deg - el), 90))
            rows.append(("skyloc vs GRASS at ground level", f"median abs. diff. {med[0]:.3f} deg, p90 {p90:.2f} deg "
                                                            f"(label shift -1/+1: {med[-1]:.3f}/{med[1]:.3f}); "
                                                            f"GRASS child CPU {gcpu:.0f} s"))
        else:
            rows.append(("GRASS r.horizon", "skipped (not installed or --no-grass)"))

        # --- 7 x 7 km at 5 m
        big = GridSpec.from_center(CENTER, 7000.0, step_m, crs_wkt=grid.crs_wkt)
        rows.append(("7 x 7 km at 5 m: extrapolated time", f"{big.n_positions:,} positions / {rate_wall:,.0f} per s = "
                                                          f"{big.n_positions / rate_wall / 3600:.2f} h wall "
                                                          f"({big.n_positions / rate_cpu2 / 3600:.2f} h on 2 free cores)"))
        if not args.no_7x7:
            rows.append(("7 x 7 km at 5 m: measured size", _write_7x7(db, big, work / "big.zarr")))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    load1 = os.getloadavg()
    print(f"\n### Skyline-database renderer benchmark — {dt.datetime.now(dt.timezone.utc):%Y-%m-%d %H:%M} UTC\n")
    print("`python -m benchmarks.bench_db_render" + (" --quick" if args.quick else "") + "` "
          f"(load average {load0[0]:.1f} at start, {load1[0]:.1f} at end, 2 cores shared)\n")
    print("| what | result |\n|---|---|")
    for k, v in rows:
        print(f"| {k} | {v} |")


def _write_7x7(db: SkyDB, big: GridSpec, path: Path) -> str:
    """Write a full 7 x 7 km store with the rendered 64 x 64 tiles repeated; return its measured size."""
    src_tiles = [t for t in db.tiles if t.nrows == db.meta.tile_size and t.ncols == db.meta.tile_size]
    src = [(db.read_tile(t), db.read_distance(t)) for t in src_tiles]
    meta = SkyDBMeta(grid=big, camera_height_m=db.meta.camera_height_m, n_azimuth=db.meta.n_azimuth,
                     body=db.meta.body, body_radius_m=db.meta.body_radius_m, renderer=db.meta.renderer,
                     renderer_version=db.meta.renderer_version, dem_sha256=db.meta.dem_sha256,
                     tile_size=db.meta.tile_size, has_distance=True)
    w = SkyDBWriter.create(path, meta)
    t0 = time.time()
    for k, tile in enumerate(w.tiles):
        el, dist = src[k % len(src)]
        w.write_tile(tile, el[:tile.nrows, :tile.ncols], dist[:tile.nrows, :tile.ncols])
    w.finalize()
    total = sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
    elev = sum(f.stat().st_size for f in (path / "elevation").rglob("*") if f.is_file())
    raw = big.n_positions * db.meta.n_azimuth * 2
    return (f"{total / 1e9:.2f} GB with distances, **{elev / 1e9:.2f} GB elevations only** "
            f"(int16 raw {raw / 1e9:.2f} GB; {len(w.tiles)} tiles written in {time.time() - t0:.0f} s; "
            f"content: the 1 km grid's tiles repeated) -> {'fits' if elev < 2e9 else 'does NOT fit'} in 2 GB")


if __name__ == "__main__":
    main()
