"""`skyloc sim descent`: one trial of a lander's descent over Europa-like terrain (a descent-sequence folder).

Added to the ``sim`` group of :mod:`blender_addon.cli_sim` (created here when absent).  The fast
bpy-free renderer of :mod:`blender_addon.descent` does the work.
"""
from __future__ import annotations

import logging
from pathlib import Path

import click

from board.errors import InvalidInputError

log = logging.getLogger(__name__)


def parse_modes(text: str) -> tuple[str, ...]:
    """'visible,thermal' -> ('visible', 'thermal'); click.BadParameter on anything else."""
    modes = tuple(m.strip().lower() for m in text.split(",") if m.strip())
    bad = [m for m in modes if m not in ("visible", "thermal")]
    if bad or not modes:
        raise click.BadParameter(f"{text!r}: give visible, thermal or visible,thermal", param_hint="--modes")
    return tuple(m for m in ("visible", "thermal") if m in modes)


def descent_options(f):
    """Options shared by `sim descent` and `sim descent-set` (appearance, sensors, cameras, terrain grid)."""
    opts = [
        click.option("--terrain", default="procedural:europa:1", show_default=True,
                     help="procedural:europa:SEED or a DEM file (metric CRS)."),
        click.option("--frames", type=int, default=None, help="Only the first N frames (default: the whole "
                     "trajectory at --frame-rate)."),
        click.option("--modes", default="visible,thermal", show_default=True, help="Cameras to render."),
        click.option("--thermal-model", type=click.Choice(["tm", "conduction"]), default="tm", show_default=True,
                     help="tm: the memorandum's instantaneous balance + smoothing; conduction: 1-D heat conduction "
                     "over Europa's day."),
        click.option("--brdf", type=click.Choice(["tm", "hapke"]), default="tm", show_default=True,
                     help="tm: the memorandum's eq. 9; hapke: Hapke photometry with cast shadows."),
        click.option("--sensor", type=click.Choice(["ideal", "noisy"]), default="ideal", show_default=True,
                     help="Camera sensor models (noisy: photon/read noise; Planck band, NETD, fixed pattern)."),
        click.option("--thermal-inertia", type=float, default=70.0, show_default=True,
                     help="J m-2 K-1 s-1/2, for --thermal-model conduction (Europa: 40-140)."),
        click.option("--sun", default="90,30", show_default=True, help="Sun azimuth,elevation (degrees)."),
        click.option("--seed", type=int, default=0, show_default=True, help="Base seed of noise and actuation."),
        click.option("--width", type=int, default=640, show_default=True, help="Image width, pixels (both cameras)."),
        click.option("--height", type=int, default=480, show_default=True, help="Image height, pixels."),
        click.option("--hfov", "hfov_deg", type=float, default=50.0, show_default=True,
                     help="Horizontal field of view, degrees."),
        click.option("--frame-rate", "frame_rate_hz", type=float, default=1.0, show_default=True,
                     help="Frames per second (the memorandum: 1)."),
        click.option("--duration", "duration_s", type=float, default=200.0, show_default=True,
                     help="Trajectory duration, seconds."),
        click.option("--terrain-res", "terrain_res_m", type=float, default=0.25, show_default=True,
                     help="Grid spacing of the procedural terrain, metres."),
        click.option("--terrain-size", "terrain_size_m", type=float, default=400.0, show_default=True,
                     help="Side of the procedural terrain, metres (the memorandum: 400)."),
    ]
    for o in reversed(opts):
        f = o(f)
    return f


def make_config(*, terrain: str, trajectory: int, trial: int, frames, modes: str, thermal_model: str, brdf: str,
                sensor: str, thermal_inertia: float, sun: str, seed: int, width: int, height: int, hfov_deg: float,
                frame_rate_hz: float, duration_s: float, terrain_res_m: float, terrain_size_m: float):
    """Build a DescentConfig from the CLI options (validating them)."""
    from blender_addon.descent.lights import default_lights
    from blender_addon.descent.render import AppearanceOptions
    from blender_addon.descent.sensors import ThermalSensor, VisibleSensor
    from blender_addon.descent.simulate import DescentConfig

    try:
        az, el = (float(v) for v in sun.split(","))
    except ValueError:
        raise click.BadParameter(f"{sun!r}: give AZIMUTH,ELEVATION in degrees, e.g. 90,30", param_hint="--sun") from None
    if not (0.0 < el <= 90.0):
        raise InvalidInputError(f"--sun elevation {el} deg: the descent is in daylight, use (0, 90]")
    if width < 8 or height < 8:
        raise InvalidInputError(f"--width/--height {width}x{height}: at least 8 x 8 pixels")
    return DescentConfig(
        terrain=terrain, trajectory=trajectory, trial=trial, seed=seed, frames=frames, modes=parse_modes(modes),
        frame_rate_hz=frame_rate_hz, duration_s=duration_s,
        appearance=AppearanceOptions(brdf=brdf, thermal=thermal_model, thermal_inertia=thermal_inertia),
        visible_sensor=VisibleSensor(mode=sensor), thermal_sensor=ThermalSensor(mode=sensor),
        lights=tuple(default_lights(sun_azimuth_deg=az, sun_elevation_deg=el)), width=width, height=height,
        hfov_deg=hfov_deg, terrain_res_m=terrain_res_m, terrain_size_m=terrain_size_m)


@click.command("descent")
@click.option("--trajectory", type=click.IntRange(1, 10), required=True, help="Trajectory 1..10.")
@click.option("--trial", type=click.IntRange(0, None), default=0, show_default=True, help="Trial number.")
@descent_options
@click.option("--overwrite", is_flag=True, help="Replace an existing output folder.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True, help="Output sequence folder.")
def descent_cmd(trajectory: int, trial: int, overwrite: bool, out_dir: str, **kw) -> None:
    """Simulate one descent trial: co-registered visible/thermal frames, IMU, altimeter and ground truth."""
    from blender_addon.descent.simulate import simulate_trial

    config = make_config(trajectory=trajectory, trial=trial, **kw)
    path = simulate_trial(config, Path(out_dir), overwrite=overwrite)
    click.echo(f"wrote {path}: trajectory {trajectory} trial {trial}, {config.n_frames} frame(s) "
               f"({','.join(config.modes)}) {config.width}x{config.height}, brdf {config.appearance.brdf}, "
               f"thermal {config.appearance.thermal}")


def register(group: click.Group) -> None:
    """Add ``descent`` to the ``sim`` group (created if :mod:`cli_sim` did not)."""
    sim = group.commands.get("sim")
    if sim is None:
        @group.group("sim")
        def sim() -> None:
            """Simulator: panoramas, NavCam acquisitions, test sets, descents."""
    sim.add_command(descent_cmd)
