"""`skyloc locate`: position, heading and tilt of a rover from its skyline and a skyline database."""
from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import click

from board.errors import InvalidInputError, NoSkylineError

log = logging.getLogger(__name__)


def _pair(value: str | None, name: str) -> tuple[float, float] | None:
    if value is None:
        return None
    try:
        a, b = (float(v) for v in value.split(","))
    except ValueError:
        raise InvalidInputError(f"{name} must be two numbers 'X,Y' (metres in the database CRS), got {value!r}") \
            from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise InvalidInputError(f"{name} must be finite, got {value!r}")
    return a, b


def _skyline_from_acquisition(acq_dir: Path, azimuth_step_deg: float):
    """Skyline of an acquisition folder, sampled on the database's azimuth step (H4's extraction)."""
    try:
        from board.extraction import extract_from_acquisition  # noqa: PLC0415
    except ImportError as exc:
        raise InvalidInputError(f"--acquisition needs board.extraction, which is not available ({exc}); "
                                "extract the skyline with `skyloc extract` and pass --skyline") from exc
    res = extract_from_acquisition(acq_dir, azimuth_step_deg=azimuth_step_deg)
    if res.skyline is None:
        raise NoSkylineError(f"no skyline extracted from {acq_dir} ({res.status}): {res.reason}")
    if res.status != "ok":
        log.warning("extraction %s: %s", res.status, res.reason)
    return res.skyline


@click.command("locate")
@click.option("--db", "db_path", required=True, type=click.Path(path_type=Path), help="Skyline database (Zarr).")
@click.option("--skyline", "sky_path", type=click.Path(dir_okay=False, path_type=Path),
              help="Query skyline JSON (azimuths relative to the heading).")
@click.option("--acquisition", "acq_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Acquisition folder: extract its skyline first (instead of --skyline).")
@click.option("--mode", type=click.Choice(["lost", "window", "heading"]), default="lost", show_default=True,
              help="lost: whole database; window: --prior and --radius; heading: position --prior, heading near "
                   "--heading-prior.")
@click.option("--prior", "prior", default=None, help="Prior position X,Y (metres, the database's CRS).")
@click.option("--radius", "radius", type=float, default=None, help="Search radius around --prior, metres (window).")
@click.option("--heading-prior", "heading_prior", type=float, default=None,
              help="Heading prior, degrees clockwise from grid north.")
@click.option("--heading-window", type=float, default=10.0, show_default=True,
              help="Half-width of the heading window around --heading-prior, degrees.")
@click.option("--position-sigma", type=float, default=20.0, show_default=True,
              help="Heading mode: uncertainty of --prior, metres (searched together with the heading; 0: exact).")
@click.option("--tilt-prior", "tilt_prior", default=None,
              help="IMU pitch,roll,sigma in degrees (e.g. 4.5,-2.0,0.5).")
@click.option("--model", type=click.Choice(["tilt", "offset"]), default="tilt", show_default=True,
              help="Coarse score: tilt-invariant (offset + first harmonic) or the report's offset-only metric.")
@click.option("--json", "as_json", is_flag=True, help="Print the fix as JSON.")
@click.option("--plot", "plot", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="PNG with the score map and the skyline overlay.")
@click.option("--out", "out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write the JSON fix to this file (atomically).")
def locate_cmd(db_path: Path, sky_path: Path | None, acq_dir: Path | None, mode: str, prior: str | None,
               radius: float | None, heading_prior: float | None, heading_window: float, position_sigma: float,
               tilt_prior: str | None,
               model: str, as_json: bool, plot: Path | None, out: Path | None) -> None:
    """Locate the rover: exhaustive FFT match over the database, sub-grid and tilt refinement, confidence."""
    from board.locate import locate  # noqa: PLC0415
    from board.skydb import SkyDB  # noqa: PLC0415
    from board.skyline import Skyline  # noqa: PLC0415

    if (sky_path is None) == (acq_dir is None):
        raise InvalidInputError("give exactly one of --skyline FILE or --acquisition DIR")
    tp = None
    if tilt_prior is not None:
        try:
            tp = tuple(float(v) for v in tilt_prior.split(","))
        except ValueError:
            tp = ()
        if len(tp) != 3:
            raise InvalidInputError(f"--tilt-prior must be pitch,roll,sigma in degrees, got {tilt_prior!r}")
    db = SkyDB.open(db_path)
    if sky_path is not None:
        sky = Skyline.load(sky_path)
    else:
        sky = _skyline_from_acquisition(acq_dir, db.meta.azimuth_step_deg)
    prior_xy = _pair(prior, "--prior")
    kw = dict(mode=mode, prior_xy=prior_xy, radius_m=radius, heading_prior_deg=heading_prior,
              heading_window_deg=heading_window, tilt_prior=tp, model=model, position_sigma_m=position_sigma)
    err = click.get_text_stream("stderr")
    if err.isatty():  # a progress bar on a terminal only (it would pollute captured output)
        with click.progressbar(length=len(db.tiles), label="matching", file=err, show_eta=True) as bar:
            state = {"done": 0}

            def progress(done: int, total: int) -> None:
                bar.length = total
                bar.update(done - state["done"] if done >= state["done"] else done)
                state["done"] = done

            fix = locate(db, sky, progress=progress, **kw)
    else:
        fix = locate(db, sky, **kw)
    d = fix.to_json_dict()
    d["crs_wkt"] = db.grid.crs_wkt
    if out is not None:
        tmp = out.with_name(out.name + ".part")
        tmp.write_text(json.dumps(d, indent=2))
        tmp.replace(out)
    if plot is not None:
        from board.plots import plot_fix  # noqa: PLC0415

        plot_fix(fix, plot)
    if as_json:
        click.echo(json.dumps(d, indent=2))
    else:
        click.echo(f"status {fix.status}{': ' + fix.reason if fix.reason else ''}")
        click.echo(f"x {fix.x:.2f} m  y {fix.y:.2f} m  (sigma {fix.sigma_x_m:.2f} / {fix.sigma_y_m:.2f} m, "
                   f"95 % ellipse {fix.ellipse95_m[0]:.2f} x {fix.ellipse95_m[1]:.2f} m)")
        click.echo(f"heading {fix.heading_deg:.2f} deg (sigma {fix.sigma_heading_deg:.2f})  pitch {fix.pitch_deg:.2f}"
                   f"  roll {fix.roll_deg:.2f} deg  |  {fix.elapsed_s:.2f} s")


def register(group: click.Group) -> None:
    """Add `locate` to the root `skyloc` group."""
    group.add_command(locate_cmd)
