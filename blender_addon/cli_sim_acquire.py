"""`skyloc sim acquire` (one NavCam acquisition) and `skyloc sim dataset` (test sets from a scene file).

Both are added to the ``sim`` group that :mod:`blender_addon.cli_sim` creates (or created here
when that module is absent).
"""
from __future__ import annotations

import logging
from pathlib import Path

import click

from blender_addon.cli_options import at_option, body_option, crs_option, dem_option, site
from blender_addon.core.cameras import PRESETS as CAMERAS
from blender_addon.core.degrade import PRESETS as LOOKS
from board.errors import InvalidInputError
from board.progress import progress_bar

log = logging.getLogger(__name__)


@click.command("acquire")
@dem_option()
@at_option()
@crs_option()
@click.option("--heading", "heading_deg", type=float, required=True, help="Heading, degrees clockwise from grid north.")
@click.option("--pitch", "pitch_deg", type=float, default=0.0, show_default=True, help="Pitch, degrees (nose up +).")
@click.option("--roll", "roll_deg", type=float, default=0.0, show_default=True,
              help="Roll, degrees (right side down +).")
@click.option("--camera", type=click.Choice(sorted(CAMERAS)), default="exomars",
              show_default=True, help="NavCam preset (report annex).")
@click.option("--width", type=int, default=None, help="Render the preset at this width (same field of view).")
@click.option("--frames", type=int, default=13, show_default=True, help="Number of frames of the pan-tilt plan.")
@click.option("--arc", "arc_deg", type=float, default=360.0, show_default=True,
              help="Azimuth arc covered, degrees (360 = full panorama, else centred on the heading).")
@click.option("--tilt", "tilt_deg", type=float, default=0.0, show_default=True, help="Tilt of every frame, degrees.")
@click.option("--preset", type=click.Choice(list(LOOKS)), default="realistic", show_default=True,
              help="Look and degradations (the report's noise levels: binary, realistic, distorted; "
                   "realistic-<body> for the Earth, the Moon, Europa; 'realistic' is the Mars look).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of rocks, textures, render and noise.")
@click.option("--samples", type=int, default=16, show_default=True,
              help="Cycles samples per pixel (at least; noisy pixels such as the skyline's get up to 4 x more).")
@click.option("--radius", "radius_m", type=float, default=None,
              help="Keep terrain up to this distance (m) beyond the site (default: the whole DEM).")
@body_option()
@click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True, help="Output acquisition folder.")
def acquire_cmd(dem: str, at: str, crs: str | None, heading_deg: float, pitch_deg: float, roll_deg: float,
                camera: str, width: int | None, frames: int, arc_deg: float, tilt_deg: float, preset: str,
                seed: int, samples: int, radius_m: float | None, body: str | None, out_dir: str) -> None:
    """Render a simulated NavCam acquisition (frames + acquisition.json with ground truth)."""
    from blender_addon.core.acquire import AcquisitionJob, Pose, wrap_heading
    from blender_addon.core.cameras import get_preset
    from blender_addon.core.degrade import check_look_body, get_degradation
    from blender_addon.core.plans import plan_frames
    from blender_addon.sim import Simulator

    if samples < 1:
        raise InvalidInputError(f"--samples must be >= 1, got {samples}")
    cam = get_preset(camera, width=width)
    plan = plan_frames(frames, arc_deg, cam.hfov_deg, tilt_deg=tilt_deg)
    deg = get_degradation(preset)
    c = site(dem, at, "--at", crs=crs, body=body)
    x, y = c.xy_m
    rock_r = deg.rocks.radius_m if deg.rocks.density_per_m2 > 0 else 0.0
    with progress_bar("sim acquire", unit="frame") as progress:
        progress(0, plan.n_frames, "building the terrain and the scene")
        sim = Simulator(c.dem_path, (x, y), grid_half_m=max(50.0, rock_r + 20.0), max_radius_m=radius_m, body=body)
        sim.dem_spec = str(dem)
        check_look_body(deg, sim.terrain.body.name)
        job = AcquisitionJob(Pose(x, y, wrap_heading(heading_deg), pitch_deg, roll_deg), cam, plan, deg, seed=seed,
                             samples=samples)
        progress(0, plan.n_frames, "dressing the scene, rendering frame 1")
        out = sim.acquire(job, out_dir, progress=progress)
    click.echo(f"wrote {Path(out)}: {plan.n_frames} {cam.width}x{cam.height} {preset} frames ({cam.name}) at "
               f"{c.describe()}, heading {heading_deg:g}, pitch {pitch_deg:g}, roll {roll_deg:g} deg")


@click.command("dataset")
@click.argument("scene_toml", type=click.Path(dir_okay=False))
@click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True, help="Output dataset folder.")
@click.option("--set", "sets", multiple=True, help="Only this set (repeatable), e.g. --set REF --set CLUT.")
@click.option("--no-resume", is_flag=True, help="Re-render acquisitions that are already there.")
@click.option("--check", is_flag=True, help="Only validate the scene file and list the sets.")
@click.option("--limit", type=int, default=None, help="At most this many acquisitions per set (preview).")
@click.option("--width", type=int, default=None, help="Render every camera at this width (preview).")
@click.option("--samples", type=int, default=None, help="Cycles samples per pixel instead of the scene's.")
def dataset_cmd(scene_toml: str, out_dir: str, sets: tuple[str, ...], no_resume: bool, check: bool,
                limit: int | None, width: int | None, samples: int | None) -> None:
    """Render the test sets of a scene file (e.g. scenes/robustness.toml) with their manifests."""
    from blender_addon.core.scene_spec import load_scene

    scene = load_scene(scene_toml)
    if check:
        for s in scene.sets:
            click.echo(f"{s.name:6s} {s.count:4d} x {s.camera}/{s.plan} at {s.site}: {', '.join(s.degradations)}"
                       f"  {s.description}")
        return
    from blender_addon.sim import generate_dataset

    with progress_bar("sim dataset", unit="acq") as progress:
        path = generate_dataset(scene_toml, out_dir, progress=progress, sets=list(sets) or None,
                                resume=not no_resume, limit=limit, width=width, samples=samples)
    click.echo(f"wrote {path}")


def register(group: click.Group) -> None:
    """Add ``acquire`` and ``dataset`` to the ``sim`` group (created if :mod:`cli_sim` did not)."""
    sim = group.commands.get("sim")
    if sim is None:
        @group.group("sim")
        def sim() -> None:
            """Simulator (Blender, headless): panoramas, NavCam acquisitions, test sets."""
    sim.add_command(acquire_cmd)
    sim.add_command(dataset_cmd)
