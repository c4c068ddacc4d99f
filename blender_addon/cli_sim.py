"""`skyloc sim panorama`: a binary or dressed equirectangular panorama at a rover pose.

The ``sim`` group is created here; H5b's ``cli_sim_acquire`` adds ``acquire`` and ``dataset``.
"""
from __future__ import annotations

import logging
from pathlib import Path

import click

from blender_addon.cli_options import at_option, body_option, crs_option, dem_option, site
from blender_addon.core.band import checked_band
from board.errors import InvalidInputError

log = logging.getLogger(__name__)


@click.group("sim")
def sim_group() -> None:
    """Simulator (Blender, headless): panoramas, NavCam acquisitions, test sets."""


@sim_group.command("panorama")
@dem_option()
@at_option()
@crs_option()
@click.option("--height", "height_m", type=float, default=2.0, show_default=True,
              help="Camera (mast) height above the ground, metres.")
@click.option("--heading", "heading_deg", type=float, default=0.0, show_default=True,
              help="Heading, degrees clockwise from grid north.")
@click.option("--pitch", "pitch_deg", type=float, default=0.0, show_default=True, help="Pitch, degrees (nose up +).")
@click.option("--roll", "roll_deg", type=float, default=0.0, show_default=True,
              help="Roll, degrees (right side down +).")
@click.option("--width", type=int, default=2048, show_default=True,
              help="Panorama width, pixels (height = width/2 for the whole sphere).")
@click.option("--band", default="-90,90", show_default=True,
              help="BOTTOM,TOP elevations (degrees, mast frame) the panorama covers, e.g. -45,45: only the rows "
                   "where the skyline can be are rendered (square pixels; the bottom widens to a whole row).")
@click.option("--binary", is_flag=True, help="Terrain white, sky black (the report's noise level 1).")
@click.option("--preset", type=click.Choice(["clean", "realistic", "distorted"]), default=None,
              help="Dressed look instead of --binary.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of rocks, textures and noise.")
@click.option("--samples", type=int, default=16, show_default=True,
              help="Cycles samples per pixel for dressed looks (at least; noisy pixels such as the skyline's "
                   "get up to 4 x more).")
@click.option("--radius", "radius_m", type=float, default=None,
              help="Keep terrain up to this distance (m) from the rover (default: the whole DEM).")
@body_option()
@click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True, help="Output panorama folder.")
def panorama_cmd(dem: str, at: str, crs: str | None, height_m: float, heading_deg: float, pitch_deg: float,
                 roll_deg: float, width: int, band: str, binary: bool, preset: str | None, seed: int, samples: int,
                 radius_m: float | None, body: str | None, out_dir: str) -> None:
    """Render an equirectangular panorama at a pose and write it as a panorama folder."""
    from tqdm import tqdm

    from blender_addon.terrain.multires import build_multires

    if binary and preset:
        raise InvalidInputError("--binary and --preset exclude each other: pick one")
    if not binary and not preset:
        raise InvalidInputError("choose --binary or --preset clean|realistic|distorted")
    if height_m < 0:
        raise InvalidInputError(f"--height must be >= 0 m, got {height_m}")
    band_deg = _parse_band(band)
    with tqdm(total=3, desc="sim panorama", unit="step", disable=None) as bar:
        c = site(dem, at, "--at", crs=crs, body=body)
        path, (x, y) = c.dem_path, c.xy_m
        terrain = build_multires(path, (x, y), grid_half_m=max(50.0, 4 * height_m), max_radius_m=radius_m, body=body)
        bar.update(1)
        from blender_addon.core.acquire import Pose
        from blender_addon.scene import build_terrain, reset_scene
        from blender_addon.scene.panorama import make_panorama, panorama_geometry

        reset_scene()
        build_terrain(terrain)
        bar.update(1)
        pose = Pose(x, y, heading_deg, pitch_deg, roll_deg)
        out = make_panorama(terrain, pose, out_dir, height_m=height_m, width=width, binary=binary, preset=preset,
                            seed=seed, samples=samples, dem=str(dem), build=False, elevation_range_deg=band_deg)
        bar.update(1)
    g = panorama_geometry(width, binary=binary, elevation_range_deg=band_deg)   # what was written, not re-read
    click.echo(f"wrote {Path(out)}: {g.width} x {g.height} {'binary' if binary else preset} panorama at "
               f"{c.describe()}, heading {heading_deg:g}, pitch {pitch_deg:g}, roll {roll_deg:g} deg")


def _parse_band(text: str) -> tuple[float, float]:
    """``--band BOTTOM,TOP`` -> (bottom, top) degrees, checked."""
    return checked_band(str(text).split(","), what="--band", example="--band=-45,45")


def register(group: click.Group) -> None:
    """Add the ``sim`` group (with ``panorama``) to the root CLI."""
    if "sim" in group.commands:
        group.commands["sim"].add_command(panorama_cmd)
    else:
        group.add_command(sim_group)
