"""`skyloc locate`: position, heading and tilt of a rover from its skyline and a skyline database.

Exit status: 0 the fix is ``ok``; 3 ``ambiguous``; 4 ``failed``; 1 an error (bad input, unreadable
files, a query from another DEM/CRS/body).  ``--allow-uncertain`` makes 3 and 4 exit 0 for scripts
that read the status from the JSON themselves.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import click

from board.atomic import write_text_atomic
from board.cliargs import parse_floats, parse_xy
from board.errors import InvalidInputError, NoSkylineError
from board.pose.confidence import STATUS_AMBIGUOUS, STATUS_FAILED, STATUS_OK

log = logging.getLogger(__name__)

#: exit status of `skyloc locate` per fix status (errors exit 1, as every skyloc command)
EXIT_CODES = {STATUS_OK: 0, STATUS_AMBIGUOUS: 3, STATUS_FAILED: 4}
EXIT_ERROR = 1


@dataclass
class Query:
    """The query skyline and what its source says: truth, the attitude it was levelled with, provenance."""

    skyline: object
    source: str
    truth: object = None
    levelled_with: tuple[float, float] | None = None
    provenance: object = None
    notes: list[str] = field(default_factory=list)


def _from_acquisition(acq_dir: Path, azimuth_step_deg: float) -> Query:
    """Skyline of an acquisition folder, sampled on the database's azimuth step, with its manifest's truth."""
    from board.acquisition import load_acquisition  # noqa: PLC0415
    from board.locate.provenance import Provenance  # noqa: PLC0415
    from board.locate.truth import Truth  # noqa: PLC0415

    try:
        from board.extraction import extract_from_acquisition  # noqa: PLC0415
    except ImportError as exc:
        raise InvalidInputError(f"--acquisition needs board.extraction, which is not available ({exc}); "
                                "extract the skyline with `skyloc extract` and pass --skyline") from exc
    acq = load_acquisition(acq_dir)
    res = extract_from_acquisition(acq, azimuth_step_deg=azimuth_step_deg)
    if res.skyline is None:
        raise NoSkylineError(f"no skyline extracted from {acq_dir} ({res.status}): {res.reason}")
    if res.status != "ok":
        log.warning("extraction %s: %s", res.status, res.reason)
    t = acq.truth
    truth = None if t is None else Truth(t.x, t.y, t.heading_deg, t.pitch_deg, t.roll_deg,
                                         source=f"{acq_dir}/acquisition.json")
    prov = Provenance.from_meta(acq.meta, crs_wkt="" if t is None else t.crs)
    return Query(res.skyline, str(acq_dir), truth, tuple(acq.attitude) if acq.attitude else None, prov)


def _from_skyline(path: Path) -> Query:
    from board.locate.provenance import Provenance  # noqa: PLC0415
    from board.skyline import Skyline  # noqa: PLC0415

    sky = Skyline.load(path)
    lev = sky.meta.get("attitude_used")
    return Query(sky, str(path), None, tuple(lev) if lev else None, Provenance.from_meta(sky.meta))


def _truth_option(value: str | None):
    """--truth X,Y[,HEADING] -> Truth (metres in the database CRS, degrees)."""
    from board.locate.truth import Truth  # noqa: PLC0415

    v = parse_floats(value, "--truth", (2, 3), "X,Y[,HEADING] (metres in the database CRS, degrees)")
    return Truth(v[0], v[1], v[2] if len(v) == 3 else None, source="--truth")


def _tilt_text(fix, q: Query) -> str:
    if q.levelled_with is None:
        return f"pitch {fix.pitch_deg:.2f}  roll {fix.roll_deg:.2f} deg (mast tilt from the local vertical)"
    p, r = q.levelled_with
    return (f"pitch {fix.pitch_deg:.2f}  roll {fix.roll_deg:.2f} deg residual after levelling with the "
            f"acquisition's attitude (pitch {p:.2f}, roll {r:.2f}): mast tilt about pitch {p + fix.pitch_deg:.2f}"
            f"  roll {r + fix.roll_deg:.2f}")


@click.command("locate")
@click.option("--db", "db_path", required=True, type=click.Path(path_type=Path), help="Skyline database (Zarr).")
@click.option("--skyline", "sky_path", type=click.Path(dir_okay=False, path_type=Path),
              help="Query skyline JSON (azimuths relative to the heading).")
@click.option("--acquisition", "acq_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Acquisition folder: extract its skyline first (instead of --skyline); its manifest's truth, "
                   "when it has one, is compared with the fix.")
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
@click.option("--truth", "truth", default=None,
              help="True pose X,Y[,HEADING] (metres in the database CRS, degrees) to compare the fix with "
                   "(overrides an acquisition's truth).")
@click.option("--ignore-provenance", is_flag=True,
              help="Match even when the query says it comes from another DEM, CRS or body than the database.")
@click.option("--allow-uncertain", is_flag=True,
              help="Exit 0 for 'ambiguous' and 'failed' fixes too (default: 3 and 4).")
@click.option("--json", "as_json", is_flag=True, help="Print the fix as JSON.")
@click.option("--plot", "plot", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="PNG with the score map and the skyline overlay (and the truth when known).")
@click.option("--out", "out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write the JSON fix to this file (atomically).")
@click.pass_context
def locate_cmd(ctx: click.Context, db_path: Path, sky_path: Path | None, acq_dir: Path | None, mode: str,
               prior: str | None, radius: float | None, heading_prior: float | None, heading_window: float,
               position_sigma: float, tilt_prior: str | None, model: str, truth: str | None, ignore_provenance: bool,
               allow_uncertain: bool, as_json: bool, plot: Path | None, out: Path | None) -> None:
    """Locate the rover: exhaustive FFT match over the database, sub-grid and tilt refinement, confidence.

    Exit status: 0 ok, 3 ambiguous, 4 failed (0 for both with --allow-uncertain), 1 error.
    """
    from board.locate import LocateOptions, locate  # noqa: PLC0415
    from board.locate.provenance import crs_name, mismatches  # noqa: PLC0415
    from board.locate.truth import compare_with_truth  # noqa: PLC0415
    from board.progress import progress_bar  # noqa: PLC0415
    from board.skydb import SkyDB  # noqa: PLC0415

    if (sky_path is None) == (acq_dir is None):
        raise InvalidInputError("give exactly one of --skyline FILE or --acquisition DIR")
    tp = None if tilt_prior is None else parse_floats(tilt_prior, "--tilt-prior", (3,), "pitch,roll,sigma in degrees")
    truth_cli = None if truth is None else _truth_option(truth)
    opts = LocateOptions(mode=mode, prior_xy=None if prior is None else parse_xy(prior, "--prior"), radius_m=radius,
                         heading_prior_deg=heading_prior, heading_window_deg=heading_window, tilt_prior=tp,
                         model=model, position_sigma_m=position_sigma)
    opts.validate()
    db = SkyDB.open(db_path)
    q = _from_skyline(sky_path) if sky_path is not None else _from_acquisition(acq_dir, db.meta.azimuth_step_deg)
    bad = mismatches(db.meta, q.provenance)
    if bad and not ignore_provenance:
        raise InvalidInputError(f"{q.source} does not come from the terrain of the database {db_path}: "
                                + "; ".join(bad) + ". Render a database of that DEM (skyloc db render), or pass "
                                "--ignore-provenance to match anyway")
    for b in bad:
        log.warning("provenance ignored: %s", b)
    if not q.provenance.known:
        log.info("%s says nothing of its DEM, CRS or body: provenance not checked", q.source)
    tru = truth_cli or q.truth
    with progress_bar("matching", unit="tile") as progress:
        fix = locate(db, q.skyline, opts, progress=progress)
    cmp = None if tru is None else compare_with_truth(fix, tru, tilt_offset_deg=q.levelled_with or (0.0, 0.0))
    crs = crs_name(db.grid.crs_wkt) or "the database's local CRS (no name)"
    d = fix.to_json_dict()
    d["crs_wkt"] = db.grid.crs_wkt
    d["crs_name"] = crs
    d["tilt_reference"] = ("local vertical" if q.levelled_with is None else "panorama levelled with the attitude "
                           f"pitch {q.levelled_with[0]:g}, roll {q.levelled_with[1]:g} deg")
    d["levelled_with_deg"] = None if q.levelled_with is None else list(q.levelled_with)
    d["truth"] = None if cmp is None else cmp.to_json_dict()
    d["exit_code"] = 0 if allow_uncertain else EXIT_CODES[fix.status]
    if out is not None:
        write_text_atomic(out, json.dumps(d, indent=2))
    if plot is not None:
        from board.plots import plot_fix  # noqa: PLC0415

        plot_fix(fix, plot, truth=None if tru is None else (tru.x, tru.y))
    if as_json:
        click.echo(json.dumps(d, indent=2))
    else:
        click.echo(f"status {fix.status}{': ' + fix.reason if fix.reason else ''}")
        click.echo(f"x {fix.x:.2f} m  y {fix.y:.2f} m  in {crs}  (sigma {fix.sigma_x_m:.2f} / {fix.sigma_y_m:.2f} m, "
                   f"95 % ellipse {fix.ellipse95_m[0]:.2f} x {fix.ellipse95_m[1]:.2f} m)")
        click.echo(f"heading {fix.heading_deg:.2f} deg (sigma {fix.sigma_heading_deg:.2f}, clockwise from grid north)"
                   f"  {_tilt_text(fix, q)}  |  {fix.elapsed_s:.2f} s")
        for what, sectors in (("above the DEM's skyline (near rocks or objects not in the DEM)", fix.above_dem),
                              ("below the DEM's skyline (the extraction missed it)", fix.below_dem)):
            if sectors:
                click.echo(f"masked {sum(x['n'] for x in sectors)} query column(s) {what}: " + ", ".join(
                    f"{x['from_deg']:g}-{x['to_deg']:g} deg ({x['excess_deg']:+.1f} deg)" for x in sectors))
        if fix.at_grid_edge:
            click.echo("warning: the fix lies within one grid step of the database grid's edge: the rover may be "
                       "beyond it (render a database around it)")
        if cmp is not None:
            line = f"truth ({cmp.truth.source}): position error {cmp.error_m:.2f} m (dx {cmp.dx_m:+.2f}, " \
                   f"dy {cmp.dy_m:+.2f})"
            if cmp.in_ellipse95 is not None:
                line += ", inside the 95 % ellipse" if cmp.in_ellipse95 else ", OUTSIDE the 95 % ellipse"
            if cmp.heading_error_deg is not None:
                line += f"; heading error {cmp.heading_error_deg:+.2f} deg"
            if cmp.pitch_error_deg is not None:
                line += f"; mast tilt error pitch {cmp.pitch_error_deg:+.2f} roll {cmp.roll_error_deg:+.2f} deg"
            click.echo(line)
    ctx.exit(d["exit_code"])


def register(group: click.Group) -> None:
    """Add `locate` to the root `skyloc` group."""
    group.add_command(locate_cmd)
