"""The Dask task of the evaluation: one trial of one trajectory, every mode (resumable per run).

Layout under the output folder::

    sequences/traj01/trial00/        the simulator's descent sequence (written atomically)
    runs/traj01/trial00/<mode>/      estimate.tum, metrics.json (written last, atomically)

A run whose ``metrics.json`` exists is not run again; a sequence whose folder reads back is not
simulated again.  Every mode of a trial runs on the same sequence with the same filter seed (common
random numbers: the modes' differences are not those of their noise draws).
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from board.descent.metrics import ate_m, distance_travelled, error_growth_percent, groundtruth_at, pose_nees, \
    position_error, rpe_m
from board.descent.runner import run_sequence, write_tum
from board.descent.sequence import read_sequence
from board.errors import FormatError, SkylocError
from board.atomic import write_text_atomic

log = logging.getLogger(__name__)

RESULT_COLUMNS = ("trajectory", "trial", "mode", "E_percent", "ate_m", "rpe_m", "nees", "frames", "landmarks_mean",
                  "step_ms", "E_intercept_m", "distance_m", "step_ms_max")


def sequence_dir(out: Path, trajectory: int, trial: int) -> Path:
    return Path(out) / "sequences" / f"traj{trajectory:02d}" / f"trial{trial:02d}"


def run_dir(out: Path, trajectory: int, trial: int, mode: str) -> Path:
    return Path(out) / "runs" / f"traj{trajectory:02d}" / f"trial{trial:02d}" / mode


def filter_seed(base_seed: int, trajectory: int, trial: int) -> int:
    """The filter's seed of a trial (the same for every mode)."""
    return int(np.random.SeedSequence([base_seed, trajectory, trial, 15]).generate_state(1)[0])


def _atomic_write(path: Path, text: str) -> None:
    write_text_atomic(path, text)


def ensure_sequence(out: Path, profile: dict, trajectory: int, trial: int):
    """The trial's sequence, simulated first if it is not on disk yet."""
    path = sequence_dir(out, trajectory, trial)
    if path.exists():
        try:
            return read_sequence(path)
        except FormatError as exc:
            raise FormatError(f"{path} exists but cannot be read ({exc}): delete it to simulate it again") from exc
    try:
        from blender_addon.descent.simulate import DescentConfig, simulate_trial  # noqa: PLC0415
    except ImportError as exc:
        raise SkylocError(f"the descent simulator (blender_addon.descent) is not importable ({exc}); install skyloc "
                          "with the ground extra") from exc
    cfg = DescentConfig(terrain=profile["terrain"], trajectory=trajectory, trial=trial, seed=profile["seed"],
                        frames=profile["frames"])
    path.parent.mkdir(parents=True, exist_ok=True)
    simulate_trial(cfg, path)
    return read_sequence(path)


def evaluate_run(seq, mode: str, seed: int, rdir: Path, trajectory: int, trial: int) -> dict:
    """Run one mode on a sequence and write its estimate and metrics; returns the metrics."""
    res = run_sequence(seq, mode, seed=seed)
    gt = groundtruth_at(seq.groundtruth, res.tum[:, 0])
    E, icpt = error_growth_percent(res.tum, gt)
    err = position_error(res.tum, gt)
    nees = pose_nees(res.tum, gt, res.pose_cov)
    m = {"trajectory": trajectory, "trial": trial, "mode": mode, "E_percent": E, "ate_m": ate_m(res.tum, gt),
         "rpe_m": rpe_m(res.tum, gt), "nees": float(np.mean(nees)), "frames": int(res.tum.shape[0]),
         "landmarks_mean": float(np.mean(res.landmarks)), "step_ms": float(np.mean(res.step_ms)),
         "E_intercept_m": icpt, "distance_m": float(distance_travelled(gt)[-1]),
         "step_ms_max": float(np.max(res.step_ms)),
         "curve": {"t": res.tum[:, 0].tolist(), "err_m": err.tolist(), "nees": nees.tolist()},
         "altimeter": {"ok": res.altimeter_ok, "gated": res.altimeter_gated}}
    rdir.mkdir(parents=True, exist_ok=True)
    write_tum(rdir / "estimate.tum", res.tum)
    _atomic_write(rdir / "metrics.json", json.dumps(m))
    return m


def run_trial(out: str, profile: dict, trajectory: int, trial: int) -> list[dict]:
    """Dask task: every mode of ``profile`` on one trial; runs already on disk are read back."""
    out = Path(out)
    seed = filter_seed(int(profile["seed"]), trajectory, trial)
    results, seq = [], None
    for mode in profile["modes"]:
        rdir = run_dir(out, trajectory, trial, mode)
        mpath = rdir / "metrics.json"
        if mpath.is_file():
            results.append(json.loads(mpath.read_text()))
            continue
        if seq is None:
            seq = ensure_sequence(out, profile, trajectory, trial)
        results.append(evaluate_run(seq, mode, seed, rdir, trajectory, trial))
        log.info("trajectory %d trial %d %s: E %.2f %%", trajectory, trial, mode, results[-1]["E_percent"])
    return results
