"""The 84-trial locate pool: the fixed set of queries that says whether a change to ``board.locate`` moved a result.

84 ray-marched, off-grid queries of the matcher benchmark's world (the 1 x 1 km database at 5 m on
``procedural:mars:7``, see :mod:`benchmarks.bench_match`): 60 lost-in-space queries (15 each of
360, 242, 120 and 65 degrees of panorama, pitch and roll uniform in +-5 degrees, noise 0.05 deg)
and 24 heading-mode queries (8 each with the prior position 0, 10 and 20 m off).  Every draw comes
from one seeded generator, so the pool is the same on every run.

``python -m benchmarks.locate_pool --out pool.json`` writes every fix (JSON) and prints the medians;
``--compare OLD.json`` also prints the largest difference of each field against an earlier run (the
check that a refactoring left the results alone).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks.bench_match import _query, _world


def _say(msg: str) -> None:
    sys.stdout.write(msg + "\n")
    sys.stdout.flush()


def run_pool() -> list[dict]:
    """The 84 fixes with their truth (metres in the database CRS, degrees)."""
    from board.conventions import wrap_deg180
    from board.locate import locate

    db, horizon = _world(1000.0, 5.0)
    rng = np.random.default_rng(84)
    x0, y0, x1, y1 = db.grid.bounds()
    out = []
    trials = [("lost", arc, 0.0) for arc in (360, 242, 120, 65) for _ in range(15)]
    trials += [("heading", 360, off) for off in (0.0, 10.0, 20.0) for _ in range(8)]
    for mode, arc, off in trials:
        m = 60.0 if mode == "heading" else 20.0
        x, y = rng.uniform(x0 + m, x1 - m), rng.uniform(y0 + m, y1 - m)
        h = rng.uniform(0, 360)
        sky = _query(horizon, x, y, heading=h, pitch=rng.uniform(-5, 5), roll=rng.uniform(-5, 5), arc=arc,
                     arc_start=rng.uniform(0, 360), rng=rng)
        kw = {}
        if mode == "heading":
            a = rng.uniform(0, 2 * np.pi)
            kw = dict(prior_xy=(x + off * math.cos(a), y + off * math.sin(a)), heading_prior_deg=h + rng.uniform(-8, 8))
        f = locate(db, sky, mode=mode, **kw)
        d = f.to_json_dict()
        d.update(truth_x=x, truth_y=y, truth_heading_deg=h, arc_deg=arc, prior_offset_m=off,
                 error_m=math.hypot(f.x - x, f.y - y) if mode != "heading" else 0.0,
                 heading_error_deg=abs(float(wrap_deg180(f.heading_deg - h))))
        out.append(d)
    return out


def summary(rows: list[dict]) -> str:
    """Median position and heading errors per group and the count of ``ok`` fixes."""
    lines = []
    groups: dict[str, list[dict]] = {}
    for r in rows:
        key = f"{r['mode']} {r['arc_deg']} deg" if r["mode"] == "lost" else f"heading {r['prior_offset_m']:g} m"
        groups.setdefault(key, []).append(r)
    for key, g in groups.items():
        e = np.array([r["error_m"] for r in g])
        h = np.array([r["heading_error_deg"] for r in g])
        ok = sum(r["status"] == "ok" for r in g)
        lines.append(f"| {key} | {len(g)} | {np.median(e):.4f} | {e.max():.4f} | {np.median(h):.4f} | {h.max():.4f} "
                     f"| {ok} |")
    return ("| group | n | median error m | max error m | median heading error deg | max heading error deg | ok |\n"
            "|---|---|---|---|---|---|---|\n" + "\n".join(lines))


def compare(old: list[dict], new: list[dict]) -> dict[str, float]:
    """Largest absolute difference of every numeric field, and the number of status changes."""
    diff: dict[str, float] = {"status_changes": float(sum(a["status"] != b["status"] for a, b in zip(old, new)))}
    for a, b in zip(old, new):
        for k, va in a.items():
            vb = b.get(k)
            if isinstance(va, (int, float)) and isinstance(vb, (int, float)) and k != "elapsed_s":
                diff[k] = max(diff.get(k, 0.0), abs(float(va) - float(vb)))
    return diff


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="JSON file for the 84 fixes")
    ap.add_argument("--compare", type=Path, default=None, help="an earlier run's JSON to compare with")
    a = ap.parse_args()
    t = time.perf_counter()
    rows = run_pool()
    a.out.write_text(json.dumps(rows, indent=1))
    _say(f"84-trial pool in {time.perf_counter() - t:.0f} s -> {a.out}\n")
    _say(summary(rows))
    if a.compare is not None:
        d = compare(json.loads(a.compare.read_text()), rows)
        _say("\nlargest difference against " + str(a.compare) + ": "
             + ", ".join(f"{k} {v:.3g}" for k, v in sorted(d.items()) if v or k == "status_changes"))


if __name__ == "__main__":
    main()
