"""`skyloc dem ...`: synthesise procedural DEMs, describe DEMs, prepare multi-resolution terrains."""
from __future__ import annotations

import json
import logging
from pathlib import Path

import click

from blender_addon.cli_options import assume_metric_option, body_option, crs_option, dem_option, site
from blender_addon.terrain.crs import crs_name
from board.errors import InvalidInputError

log = logging.getLogger(__name__)
#: = blender_addon.terrain.multires.CELLS_PER_STEP (not imported here: that module loads GDAL at start-up;
#: tests/blender_addon/test_multires.py checks the two agree).
CLI_CELLS_PER_STEP = 8


@click.group("dem")
def dem_group() -> None:
    """DEMs: synthesise procedural terrain, inspect a DEM, prepare a multi-resolution terrain."""


@dem_group.command("synth")
@click.option("--preset", type=click.Choice(["mars", "europa", "moon"]), default="mars", show_default=True,
              help="Terrain type.")
@click.option("--size", "size_m", type=float, default=20000.0, show_default=True, help="Side length (m).")
@click.option("--res", "res_m", type=float, default=5.0, show_default=True, help="Cell size (m).")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (same seed, same file).")
@click.option("--out", "out_path", type=click.Path(dir_okay=False), required=True, help="Output GeoTIFF.")
@click.option("--preview", type=click.Path(dir_okay=False), default=None, help="Also write a hillshade PNG here.")
def synth_cmd(preset: str, size_m: float, res_m: float, seed: int, out_path: str, preview: str | None) -> None:
    """Synthesise a procedural DEM (GeoTIFF on the body's sphere, centred on 0,0)."""
    from blender_addon.terrain.dem import dem_info
    from blender_addon.terrain.procedural import synthesize

    out = synthesize(preset, size_m=size_m, res_m=res_m, seed=seed, out_path=out_path)
    info = dem_info(out)
    b = info.bounds
    click.echo(
        f"wrote {out}: {preset} seed {seed}, {info.size[0]} x {info.size[1]} cells at {info.cell_m:g} m, "
        f"x {b[0]:g}..{b[2]:g}, y {b[1]:g}..{b[3]:g} m in CRS {crs_name(info.crs_wkt)!r} "
        f"(body {info.body.name}, R = {info.body.radius_m:.0f} m)"
    )
    if preview:
        from blender_addon.terrain.preview import plot_dem

        click.echo(f"preview: {plot_dem(out, preview)}")


@dem_group.command("info")
@click.argument("dem")
@body_option()
@assume_metric_option()
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def info_cmd(dem: str, body: str | None, assume_metric: bool, as_json: bool) -> None:
    """Describe a DEM (file or procedural:PRESET:SEED) in its metric working CRS, without reading it whole."""
    from blender_addon.terrain.dem import dem_info, resolve_dem

    info = dem_info(resolve_dem(dem), body=body, assume_metric=assume_metric)
    src_bounds, src_name = _source_bounds(info)
    if as_json:
        d = info.to_json_dict()
        d["source_bounds"] = list(src_bounds)
        d["source_crs_name"] = src_name
        click.echo(json.dumps(d, indent=2))
        return
    b = info.bounds
    click.echo(f"{info.path} ({info.driver}, {info.dtype})")
    click.echo(f"  body        {info.body.name} (R = {info.body.radius_m:.0f} m)")
    click.echo(f"  source CRS  {'geographic (degrees), reprojected' if info.is_geographic else 'projected, metres'}")
    click.echo(f"  working CRS {crs_name(info.crs_wkt)} (metres: every output's x, y)")
    click.echo(f"  grid        {info.size[0]} x {info.size[1]} cells of {info.cell_m:g} m")
    sb = src_bounds
    if info.is_geographic:
        click.echo(f"  bounds      lon {sb[0]:.6f}..{sb[2]:.6f}, lat {sb[1]:.6f}..{sb[3]:.6f} deg in {src_name} "
                   "(what --at / --center expect)")
        click.echo(f"  working     x {b[0]:.2f}..{b[2]:.2f}, y {b[1]:.2f}..{b[3]:.2f} m (outputs; --crs to give these)")
    else:
        click.echo(f"  bounds      x {b[0]:.2f}..{b[2]:.2f}, y {b[1]:.2f}..{b[3]:.2f} m in {src_name or 'the DEM CRS'} "
                   "(what --at / --center expect, and the outputs' CRS)")
    click.echo(f"  nodata      ~{info.nodata_fraction:.2%}")
    click.echo(f"  sha256      {info.sha256}")


