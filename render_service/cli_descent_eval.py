"""`skyloc descent eval`: the memorandum's evaluation of the descent filter on the Dask engine."""
from __future__ import annotations

import logging
from pathlib import Path

import click

from board.errors import InvalidInputError

log = logging.getLogger(__name__)


def _ints(value: str | None, name: str) -> tuple[int, ...] | None:
    if value is None:
        return None
    try:
        out: list[int] = []
        for part in value.split(","):
            if "-" in part:
                a, b = (int(v) for v in part.split("-"))
                out.extend(range(a, b + 1))
            else:
                out.append(int(part))
    except ValueError:
        raise InvalidInputError(f"{name} must be ids like '1,3' or '1-10', got {value!r}") from None
    return tuple(out)


@click.command("eval")
@click.option("--profile", "profile_name", type=click.Choice(["ci", "paper"]), default="ci", show_default=True,
              help="ci: two short trajectories x three trials; paper: 10 x 30 whole trajectories.")
@click.option("--out", "out", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Output folder (resumable: runs already there are kept).")
@click.option("--trajectories", default=None, help="Subset of trajectories, e.g. '1,3' or '1-10'.")
@click.option("--trials", type=int, default=None, help="Trials per trajectory (overrides the profile).")
@click.option("--frames", type=int, default=None, help="Frames per trial (overrides the profile).")
@click.option("--modes", default=None, help="Comma-separated modes (visible,thermal,dual,visible-64).")
@click.option("--workers", type=int, default=2, show_default=True, help="Dask worker processes (local cluster).")
@click.option("--scheduler", default=None, help="Address of an existing Dask scheduler instead of a local cluster.")
@click.option("--local", is_flag=True, help="Run in this process without Dask (debugging).")
def eval_cmd(profile_name, out, trajectories, trials, frames, modes, workers, scheduler, local):
    """Reproduce the memorandum's tables: results.csv, tables.md and report.html in OUT."""
    from render_service.descent_eval.campaign import run_eval  # noqa: PLC0415
    from render_service.descent_eval.profiles import get_profile  # noqa: PLC0415

    prof = get_profile(profile_name, trajectories=_ints(trajectories, "--trajectories"), trials=trials,
                       frames=frames, modes=tuple(modes.split(",")) if modes else None)
    tables = run_eval(prof, out, scheduler=scheduler, n_workers=workers, local=local)
    click.echo(f"median E: " + ", ".join(f"{m} {v:.2f} %" for m, v in tables["median_E"].items()))
    click.echo(f"wrote {out / 'results.csv'}, {out / 'tables.md'}, {out / 'report.html'}")


@click.group("descent")
def descent_group() -> None:
    """Descent navigation (inverse-depth EKF-SLAM): evaluation."""


descent_group.add_command(eval_cmd)


def register(main: click.Group) -> None:
    existing = main.commands.get("descent")
    if isinstance(existing, click.Group):
        existing.add_command(eval_cmd)
    else:
        main.add_command(descent_group)
