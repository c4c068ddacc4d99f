"""`skyloc db ...`: render a skyline database, describe one, compute one horizon from a DEM.

Coordinates given on the command line (``--center``, ``--at``) are in the DEM's own CRS (lon,lat
for a DEM in degrees) unless ``--crs`` names another; everything written is in the DEM's metric
working CRS, whose name and WKT the outputs state.
"""
from __future__ import annotations

import json
import logging
import math

import click

from blender_addon.cli_options import at_option, dem_options, site
from blender_addon.terrain.crs import crs_name
from board.errors import InvalidInputError
from board.skydb import AZIMUTH_SUBSAMPLES, ELEVATION_SCALE_DEG, MAX_AZIMUTH_SUBSAMPLES, SUPPORTED_ELEVATION_SCALES_DEG

log = logging.getLogger(__name__)


def _spec(height: float, azimuths: int, refraction: float, max_distance: float | None, subsamples: int = 1):
    from render_service.renderers.base import RenderSpec  # noqa: PLC0415

    if not (math.isfinite(height) and height >= 0):
        raise InvalidInputError(f"--height must be a camera height >= 0 m, got {height}")
    if azimuths <= 0:
        raise InvalidInputError(f"--azimuths must be a positive number of samples, got {azimuths}")
    if not (0.0 <= refraction < 1.0):
        raise InvalidInputError(f"--refraction must be in [0, 1) (0.13 is typical on Earth), got {refraction}")
    if max_distance is not None and not max_distance > 0:
        raise InvalidInputError(f"--max-distance must be > 0 m, got {max_distance}")
    if not 1 <= subsamples <= MAX_AZIMUTH_SUBSAMPLES:
        raise InvalidInputError(f"--azimuth-subsamples must be 1 (point samples) to {MAX_AZIMUTH_SUBSAMPLES} rays "
                                f"per sample, "
                                f"got {subsamples}")
    return RenderSpec(camera_height_m=height, n_azimuth=azimuths, refraction_k=refraction,
                      max_distance_m=max_distance, azimuth_subsamples=subsamples)


@click.group("db")
def db_group() -> None:
    """Skyline databases: render one from a DEM, describe one, compute a single horizon."""


_common_render = [
    dem_options(),
    click.option("--height", "height", type=float, default=2.0, show_default=True,
                 help="Camera height above ground (m)."),
    click.option("--azimuths", type=int, default=360, show_default=True, help="Azimuth samples (360 -> 1 degree)."),
    click.option("--refraction", type=float, default=0.0, show_default=True, help="Refraction coefficient k."),
    click.option("--max-distance", type=float, default=None, help="Ignore terrain farther than this (m)."),
]


def _with(options):
    def deco(f):
        for opt in reversed(options):
            f = opt(f)
        return f
    return deco


@db_group.command("render")
@_with(_common_render)
@click.option("--center", required=True, help="Grid centre X,Y (DEM's CRS, lon,lat in degrees, unless --crs).")
@click.option("--size", "size_m", type=float, default=1000.0, show_default=True, help="Grid side (m).")
@click.option("--step", "step_m", type=float, default=5.0, show_default=True, help="Grid spacing (m).")
@click.option("--renderer", type=click.Choice(["raymarch", "blender"]), default="raymarch", show_default=True)
@click.option("--tile", "tile", type=int, default=64, show_default=True, help="Tile side (positions).")
@click.option("--terrain-dir", type=click.Path(file_okay=False), default=None,
              help="Prepared multi-resolution terrain (skyloc dem prepare); built here when absent.")
@click.option("--out", required=True, type=click.Path(), help="Output Zarr store (resumed if it exists).")
@click.option("--elevation-unit", "elevation_unit", type=float, default=ELEVATION_SCALE_DEG, show_default=True,
              help="The stored elevations' int16 unit (degrees): "
                   f"{', '.join(str(s) for s in SUPPORTED_ELEVATION_SCALES_DEG)}.")
@click.option("--azimuth-subsamples", "subsamples", type=int, default=AZIMUTH_SUBSAMPLES, show_default=True,
              help="Rays averaged per sample across its azimuth step, as an extracted skyline's samples average "
                   "the horizon over the step (1: point samples, the only kind before; docs/renderer.md).")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
def render_cmd(dem, body, assume_metric, crs, height, azimuths, refraction, max_distance, center, size_m, step_m,
               renderer, tile, terrain_dir, out, elevation_unit, subsamples, no_progress) -> None:
    """Render (or resume) the skyline database of a square grid of positions."""
    from render_service.dbrender import render_database  # noqa: PLC0415

    if not (math.isfinite(step_m) and step_m > 0):
        raise InvalidInputError(f"--step must be a positive number of metres, got {step_m}")
    if not (math.isfinite(size_m) and size_m >= 0):
        raise InvalidInputError(f"--size must be >= 0 m, got {size_m}")
    if tile <= 0:
        raise InvalidInputError(f"--tile must be a positive number of positions, got {tile}")
    spec = _spec(height, azimuths, refraction, max_distance, subsamples)
    c = site(dem, center, "--center", crs=crs, body=body, assume_metric=assume_metric)
    db = render_database(c.dem_path, center_xy=c.xy_m, size_m=size_m, step_m=step_m, spec=spec, out=out,
                         renderer=renderer, tile_size=tile, terrain_dir=terrain_dir, progress=not no_progress,
                         body=body, assume_metric=assume_metric, elevation_unit_deg=elevation_unit)
    s = db.summary()
    click.echo(f"wrote {out}: {s['grid']['nx']} x {s['grid']['ny']} positions x {s['n_azimuth']} azimuths, "
               f"{s['size_bytes'] / 1e6:.1f} MB, renderer {s['renderer']} v{s['renderer_version']}; centre "
               f"{c.describe()}; positions (skyloc locate's x, y) are metres in {crs_name(s['crs_wkt'])!r}")


