"""`skyloc extract`: skyline of an acquisition or a panorama folder, as a skyline JSON file."""
from __future__ import annotations

import logging
from pathlib import Path

import click

from board.atomic import write_json_atomic
from board.errors import NoSkylineError

log = logging.getLogger(__name__)


@click.command("extract")
@click.option("--acquisition", "acq_dir", type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="Acquisition folder (acquisition.json + frames).")
@click.option("--panorama", "pano_dir", type=click.Path(exists=True, file_okay=False, path_type=Path),
              help="Panorama folder (panorama.json + image).")
@click.option("--out", "out", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="Skyline JSON to write (azimuths relative to the heading).")
@click.option("--debug", "debug", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="PNG showing the panorama, the detected line and the masked columns.")
@click.option("--n-azimuth", type=click.IntRange(4, 36000), default=360, show_default=True,
              help="Samples of the skyline over 360 degrees (the database's azimuth grid).")
@click.option("--azimuth-start", type=float, default=0.0, show_default=True,
              help="Azimuth of sample 0, degrees (the database's azimuth start).")
@click.option("--refine-yaw/--no-refine-yaw", default=False, show_default=True,
              help="Correct the pan angles by matching overlapping frames (pan-tilt units with ~1 deg error).")
@click.option("--report", "report", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write the status, reason and diagnostics as JSON.")
def extract_cmd(acq_dir: Path | None, pano_dir: Path | None, out: Path, debug: Path | None, n_azimuth: int,
                azimuth_start: float, refine_yaw: bool, report: Path | None) -> None:
    """Extract the skyline (elevation by azimuth) from an acquisition or a panorama.

    Exits with status 1 and the reason (black, over-exposed, all sky, all ground, too few
    confident columns) when there is no skyline to give; nothing is written to --out then.
    """
    from board.extraction import ExtractionOptions, extract_from_acquisition, extract_from_panorama

    if (acq_dir is None) == (pano_dir is None):
        raise click.UsageError("give exactly one of --acquisition DIR or --panorama DIR")
    opts = ExtractionOptions(n_azimuth=n_azimuth, azimuth_start_deg=azimuth_start)
    if acq_dir is not None:
        res = extract_from_acquisition(acq_dir, refine_yaw=refine_yaw, options=opts)
    else:
        res = extract_from_panorama(pano_dir, options=opts)
    if debug is not None and res.panorama is not None:
        from board.debug_plot import save_extraction_picture

        save_extraction_picture(res, debug)
        click.echo(f"debug picture: {debug}")
    if report is not None:
        write_json_atomic(report, res.to_json_dict(), indent=1)
    if res.skyline is None:
        raise NoSkylineError(f"no skyline: {res.reason}")
    res.skyline.save(out)
    click.echo(f"{res.status}: {res.reason}; {res.skyline.coverage_deg:.0f} deg of azimuth seen; "
               f"skyline written to {out} ({res.elapsed_s:.2f} s)")


def register(group: click.Group) -> None:
    """Add `extract` to the root `skyloc` group."""
    group.add_command(extract_cmd)
