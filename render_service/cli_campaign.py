"""``skyloc campaign``: the reference report's test campaign, end to end from rendered images, on any DEM."""
from __future__ import annotations

import logging
from pathlib import Path

import click

from blender_addon.cli_options import body_option, dem_option
from render_service.cli_tls import check_tls_options, tls_client_options

log = logging.getLogger(__name__)


@click.command("campaign")
@dem_option(default="procedural:mars:7", note="A procedural terrain is sized by the profile.")
@click.option("--profile", "profile_name", default="ci", show_default=True,
              type=click.Choice(["ci", "report", "full"]),
              help="ci: a small site in minutes; report: the report's protocol on 1 x 1 km at 5 m; full: "
                   "+ robustness sets and 7 x 7 km (a cluster).")
@click.option("--seed", default=0, show_default=True, type=int,
              help="Draws the site, poses (off the grid), headings, tilts, suns and texture seeds.")
@click.option("--out", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Output folder (results.csv, summary.json, report.html); run again to resume.")
@click.option("--scheduler", default=None,
              help="Dask scheduler address (tls://host:8786); default a LocalCluster on this machine (mutual TLS, "
                   "credentials generated for the run).")
@tls_client_options
@click.option("--workers", default=2, show_default=True, type=click.IntRange(1, 256),
              help="LocalCluster worker processes (one thread each: Blender is not thread-safe).")
@body_option()
@click.option("--min-relief-deg", default=None, type=click.FloatRange(0.0, 90.0),
              help="Use only poses whose true horizon rises this much (deg) above its lowest part [profile: 1].")
@click.option("--poses", default=None, type=click.IntRange(1, 10000),
              help="Override the profile's number of hidden poses (tables 4, 5, 7, 8); more than a folder holds "
                   "grows it (its finished cases are kept).")
@click.option("--acquisitions", default=None, type=click.IntRange(0, 10000),
              help="Override the profile's number of NavCam acquisitions (table 6).")
@click.option("--pano-width", default=None, type=click.IntRange(64, 16384),
              help="Override the panorama width (pixels).")
@click.option("--samples", default=None, type=click.IntRange(1, 4096), help="Override the Cycles samples.")
@click.option("--set", "settings", multiple=True, metavar="FIELD=VALUE",
              help="Override any profile field, e.g. --set t4_presets=binary,clean --set frames=9 (repeatable; "
                   "fields in render_service/campaign/profiles.py).")
@click.option("--only", "only", multiple=True, metavar="CASE_GLOB",
              help="Run only the cases whose id matches this glob (repeatable), e.g. --only 't6-*-pitch-*' "
                   "--only 't6-*-roll-*'; the cases whose skyline they reuse run too, the rest stay unfinished "
                   "(run again without --only to finish them). Case ids are in the folder's cases/.")
@click.option("--no-progress", is_flag=True, help="No progress bars (logs only).")
def campaign(dem: str, profile_name: str, seed: int, out: Path, scheduler: str | None, tls_ca_file: Path | None,
             tls_cert: Path | None, tls_key: Path | None, workers: int,
             body: str | None, min_relief_deg: float | None, poses: int | None, acquisitions: int | None,
             pano_width: int | None, samples: int | None, settings: tuple[str, ...], only: tuple[str, ...],
             no_progress: bool) -> None:
    """Run (or resume) the report's test campaign (tables 4-8) end to end from rendered images.

    Exit status 0 when the harness ran (bad fixes are results, in results.csv), 1 on bad arguments
    or when cases crashed the harness (running the same command again retries them).
    """
    from render_service.campaign import CampaignOptions, run_campaign  # noqa: PLC0415
    from render_service.engine import security_from_files  # noqa: PLC0415

    security = None
    if check_tls_options(scheduler, tls_ca_file, tls_cert, tls_key):
        security = security_from_files(ca_file=tls_ca_file, cert_file=tls_cert, key_file=tls_key)
    overrides = profile_overrides(settings, poses=poses, acquisitions=acquisitions, pano_width=pano_width,
                                  samples=samples)
    run_campaign(CampaignOptions(out=out, dem=dem, profile=profile_name, seed=seed, scheduler=scheduler,
                                 workers=workers, body=body, min_relief_deg=min_relief_deg,
                                 overrides=overrides, only=only,
                                 progress=not no_progress, security=security))
    click.echo(f"results: {out / 'results.csv'}, {out / 'summary.json'}, {out / 'report.html'}")


def profile_overrides(settings, *, poses: int | None, acquisitions: int | None, pano_width: int | None,
                      samples: int | None) -> dict:
    """The profile fields the command line sets: every ``--set FIELD=VALUE``, then the dedicated options given
    (None: not given).  ``--poses`` also sets how many poses tables 7 and 8 use, unless ``--set`` names them
    (``--poses 30 --set n_window_poses=1`` runs the window table at one pose)."""
    from render_service.campaign.profiles import parse_setting  # noqa: PLC0415

    overrides = dict(parse_setting(s) for s in settings)
    overrides |= {k: v for k, v in {"n_poses": poses, "n_acquisitions": acquisitions, "pano_width": pano_width,
                                    "samples": samples}.items() if v is not None}
    if poses is not None:
        for k in ("n_window_poses", "n_heading_poses"):
            overrides.setdefault(k, poses)
    return overrides


def register(group: click.Group) -> None:
    """Add ``campaign`` to the root ``skyloc`` group."""
    group.add_command(campaign)