@db_group.command("info")
@click.argument("store", type=click.Path())
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def info_cmd(store: str, as_json: bool) -> None:
    """Describe a skyline database (grid, CRS, sampling, renderer, progress, size)."""
    from board.skydb import SkyDB  # noqa: PLC0415

    s = SkyDB.open(store).summary()
    s["crs_name"] = crs_name(s["crs_wkt"])
    if as_json:
        click.echo(json.dumps(s, indent=2))
        return
    g = s["grid"]
    b = g["bounds"]
    click.echo(f"{s['path']} ({s['format']} v{s['version']}, {'complete' if s['complete'] else 'INCOMPLETE'})")
    click.echo(f"  grid        {g['nx']} x {g['ny']} positions every {g['step_m']:g} m "
               f"(x {b[0]:.2f}..{b[2]:.2f}, y {b[1]:.2f}..{b[3]:.2f} m)")
    click.echo(f"  CRS         {s['crs_name']}")
    click.echo(f"  camera      {s['camera_height_m']:g} m above ground")
    click.echo(f"  azimuths    {s['n_azimuth']} from {s['azimuth_start_deg']:g} deg every "
               f"{s['azimuth_step_deg']:g} deg (clockwise from grid north)")
    click.echo(f"  body        {s['body']} (R = {s['body_radius_m']:.0f} m), refraction k = {s['refraction_k']:g}")
    click.echo(f"  elevations  int16 in units of {s['elevation_scale_deg']:g} deg; "
               + ("point samples" if s["azimuth_subsamples"] == 1 else
                  f"each the mean of {s['azimuth_subsamples']} rays across its step"))
    click.echo("  per node    " + ", ".join(
        [("horizon distances (10 m units)" if s["has_distance"] else "no horizon distances"),
         ("ground heights (the eye's steps between nodes)" if s["has_ground"] else
          "no ground heights (eye steps estimated from the skylines; render again to store them)")]))
    click.echo(f"  renderer    {s['renderer']} v{s['renderer_version']}")
    click.echo(f"  tiles       {s['tiles_done']} of {s['tiles_total']} done ({s['tile_size']} x {s['tile_size']})")
    click.echo(f"  DEM sha256  {s['dem_sha256']}")
    click.echo(f"  created     {s['created_utc']}")
    click.echo(f"  size        {s['size_bytes'] / 1e6:.2f} MB")


@db_group.command("horizon")
@_with(_common_render)
@at_option()
@click.option("--json", "as_json", is_flag=True, help="Print JSON.")
def horizon_cmd(dem, body, assume_metric, crs, height, azimuths, refraction, max_distance, at, as_json) -> None:
    """Horizon elevation by azimuth at one position, straight from the DEM (ray-marcher)."""
    from render_service.dbrender import horizon_from_dem  # noqa: PLC0415

    spec = _spec(height, azimuths, refraction, max_distance)
    c = site(dem, at, "--at", crs=crs, body=body, assume_metric=assume_metric)
    given, (x, y) = c.given, c.xy_m
    az, el, dist, crs_wkt, used = horizon_from_dem(c.dem_path, x=x, y=y, spec=spec, body=body,
                                                   assume_metric=assume_metric)
    doc = {
        "azimuth_deg": [round(float(a), 6) for a in az],
        "elevation_deg": [round(float(e), 4) for e in el],
        "distance_m": [None if not math.isfinite(d) else round(float(d), 2) for d in dist],
        "x": x, "y": y, "crs": crs_wkt, "crs_name": crs_name(crs_wkt),
        "input_xy": list(given), "input_crs": crs or "the DEM's own CRS",
        "camera_height_m": height, "body_radius_m": used.body_radius_m, "refraction_k": refraction,
        "azimuth_convention": "degrees clockwise from grid north; elevation in degrees above the eye's horizontal",
    }
    if as_json:
        click.echo(json.dumps(doc))
        return
    click.echo(f"horizon at ({x:.2f}, {y:.2f}) m in CRS {doc['crs_name']!r}, eye {height:g} m above ground")
    click.echo("azimuth_deg elevation_deg distance_m")
    for a, e, d in zip(doc["azimuth_deg"], doc["elevation_deg"], doc["distance_m"]):
        click.echo(f"{a:10.3f} {e:9.3f} {d if d is not None else 'nan':>10}")


def register(group: click.Group) -> None:
    """Add the `db` group to the root `skyloc` group."""
    group.add_command(db_group)
