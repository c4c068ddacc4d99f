"""``skyloc sim descent-set``: trajectories x trials of the descent simulator on the Dask engine (resumable)."""
from __future__ import annotations

import logging
from pathlib import Path

import click

log = logging.getLogger(__name__)


def _command():
    from blender_addon.cli_descent import descent_options, make_config  # noqa: PLC0415

    @click.command("descent-set")
    @click.option("--trajectories", default="1-10", show_default=True, help="Trajectories, e.g. 1-10 or 1,3,5-7.")
    @click.option("--trials", default="30", show_default=True,
                  help="Number of trials per trajectory (0..N-1), or a range like 5-9.")
    @descent_options
    @click.option("--scheduler", default=None, help="Dask scheduler address (tls://host:8786); default: a "
                  "LocalCluster on this machine.")
    @click.option("--workers", default=2, show_default=True, type=click.IntRange(1, 256),
                  help="LocalCluster worker processes (one thread each).")
    @click.option("--out", "out_dir", type=click.Path(file_okay=False), required=True,
                  help="Output folder (OUT/trajNN/trialMM); run again to resume.")
    def descent_set_cmd(trajectories: str, trials: str, scheduler: str | None, workers: int, out_dir: str,
                        **kw) -> None:
        """Simulate a descent data set (the memorandum's 10 trajectories x 30 trials by default) on Dask."""
        from render_service.descent_set import parse_range, run_descent_set  # noqa: PLC0415

        trajs = parse_range(trajectories, lo=1, hi=10, what="--trajectories")
        trial_list = (list(range(int(trials))) if trials.strip().isdigit()
                      else parse_range(trials, lo=0, hi=100000, what="--trials"))
        if not trial_list:
            raise click.BadParameter("at least one trial", param_hint="--trials")
        base = make_config(trajectory=trajs[0], trial=trial_list[0], **kw)
        from tqdm import tqdm  # noqa: PLC0415

        with tqdm(desc="descent-set", unit="trial", disable=None) as bar:
            def progress(done: int, total: int) -> None:
                bar.total = total
                bar.update(done - bar.n)

            m = run_descent_set(base, Path(out_dir), trajectories=trajs, trials=trial_list, scheduler=scheduler,
                                n_workers=workers, progress=progress)
        click.echo(f"{out_dir}: {m['complete']} of {m['total']} trials complete")

    return descent_set_cmd


def register(group: click.Group) -> None:
    """Add ``descent-set`` to the ``sim`` group (created if absent)."""
    sim = group.commands.get("sim")
    if sim is None:
        @group.group("sim")
        def sim() -> None:
            """Simulator: panoramas, NavCam acquisitions, test sets, descents."""
    sim.add_command(_command())
