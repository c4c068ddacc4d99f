"""render_service's `skyloc` subcommands: `db ...` (databases) and `serve`."""
from __future__ import annotations

import importlib

import click

_SUBMODULES = ("render_service.cli_db", "render_service.cli_serve")


def register(group: click.Group) -> None:
    for name in _SUBMODULES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue
            raise
        mod.register(group)
