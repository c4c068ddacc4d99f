"""``run_eval``: plan the trials of a profile, run them on the Dask engine (resumable), write the outputs.

Outputs in the folder: ``profile.json`` (the protocol; a resume must use the same one), ``results.csv``
(one row per run, :data:`tasks.RESULT_COLUMNS`), ``tables.md`` and ``report.html``.
"""
from __future__ import annotations

import csv
import json
import logging
import os
import platform
import time
from pathlib import Path

from board.errors import InvalidInputError
from render_service.engine import dask_client

from .profiles import Profile
from .report import compute_tables, report_html, tables_markdown
from .tasks import RESULT_COLUMNS, run_trial
from board.atomic import atomic_path

log = logging.getLogger(__name__)


def _check_resume(out: Path, profile: Profile) -> None:
    p = out / "profile.json"
    want = profile.to_dict()
    if p.is_file():
        have = json.loads(p.read_text())
        keep = {k: v for k, v in have.items() if k not in ("name", "trajectories", "trials", "modes")}
        new = {k: v for k, v in want.items() if k not in ("name", "trajectories", "trials", "modes")}
        if keep != new:
            raise InvalidInputError(f"{out} holds an evaluation with {keep}, not {new}: use another --out or the same "
                                    "frames/terrain/seed (trajectories, trials and modes may grow)")
    out.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(want, indent=1))


def write_results_csv(path: Path, rows: list[dict]) -> None:
    with atomic_path(path) as tmp, open(tmp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(RESULT_COLUMNS)
        for r in sorted(rows, key=lambda r: (r["trajectory"], r["trial"], r["mode"])):
            w.writerow([r[c] if isinstance(r[c], (int, str)) else f"{r[c]:.6g}" for c in RESULT_COLUMNS])


def run_eval(profile: Profile, out: str | os.PathLike, *, scheduler: str | None = None, n_workers: int = 2,
             local: bool = False) -> dict:
    """Run ``profile`` into ``out``; returns the tables (see :func:`report.compute_tables`).

    local : run the trials in this process, one after the other (no Dask), e.g. for debugging.
    """
    out = Path(out)
    _check_resume(out, profile)
    pdict = profile.to_dict()
    jobs = [(k, i) for k in profile.trajectories for i in range(profile.trials)]
    t0 = time.time()
    rows: list[dict] = []
    if local:
        for k, i in jobs:
            rows.extend(run_trial(str(out), pdict, k, i))
    else:
        with dask_client(scheduler, n_workers=n_workers, threads_per_worker=1) as client:
            futs = [client.submit(run_trial, str(out), pdict, k, i, key=f"descent-eval-{k}-{i}-{time.time_ns()}",
                                  pure=False) for k, i in jobs]
            for f in futs:
                rows.extend(f.result())
    wall = time.time() - t0
    write_results_csv(out / "results.csv", rows)
    tables = compute_tables(rows, profile.modes)
    md = tables_markdown(tables, profile.modes, title=f"profile {profile.name}: {len(profile.trajectories)} "
                                                      f"trajectories x {profile.trials} trials")
    (out / "tables.md").write_text(md)
    header = {"profile": profile.name, "trajectories": list(profile.trajectories), "trials": profile.trials,
              "frames": profile.frames or "whole trajectory", "terrain": profile.terrain, "runs": len(rows),
              "wall time (s)": f"{wall:.0f}", "machine": f"{platform.machine()} {os.cpu_count()} cores",
              "E": "OLS slope of the position error norm vs distance travelled, free intercept, in %"}
    (out / "report.html").write_text(report_html(rows, md, profile.modes, header))
    log.info("descent eval %s: %d runs in %.0f s -> %s", profile.name, len(rows), wall, out)
    return tables
