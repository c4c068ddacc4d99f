"""`skyloc` console entry point.

Each package owns its subcommands through a ``register(group)`` function in its
``cli_*`` modules; this module only builds the root group, sets up logging and maps
:class:`board.errors.SkylocError` to a clean error message and exit status 1.
"""
from __future__ import annotations

import importlib
import logging

import click

from board.errors import SkylocError

log = logging.getLogger(__name__)

#: Modules whose ``register(group)`` adds subcommands; each package owns its own ``cli_*`` modules.
PLUGIN_MODULES = (
    "blender_addon.cli_dem",      # skyloc dem synth|prepare
    "blender_addon.cli_sim",      # skyloc sim panorama
    "blender_addon.cli_sim_acquire",  # skyloc sim acquire|dataset (adds to the sim group)
    "blender_addon.cli_descent",  # skyloc sim descent (adds to the sim group)
    "render_service.cli_descent_set",  # skyloc sim descent-set (Dask)
    "render_service.cli_db",      # skyloc db render|info|horizon
    "render_service.cli_serve",   # skyloc serve
    "render_service.cli_campaign",  # skyloc campaign
    "render_service.cli_descent_eval",  # skyloc descent eval
    "board.cli_extract",          # skyloc extract
    "board.cli_locate",           # skyloc locate
    "board.cli_descent",          # skyloc descent run (adds to the descent group)
)


class SkylocGroup(click.Group):
    """Root group: turns SkylocError into ClickException (traceback only with -vv)."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except SkylocError as exc:
            if logging.getLogger().level <= logging.DEBUG:
                log.exception("skyloc failed")
            raise click.ClickException(str(exc)) from exc


@click.group(cls=SkylocGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug with tracebacks).")
@click.option("-q", "--quiet", is_flag=True, help="Only errors.")
@click.version_option(package_name="skyloc")
def main(verbose: int, quiet: bool) -> None:
    """skyloc: absolute rover localisation by skyline matching, and its simulator."""
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger().setLevel(level)


def _register_plugins() -> None:
    for name in PLUGIN_MODULES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # that package has no CLI yet
                continue
            raise
        mod.register(main)


_register_plugins()

if __name__ == "__main__":  # pragma: no cover
    main()
