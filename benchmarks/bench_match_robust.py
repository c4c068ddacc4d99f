"""Matching that survives bad columns (issue 11): corrupted queries against clean ones, `make bench-match-robust`.

Queries are ray-marched at seeded off-grid poses on a 1 x 1 km database at 5 m (the matcher
benchmark's world, :func:`benchmarks.bench_match._world`), with 0.05 degree noise; a corrupted query
has 5 % of its seen columns wrong by 2-10 degrees, in runs of 1-4 columns (rocks, a wrong edge
followed for a few columns), 70 % of them above the true skyline.  Each query is located with the
robust stage on (the default) and off (``LocateOptions(robust=False)``) in the same run: errors,
status, wrong fixes reported ok, and locate time.  Worlds: ``procedural:mars:7`` (the matcher's
tuning world) and ``procedural:moon:11`` (held out).  Prints a markdown table.

Usage: python -m benchmarks.bench_match_robust [--trials N] [--worlds mars,moon]
"""
from __future__ import annotations

import argparse
import datetime as dt
import math
import os
import subprocess
import sys
import time

import numpy as np

WORLDS = {"mars": "procedural:mars:7", "moon": "procedural:moon:11"}
#: fraction of the seen columns corrupted, and the corruption range (degrees)
BAD_FRACTION = 0.05
BAD_RANGE_DEG = (2.0, 10.0)


def _say(msg: str) -> None:
    sys.stdout.write(msg + "\n")
    sys.stdout.flush()


def corrupt(el: np.ndarray, rng: np.random.Generator, fraction: float = BAD_FRACTION) -> tuple[np.ndarray, np.ndarray]:
    """A copy of ``el`` with ``fraction`` of its seen samples moved by 2-10 degrees in runs of 1-4; (copy, bad mask)."""
    out = el.copy()
    seen = np.flatnonzero(np.isfinite(el))
    target = int(round(fraction * seen.size))
    bad = np.zeros(el.size, bool)
    while bad.sum() < target:
        start = int(rng.choice(seen))
        run = int(rng.integers(1, 5))
        delta = float(rng.uniform(*BAD_RANGE_DEG)) * (1.0 if rng.random() < 0.7 else -1.0)
        for k in range(run):
            j = (start + k) % el.size
            if np.isfinite(el[j]) and bad.sum() < target:
                out[j] = el[j] + delta + float(rng.normal(0, 0.3))
                bad[j] = True
    return out, bad


def run_world(name: str, trials: int, seed: int) -> list[dict]:
    import benchmarks.bench_match as bm
    from board.locate import LocateOptions, locate
    from board.skyline import Skyline

    bm.DEM_SPEC = WORLDS[name]
    bm.CACHE = bm.CACHE.parent / f"bench_match_robust_{name}"
    db, horizon = bm._world(1000.0, 5.0)
    g = db.grid
    cx, cy = g.xy((g.ny - 1) / 2, (g.nx - 1) / 2)
    rng = np.random.default_rng(seed)
    rows = []
    for t in range(trials):
        x = cx + float(rng.uniform(-420, 420))
        y = cy + float(rng.uniform(-420, 420))
        heading = float(rng.uniform(0, 360))
        arc = 360.0 if t % 2 == 0 else 180.0
        q = bm._query(horizon, x, y, heading=heading, arc=arc, arc_start=float(rng.uniform(-180, 0)), rng=rng)
        bad_el, bad = corrupt(q.elevation_deg, rng)
        for kind, sky in (("clean", q), ("corrupted", Skyline(bad_el))):
            for robust in (False, True):
                t0 = time.perf_counter()
                fix = locate(db, sky, LocateOptions(robust=robust))
                dt_s = time.perf_counter() - t0
                err = math.hypot(fix.x - x, fix.y - y)
                herr = abs((fix.heading_deg - heading + 180) % 360 - 180)
                rows.append({"world": name, "trial": t, "arc": arc, "kind": kind, "robust": robust, "error_m": err,
                             "heading_error_deg": herr, "status": fix.status, "locate_s": dt_s,
                             "wrong": err > 25 or herr > 2, "n_outliers": getattr(fix, "n_outliers", 0)})
        _say(f"  {name} trial {t}: arc {arc:.0f}, " + ", ".join(
            f"{r['kind']}/{'robust' if r['robust'] else 'plain'} {r['error_m']:.2f} m {r['status']}"
            for r in rows[-4:]))
    return rows


def table(rows: list[dict]) -> str:
    lines = ["| world | arc | query | robust | n | median m | p90 m | max m | median heading deg | <= 2.5 m | wrong | wrong ok | median locate s |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    keys = sorted({(r["world"], r["arc"], r["kind"], r["robust"]) for r in rows})
    for k in keys:
        g = [r for r in rows if (r["world"], r["arc"], r["kind"], r["robust"]) == k]
        e = np.array([r["error_m"] for r in g])
        h = np.array([r["heading_error_deg"] for r in g])
        lines.append(f"| {k[0]} | {k[1]:.0f} | {k[2]} | {'on' if k[3] else 'off'} | {len(g)} | {np.median(e):.2f} | "
                     f"{np.percentile(e, 90):.2f} | {e.max():.1f} | {np.median(h):.2f} | {np.mean(e <= 2.5):.0%} | "
                     f"{sum(r['wrong'] for r in g)} | {sum(r['wrong'] and r['status'] == 'ok' for r in g)} | "
                     f"{np.median([r['locate_s'] for r in g]):.2f} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=20)
    p.add_argument("--worlds", default="mars,moon")
    p.add_argument("--seed", type=int, default=2026)
    a = p.parse_args()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    _say(f"bench_match_robust {dt.datetime.now(dt.timezone.utc):%Y-%m-%d %H:%M} UTC, commit {commit}, "
         f"load {os.getloadavg()[0]:.1f}, {a.trials} trials per world, seed {a.seed}")
    rows = []
    for w in a.worlds.split(","):
        rows += run_world(w.strip(), a.trials, a.seed)
    _say(table(rows))


if __name__ == "__main__":
    main()
