"""One declaration of the DEM-facing options (issue 13 point 9): every ``skyloc`` subcommand's --dem, --body,
--crs, --assume-metric and --at come from blender_addon/cli_options.py, with its help."""
from __future__ import annotations

import click

from blender_addon import cli_options as O
from skyloc.cli import main

SHARED = {"--dem": O.DEM_HELP, "--body": O.BODY_HELP, "--crs": O.CRS_HELP, "--assume-metric": O.ASSUME_METRIC_HELP,
          "--at": O.AT_HELP}


def _commands(group: click.Group, prefix: str = ""):
    for name, cmd in group.commands.items():
        if isinstance(cmd, click.Group):
            yield from _commands(cmd, f"{prefix}{name} ")
        else:
            yield f"{prefix}{name}", cmd


def test_dem_body_crs_at_are_the_shared_options_everywhere():
    seen, bad = set(), []
    for path, cmd in _commands(main):
        for p in cmd.params:
            for opt in getattr(p, "opts", []):
                if opt in SHARED:
                    seen.add(opt)
                    if not (p.help or "").startswith(SHARED[opt]):
                        bad.append(f"skyloc {path} {opt}: {p.help!r}")
    assert not bad, "declared outside blender_addon/cli_options.py:\n" + "\n".join(bad)
    assert seen == set(SHARED)


def test_campaign_takes_the_shared_dem_and_body():
    cmd = main.commands["campaign"]
    opts = {o: p for p in cmd.params for o in getattr(p, "opts", [])}
    assert opts["--dem"].default == "procedural:mars:7" and opts["--dem"].help.startswith(O.DEM_HELP)
    assert opts["--body"].help == O.BODY_HELP
