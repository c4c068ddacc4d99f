"""Benchmark of the matcher (issue 3): `make bench-match`.

1. A 1 x 1 km database at 5 m (201 x 201 = 40,401 positions x 360 azimuths) ray-marched on the
   20 x 20 km procedural Mars DEM ``procedural:mars:7`` (cached in .cache/bench_match).
2. Speed, warm (second and later queries on one open database, which SkyDB keeps in memory as
   int16 when it fits its cache, 64 MB by default; also without that cache): ``locate`` in
   lost-in-space mode with a full and a 242-degree query, next to the report's brute force in the
   same run, twice: vectorised over the headings of a position, and written as the report's
   matcher works (loop over positions and headings, ``np.roll`` per heading; timed on a random
   subset of positions and extrapolated linearly).
3. 7 x 7 km at 5 m (1401 x 1401 = 1.96 M positions): a synthetic store made of the 1 km
   database's tiles, each copy rotated in azimuth by a random whole number of samples and given
   a smooth random perturbation (so no two copies are identical); one lost-in-space query, run
   in a child process under ``/usr/bin/time -v`` for its wall time and peak RSS.
4. Accuracy tables shaped like the report's tables 4 (tilt), 5 (partial panoramas) and 8
   (heading from a wrong position), with ray-marched off-grid queries on the 1 km database.

The machine has 2 cores shared with other jobs: times are noisy; the ratio to the brute force
is measured in the same run.  Prints markdown tables.

Usage: python -m benchmarks.bench_match [--quick] [--no-7x7] [--no-brute] [--no-accuracy] [--only-7x7] [--trials N]
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

CACHE = Path(os.environ.get("SKYLOC_BENCH_CACHE", Path(__file__).resolve().parents[1] / ".cache" / "bench_match"))
DEM_SPEC = "procedural:mars:7"
CENTER = (2.5, 2.5)


def _say(msg: str) -> None:
    sys.stdout.write(msg + "\n")
    sys.stdout.flush()


def brute_force_report(db_el: np.ndarray, query: np.ndarray) -> tuple[int, int, float]:
    """The report's matcher in plain numpy: every position, every heading, mean offset removed.

    db_el : (P, N) database skylines; query : (N,) with NaN where unseen.
    Returns (best position index, best shift, best score).
    """
    n = query.size
    seen = np.isfinite(query)
    e = query[seen]
    idx = (np.arange(n)[None, :] + np.arange(n)[:, None]) % n  # idx[a, j] = (j + a) mod N
    idx = idx[:, seen]
    best = (0, 0, np.inf)
    for p in range(db_el.shape[0]):
        r = e[None, :] - db_el[p][idx]
        r -= r.mean(axis=1, keepdims=True)
        s = (r * r).sum(axis=1)
        a = int(np.argmin(s))
        if s[a] < best[2]:
            best = (p, a, float(s[a]))
    return best


def brute_force_loop(db_el: np.ndarray, query: np.ndarray, positions: np.ndarray) -> tuple[int, int, float]:
    """The report's matcher as written there: a loop over positions and headings, ``np.roll`` of the
    database skyline per heading, mean offset removed, numpy per heading.

    db_el : (P, N) database skylines; query : (N,) with NaN where unseen; positions : row indices of
    ``db_el`` to visit.  Returns (best position index, best shift, best score).
    """
    n = query.size
    seen = np.isfinite(query)
    e = query[seen]
    best = (0, 0, np.inf)
    for p in positions:
        for a in range(n):
            d = e - np.roll(db_el[p], -a)[seen]  # query sample j against database sample j + a
            d = d - d.mean()
            score = float(np.sum(d * d))
            if score < best[2]:
                best = (int(p), a, score)
    return best


def _world(size_m: float, step_m: float):
    from blender_addon.terrain.dem import resolve_dem
    from render_service.dbrender import load_terrain, prepare_job, render_database
    from render_service.renderers.base import RenderSpec
    from render_service.renderers.raymarch import render_positions

    CACHE.mkdir(parents=True, exist_ok=True)
    dem = resolve_dem(DEM_SPEC)
    spec = RenderSpec(camera_height_m=2.0, n_azimuth=360)
    out = CACHE / f"db_{int(size_m)}m_{int(step_m)}m.zarr"
    t = time.perf_counter()
    db = render_database(dem, center_xy=CENTER, size_m=size_m, step_m=step_m, spec=spec, out=out,
                         terrain_dir=CACHE / f"terrain_{int(size_m)}", progress=True)
    _say(f"database {out}: {db.grid.nx} x {db.grid.ny} positions ({time.perf_counter() - t:.1f} s incl. cache)")
    job = prepare_job(dem, center_xy=CENTER, size_m=size_m, step_m=step_m, spec=spec)
    terrain = load_terrain(job, terrain_dir=CACHE / f"terrain_{int(size_m)}")
    fine = RenderSpec(camera_height_m=2.0, n_azimuth=1440, body_radius_m=db.meta.body_radius_m)

    def horizon(x, y):
        el, _ = render_positions(terrain, np.array([x]), np.array([y]), fine)
        return fine.azimuths_deg(), el[0].astype(np.float64)

    return db, horizon


def _query(horizon, x, y, *, heading, pitch=0.0, roll=0.0, noise=0.05, arc=360.0, arc_start=0.0, rng=None):
    from board.match.synthetic import mask_arc, observe
    from board.skyline import Skyline

    az, el = horizon(x, y)
    q = observe(az, el, heading_deg=heading, pitch_deg=pitch, roll_deg=roll)
    if noise:
        q = q + rng.normal(0, noise, q.size)
    if arc < 360:
        q = mask_arc(q, start_deg=arc_start, width_deg=arc)
    return Skyline(q)


def speed(db, horizon, *, brute: bool, repeats: int = 5, loop_positions: int = 400) -> list[dict]:
    """Warm ``locate`` times of a full and a 242-degree query, next to the report's brute force in the same run.

    ``db`` keeps its int16 elevations in memory (SkyDB's default cache, the 1 km database is 29 MB):
    the warm figure.  The "no cache" figure reopens the store with ``cache_mb=0``: every query reads
    and decompresses the chunk files again (from the OS page cache).  The loop brute force visits
    ``loop_positions`` random positions and is extrapolated linearly to the whole grid.
    """
    from board.locate import locate
    from board.skydb import SkyDB

    rng = np.random.default_rng(1)
    x0, y0, x1, y1 = db.grid.bounds()
    x, y = rng.uniform(x0 + 50, x1 - 50), rng.uniform(y0 + 50, y1 - 50)
    h = 123.4
    rows = []
    all_el = None
    nocache = SkyDB.open(db.path, cache_mb=0)

    def median_time(dbx, sky, **kw):
        locate(dbx, sky, **kw)  # warm-up (OS and in-process caches, FFT plans)
        return float(np.median([locate(dbx, sky, **kw).elapsed_s for _ in range(repeats)]))

    for name, arc in (("full 360 deg", 360.0), ("242 deg", 242.0)):
        sky = _query(horizon, x, y, heading=h, pitch=0.0, roll=0.0, arc=arc, arc_start=-121.0, rng=rng)
        fix = locate(db, sky)
        row = {"query": name, "positions": db.grid.n_positions, "locate_s": median_time(db, sky),
               # the same exact search with the report's offset-only metric, to compare like with like
               "locate_offset_model_s": median_time(db, sky, model="offset"),
               "locate_nocache_s": median_time(nocache, sky),
               "error_m": math.hypot(fix.x - x, fix.y - y), "status": fix.status}
        if brute:
            if all_el is None:
                all_el = db.read_all().reshape(-1, 360).astype(np.float64)
            t = time.perf_counter()
            p, a, s = brute_force_report(all_el, sky.elevation_deg)
            row["brute_s"] = time.perf_counter() - t
            i, j = divmod(p, db.grid.nx)
            bx, by = db.grid.xy(i, j)
            row["brute_error_m"] = math.hypot(bx - x, by - y)
            sub = np.random.default_rng(7).choice(all_el.shape[0], size=loop_positions, replace=False)
            t = time.perf_counter()
            brute_force_loop(all_el, sky.elevation_deg, sub)
            row["loop_s"] = (time.perf_counter() - t) * all_el.shape[0] / loop_positions
            row["loop_positions"] = loop_positions
        rows.append(row)
    return rows


def make_7x7(db, path: Path, *, seed: int = 0) -> Path:
    """A 1401 x 1401 store from the 1 km database's tiles (rotated, perturbed copies); tile (0, 0) unchanged."""
    from tqdm import tqdm

    from board.skydb import GridSpec, SkyDBMeta, SkyDBWriter

    if (path / "zarr.json").is_file():
        try:
            from board.skydb import SkyDB

            if SkyDB.open(path).complete:
                return path
        except Exception:  # noqa: BLE001 - rebuild a damaged cache
            pass
    shutil.rmtree(path, ignore_errors=True)
    g1 = db.grid
    step = abs(g1.geotransform[1])
    gt = g1.geotransform
    grid = GridSpec((gt[0], step, 0.0, gt[3], 0.0, -step), 1401, 1401, g1.crs_wkt)
    meta = SkyDBMeta(grid=grid, camera_height_m=db.meta.camera_height_m, n_azimuth=360,
                     body_radius_m=db.meta.body_radius_m, renderer="synthetic-tiled-copies",
                     tile_size=db.meta.tile_size, extra={"source": str(db.path)})
    w = SkyDBWriter.create(path, meta)
    src = db.read_all()
    rng = np.random.default_rng(seed)
    k = np.arange(360)
    for t in tqdm(w.tiles, desc="7x7 km store", unit="tile"):
        r0, c0 = t.row0 % (g1.ny - t.nrows + 1), t.col0 % (g1.nx - t.ncols + 1)
        block = src[r0:r0 + t.nrows, c0:c0 + t.ncols].astype(np.float64)
        if (t.ti, t.tj) != (0, 0):
            block = np.roll(block, int(rng.integers(1, 360)), axis=2)
            pert = sum(rng.uniform(0.2, 1.0) * np.sin(2 * np.pi * m * k / 360 + rng.uniform(0, 2 * np.pi))
                       for m in (2, 3, 5))
            block = block + pert
        w.write_tile(t, block)
    w.finalize()
    return path


def run_7x7(db, horizon, path: Path) -> dict:
    """One lost-in-space query on the 7 x 7 km store in a child process under /usr/bin/time -v."""
    rng = np.random.default_rng(3)
    x0, y0, _, _ = db.grid.bounds()
    # a position inside tile (0, 0) of the big store, which is the 1 km database's tile (0, 0)
    x, y = x0 + 100.0 + rng.uniform(0, 150), db.grid.bounds()[3] - 100.0 - rng.uniform(0, 150)
    sky = _query(horizon, x, y, heading=77.0, pitch=3.0, roll=-2.0, arc=242.0, arc_start=-121.0, rng=rng)
    qpath = CACHE / "query_7x7.json"
    sky.save(qpath)
    out = CACHE / "fix_7x7.json"
    cmd = ["/usr/bin/time", "-v", sys.executable, "-m", "skyloc.cli", "locate", "--db", str(path), "--skyline",
           str(qpath), "--out", str(out)]
    t = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if res.returncode != 0:
        raise RuntimeError(f"7x7 query failed: {res.stderr[-2000:]}")
    rss_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", res.stderr).group(1))
    fix = json.loads(out.read_text())
    size = sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
    return {"positions": 1401 * 1401, "wall_s": wall, "locate_s": fix["elapsed_s"], "peak_rss_mb": rss_kb / 1024,
            "error_m": math.hypot(fix["x"] - x, fix["y"] - y), "status": fix["status"],
            "store_gb": size / 1e9}


def accuracy(db, horizon, trials: int) -> dict:
    from board.conventions import wrap_deg180
    from board.locate import locate

    rng = np.random.default_rng(42)
    x0, y0, x1, y1 = db.grid.bounds()

    def pos(margin=20.0):
        return rng.uniform(x0 + margin, x1 - margin), rng.uniform(y0 + margin, y1 - margin)

    def stats(rows):
        d = np.array([r[0] for r in rows])
        hd = np.array([r[1] for r in rows])
        st = [r[2] for r in rows]
        ok = np.array([s == "ok" for s in st])
        return {"median_m": float(np.median(d)), "p90_m": float(np.percentile(d, 90)), "max_m": float(d.max()),
                "median_heading_deg": float(np.median(hd)), "max_heading_deg": float(hd.max()),
                "ok": int(ok.sum()), "n": len(rows), "ok_max_m": float(d[ok].max()) if ok.any() else float("nan"),
                "ok_max_heading_deg": float(hd[ok].max()) if ok.any() else float("nan")}

    tables = {"tilt": {}, "partial": {}, "heading": {}}
    for label, (p, r) in {"level": (0, 0), "pitch 5": (5, 0), "roll 5": (0, 5), "pitch 10": (10, 0),
                          "roll 10": (0, 10), "pitch 7 roll 7": (7, 7)}.items():
        rows = []
        for _ in range(trials):
            x, y = pos()
            h = rng.uniform(0, 360)
            f = locate(db, _query(horizon, x, y, heading=h, pitch=p, roll=r, rng=rng))
            rows.append((math.hypot(f.x - x, f.y - y), abs(float(wrap_deg180(f.heading_deg - h))), f.status))
        tables["tilt"][label] = stats(rows)
    for arc in (360, 242, 120, 65):
        rows = []
        for _ in range(trials):
            x, y = pos()
            h = rng.uniform(0, 360)
            f = locate(db, _query(horizon, x, y, heading=h, pitch=rng.uniform(-5, 5), roll=rng.uniform(-5, 5),
                                  arc=arc, arc_start=rng.uniform(0, 360), rng=rng))
            rows.append((math.hypot(f.x - x, f.y - y), abs(float(wrap_deg180(f.heading_deg - h))), f.status))
        tables["partial"][f"{arc} deg"] = stats(rows)
    for off in (0, 5, 10, 15, 20):
        rows = []
        for _ in range(trials):
            x, y = pos(60.0)
            h = rng.uniform(0, 360)
            a = rng.uniform(0, 2 * np.pi)
            f = locate(db, _query(horizon, x, y, heading=h, pitch=rng.uniform(-5, 5), roll=rng.uniform(-5, 5), rng=rng),
                       mode="heading", prior_xy=(x + off * math.cos(a), y + off * math.sin(a)),
                       heading_prior_deg=h + rng.uniform(-8, 8))
            rows.append((0.0, abs(float(wrap_deg180(f.heading_deg - h))), f.status))
        tables["heading"][f"{off} m"] = stats(rows)
    return tables


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a 300 m database, no 7 x 7 km, 3 trials")
    ap.add_argument("--no-7x7", action="store_true")
    ap.add_argument("--no-brute", action="store_true")
    ap.add_argument("--no-accuracy", action="store_true")
    ap.add_argument("--trials", type=int, default=10)
    ap.add_argument("--only-7x7", action="store_true", help="only the 7 x 7 km lost-in-space query")
    a = ap.parse_args()
    size = 300.0 if a.quick else 1000.0
    trials = 3 if a.quick else a.trials
    _say(f"# bench_match {dt.datetime.now(dt.timezone.utc).isoformat(timespec='minutes')} "
         f"(2 shared cores: times are noisy)")
    db, horizon = _world(size, 5.0)
    load0 = os.getloadavg()
    rows = [] if a.only_7x7 else speed(db, horizon, brute=not a.no_brute)
    if rows:
        _say(f"\nload average {load0[0]:.1f} at the start, {os.getloadavg()[0]:.1f} at the end of the speed runs; "
             "locate: median of 5 warm calls; 'no cache': SkyDB.open(cache_mb=0), chunks read and decompressed "
             "on every call; brute force 'vectorised': 360 headings of a position as one array, all positions; "
             f"'loop': position by position, heading by heading with np.roll, "
             f"{rows[0].get('loop_positions', 0)} random positions extrapolated to the grid\n")
        _say("| query | positions | locate s (tilt model, default) | locate s (offset model) "
             "| locate s (no cache, tilt) | brute force vectorised s | ratio vectorised / locate (tilt, offset) "
             "| brute force loop s | ratio loop / locate (tilt, offset) | fix error m | brute-force error m |")
        _say("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        nan = float("nan")
        b, lp = r.get("brute_s", nan), r.get("loop_s", nan)
        t_tilt, t_off = r["locate_s"], r["locate_offset_model_s"]
        _say(f"| {r['query']} | {r['positions']:,} | {t_tilt:.3f} | {t_off:.3f} | {r['locate_nocache_s']:.3f} | "
             f"{b:.1f} | {b / t_tilt:.0f}x, {b / t_off:.0f}x | {lp:.0f} | {lp / t_tilt:.0f}x, {lp / t_off:.0f}x | "
             f"{r['error_m']:.2f} | {r.get('brute_error_m', nan):.2f} |")
    if not (a.quick or a.no_7x7):
        path = make_7x7(db, CACHE / "db_7x7km_5m.zarr")
        r = run_7x7(db, horizon, path)
        _say("\n| 7 x 7 km lost in space | positions | locate s | process wall s | peak RSS MB | store GB | "
             "fix error m | status |")
        _say("|---|---|---|---|---|---|---|---|")
        _say(f"| 242 deg, pitch 3 roll -2 | {r['positions']:,} | {r['locate_s']:.1f} | {r['wall_s']:.1f} | "
             f"{r['peak_rss_mb']:.0f} | {r['store_gb']:.2f} | {r['error_m']:.2f} | {r['status']} |")
    if not (a.no_accuracy or a.only_7x7):
        t = accuracy(db, horizon, trials)
        for name, title in (("tilt", "Table 4 shape: full panorama, lost in space, tilt"),
                            ("partial", "Table 5 shape: partial panoramas, lost in space, tilt up to 5 deg"),
                            ("heading", "Table 8 shape: heading mode from a wrong position, tilt up to 5 deg")):
            _say(f"\n{title} ({trials} ray-marched off-grid queries each, noise 0.05 deg)\n")
            _say("| case | median error m | p90 m | max m | median heading error deg | max heading error deg | "
                 "status ok | max error of ok fixes m | max heading error of ok fixes deg |")
            _say("|---|---|---|---|---|---|---|---|---|")
            for k, s in t[name].items():
                _say(f"| {k} | {s['median_m']:.2f} | {s['p90_m']:.2f} | {s['max_m']:.2f} | "
                     f"{s['median_heading_deg']:.2f} | {s['max_heading_deg']:.2f} | {s['ok']}/{s['n']} | "
                     f"{s['ok_max_m']:.2f} | {s['ok_max_heading_deg']:.2f} |")


if __name__ == "__main__":
    main()
