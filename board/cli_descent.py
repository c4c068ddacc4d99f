"""`skyloc descent run`: the descent filter on one descent-sequence folder (estimate.tum + metrics)."""
from __future__ import annotations

import json
import logging
from pathlib import Path

import click
import numpy as np

log = logging.getLogger(__name__)


@click.command("run")
@click.argument("sequence", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--mode", type=click.Choice(["visible", "thermal", "dual", "visible-64"]), default="dual",
              show_default=True)
@click.option("--out", "out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Write the estimate here (TUM: t x y z qx qy qz qw).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the initial-state draw and RANSAC.")
@click.option("--frames", type=int, default=None, help="Only the first N frames.")
def run_cmd(sequence: Path, mode: str, out: Path | None, seed: int, frames: int | None) -> None:
    """Run the filter on SEQUENCE and print E, ATE, RPE and NEES against its ground truth (JSON)."""
    from board.descent.metrics import ate_m, error_growth_percent, groundtruth_at, pose_nees, rpe_m  # noqa: PLC0415
    from board.descent.runner import run_sequence, write_tum  # noqa: PLC0415
    from board.descent.sequence import read_sequence  # noqa: PLC0415

    seq = read_sequence(sequence)
    res = run_sequence(seq, mode, seed=seed, max_frames=frames)
    gt = groundtruth_at(seq.groundtruth, res.tum[:, 0])
    if out is not None:
        write_tum(out, res.tum)
    E, icpt = error_growth_percent(res.tum, gt)
    click.echo(json.dumps({"mode": mode, "frames": int(res.tum.shape[0]), "E_percent": round(E, 4),
                           "E_intercept_m": round(icpt, 4), "ate_m": round(ate_m(res.tum, gt), 4),
                           "rpe_m": round(rpe_m(res.tum, gt), 4),
                           "nees": round(float(np.mean(pose_nees(res.tum, gt, res.pose_cov))), 3),
                           "step_ms_mean": round(float(np.mean(res.step_ms)), 1)}))


def register(main: click.Group) -> None:
    existing = main.commands.get("descent")
    if isinstance(existing, click.Group):
        existing.add_command(run_cmd)
        return

    @click.group("descent")
    def descent_group() -> None:
        """Descent navigation (inverse-depth EKF-SLAM): run, evaluation."""

    descent_group.add_command(run_cmd)
    main.add_command(descent_group)
