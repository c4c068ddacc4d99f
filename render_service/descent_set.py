"""``skyloc sim descent-set``: the descent campaign's data set (trajectories x trials) on the Dask engine.

Layout::

    OUT/traj01/trial00/    one descent sequence per trial (board.descent.sequence, written atomically)
    OUT/descent_set.json   what was asked and what is on disk (rewritten atomically at the end)

Resumable: a trial whose folder reads back (``read_sequence``) is not simulated again; an
interrupted one left only a hidden ``.trial00.*.part`` folder, which is removed and redone.  One
task per trial; each worker process builds the terrain and the renderer once (``simulate.cached_*``)
and reuses them for all its trials.
"""
from __future__ import annotations

import logging
import os
import shutil
from dataclasses import replace
from pathlib import Path

from board.atomic import write_json_atomic
from board.descent.sequence import read_sequence
from board.errors import FormatError, InvalidInputError, SkylocError

log = logging.getLogger(__name__)

SET_MANIFEST = "descent_set.json"


def trial_dir(out: Path, trajectory: int, trial: int) -> Path:
    return Path(out) / f"traj{trajectory:02d}" / f"trial{trial:02d}"


def parse_range(text: str, *, lo: int, hi: int, what: str) -> list[int]:
    """'1-10', '3', '1,4,7-9' -> sorted unique ints in [lo, hi]; InvalidInputError naming the fix."""
    out: set[int] = set()
    try:
        for part in str(text).split(","):
            part = part.strip()
            if "-" in part:
                a, b = (int(v) for v in part.split("-", 1))
                out.update(range(a, b + 1))
            elif part:
                out.add(int(part))
    except ValueError:
        raise InvalidInputError(f"{what} {text!r}: give numbers and ranges like 1-10 or 1,3,5-7") from None
    if not out or min(out) < lo or max(out) > hi:
        raise InvalidInputError(f"{what} {text!r}: use values from {lo} to {hi}")
    return sorted(out)


def is_complete(path: Path) -> bool:
    """True when ``path`` is a readable descent sequence."""
    if not (path / "sequence.json").is_file():
        return False
    try:
        read_sequence(path)
    except FormatError as exc:
        log.warning("%s is not a complete sequence (%s): it will be simulated again", path, exc)
        return False
    return True


def _simulate_task(config, out: str) -> str:
    """Dask task: one trial (an existing incomplete folder is replaced)."""
    from blender_addon.descent.simulate import simulate_trial  # noqa: PLC0415

    path = Path(out)
    for stale in path.parent.glob(f".{path.name}.*.part"):
        shutil.rmtree(stale, ignore_errors=True)
    return str(simulate_trial(config, path, overwrite=path.exists()))


def plan_set(out: Path, trajectories: list[int], trials: list[int]) -> tuple[list[tuple[int, int]], int]:
    """(trajectory, trial) pairs still to simulate, and how many are already complete."""
    todo, done = [], 0
    for tr in trajectories:
        for k in trials:
            if is_complete(trial_dir(out, tr, k)):
                done += 1
            else:
                todo.append((tr, k))
    return todo, done


def run_descent_set(base_config, out: str | os.PathLike, *, trajectories: list[int], trials: list[int],
                    scheduler: str | None = None, n_workers: int = 2, security=None, progress=None) -> dict:
    """Simulate every (trajectory, trial) not on disk yet on the Dask engine; returns the manifest.

    base_config : a :class:`blender_addon.descent.simulate.DescentConfig` (its trajectory and trial are
    replaced per task).  progress : callable(done, total) or None.  A failed trial is recorded with
    its error and the others go on; SkylocError is raised at the end naming the failed trials.
    """
    from distributed import as_completed  # noqa: PLC0415

    from render_service.engine import dask_client  # noqa: PLC0415

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    todo, done = plan_set(out, trajectories, trials)
    total = len(trajectories) * len(trials)
    log.info("descent set %s: %d of %d trials on disk, %d to simulate", out, done, total, len(todo))
    failed: dict[str, str] = {}
    if progress:
        progress(done, total)
    if todo:
        with dask_client(scheduler, n_workers=n_workers, security=security) as client:
            futures = {client.submit(_simulate_task, replace(base_config, trajectory=tr, trial=k),
                                     str(trial_dir(out, tr, k)), pure=False, key=f"descent-{tr:02d}-{k:02d}"): (tr, k)
                       for tr, k in todo}
            for fut in as_completed(futures):
                tr, k = futures[fut]
                try:
                    fut.result()
                    done += 1
                except Exception as exc:  # a task's failure is recorded, the set goes on
                    failed[f"traj{tr:02d}/trial{k:02d}"] = f"{type(exc).__name__}: {exc}"
                    log.error("trajectory %d trial %d failed: %s", tr, k, exc)
                if progress:
                    progress(done, total)
    manifest = {"format": "skyloc-descent-set", "version": 1, "trajectories": trajectories, "trials": trials,
                "complete": done, "total": total, "failed": failed,
                "config": {"terrain": base_config.terrain, "seed": base_config.seed, "frames": base_config.frames,
                           "modes": list(base_config.modes), "brdf": base_config.appearance.brdf,
                           "thermal": base_config.appearance.thermal, "width": base_config.width,
                           "height": base_config.height}}
    write_json_atomic(out / SET_MANIFEST, manifest, indent=1)
    if failed:
        raise SkylocError(f"{len(failed)} of {total} trials failed ({', '.join(sorted(failed)[:5])}...): see "
                          f"{out / SET_MANIFEST}; run the same command again to retry them")
    return manifest
