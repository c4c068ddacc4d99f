"""blender_addon's `skyloc` subcommands: `dem ...` (terrain) and `sim ...` (simulator)."""
from __future__ import annotations

import importlib

import click

_SUBMODULES = ("blender_addon.cli_dem", "blender_addon.cli_sim")


def register(group: click.Group) -> None:
    for name in _SUBMODULES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue
            raise
        mod.register(group)