@dem_group.command("prepare")
@dem_option()
@click.option("--center", required=True,
              help="Site X,Y in the DEM's own CRS (lon,lat for a DEM in degrees) unless --crs.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True, help="Output folder.")
@crs_option()
@click.option("--grid-size", "grid_size", type=float, default=1000.0, show_default=True,
              help="Side of the square search grid around the centre (m).")
@click.option("--azimuth-step", type=float, default=1.0, show_default=True, help="Skyline azimuth resolution (deg).")
@click.option("--max-radius", type=float, default=None,
              help="Keep terrain up to this far beyond the grid (m); default: the DEM's edge.")
@click.option("--cells-per-step", type=click.IntRange(min=1), default=CLI_CELLS_PER_STEP, show_default=True,
              help="A coarse level starts where one of its cells subtends 1/N azimuth step (1: smaller files, "
                   "far ridges lifted by up to a cell).")
@body_option()
@assume_metric_option()
def prepare_cmd(dem: str, center: str, out_dir: str, crs: str | None, grid_size: float, azimuth_step: float,
                max_radius: float | None, cells_per_step: int, body: str | None, assume_metric: bool) -> None:
    """Build the multi-resolution terrain (nested max-downsampled GeoTIFF levels + VRT + terrain.json)."""
    from blender_addon.terrain.multires import build_multires

    if grid_size < 0:
        raise InvalidInputError(f"--grid-size must be >= 0 m, got {grid_size}")
    c = site(dem, center, "--center", crs=crs, body=body, assume_metric=assume_metric)
    path = c.dem_path
    terrain = build_multires(
        path, c.xy_m, grid_half_m=grid_size / 2.0, azimuth_step_deg=azimuth_step, out_dir=out_dir, body=body,
        max_radius_m=max_radius, assume_metric=assume_metric, progress=True, cells_per_step=cells_per_step,
    )
    from blender_addon.terrain.preview import plot_multires

    png = plot_multires(terrain, Path(out_dir) / "levels.png")
    click.echo(f"terrain for {path} around {c.describe()} (body {terrain.body.name}) -> {out_dir}")
    click.echo("| level | cell (m) | cells | x range (m) | y range (m) | used beyond (m) |")
    click.echo("|---|---|---|---|---|---|")
    for k, (lvl, inner) in enumerate(zip(terrain.levels, terrain.meta["inner_distance_m"])):
        b = lvl.bounds()
        click.echo(f"| {k} | {lvl.cell_m:g} | {lvl.array.shape[1]} x {lvl.array.shape[0]} | "
                   f"{b[0]:.1f}..{b[2]:.1f} | {b[1]:.1f}..{b[3]:.1f} | {inner:.0f} |")
    click.echo(f"levels picture: {png}")


def _source_bounds(info) -> tuple[tuple[float, float, float, float], str]:
    """Bounds of the DEM file in its own CRS (lon/lat degrees for a DEM in degrees), and that CRS's name."""
    from osgeo import gdal  # noqa: PLC0415

    ds = gdal.Open(str(info.path))
    gt, nx, ny = ds.GetGeoTransform(), ds.RasterXSize, ds.RasterYSize
    xs = [gt[0], gt[0] + nx * gt[1] + ny * gt[2]]
    ys = [gt[3], gt[3] + nx * gt[4] + ny * gt[5]]
    return (min(xs), min(ys), max(xs), max(ys)), crs_name(ds.GetProjectionRef() or "")


def register(group: click.Group) -> None:
    """Add the `dem` group to the root `skyloc` group."""
    group.add_command(dem_group)
