"""board's `skyloc` subcommands: `locate` and `extract`."""
from __future__ import annotations

import importlib

import click

_SUBMODULES = ("board.cli_locate", "board.cli_extract")


def register(group: click.Group) -> None:
    for name in _SUBMODULES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue
            raise
        mod.register(group)
