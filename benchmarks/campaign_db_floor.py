"""The database's own error floor in a finished campaign: its true horizons located as queries.

A campaign (``skyloc campaign --out RUN``) keeps the ray-marched true horizon of every hidden pose
(``truth.npz``, level, every 0.1 deg from grid north) and the database it located against (``db.zarr``).
Locating each true horizon, sampled at the database's azimuths, against that database measures what
the database and the matcher alone contribute to the campaign's position errors: the grid's
interpolation between nodes, the terrain levels, the horizon's quantisation.  What the campaign
loses beyond that floor is the image chain (render, detection, sampling).

    python -m benchmarks.campaign_db_floor RUN [RUN ...] [--north] [--no-fine] [--no-ground]

Prints one row per pose (error in metres, sigmas, status) and a summary per run.  Each true horizon is
seen at the pose's own heading (the rover's: its samples fall between the database's azimuths) with fine
samples every tenth of a step, as an extracted skyline carries them, so that the matcher's second pass
reads it on the database's azimuths (:mod:`board.locate.alignment`).  ``--no-fine`` leaves the fine samples
out (the database then interpolated between its azimuths, as before session 16); ``--north`` sees the
horizon at heading 0 instead, every sample on a database azimuth (before session 16 the only floor
measured).  On the flat Aristoteles floor (seed 48, horizons 25-37 km away, DEM features of 0.2-0.4 deg)
``--north`` and ``--no-fine`` differ: at heading 0 the 4 poses were 0.5-3.0 m off and `ok`; at their own
headings without fine samples 1.2-5.2 m and `ambiguous` (0.012 deg RMS of interpolation error at the true
position, 0.0034 deg on the database's azimuths); with fine samples (the default) 0.7-3.0 m and `ok` again.

A database that stores its nodes' ground heights (every database since session 26) moves the eye between
nodes by them; ``--no-ground`` ignores them and estimates the heights from the skylines (as every database
before): on Baltoro seed 112 that estimate read the slope's height steps at 26-57 % of their size, and the
floor's two worst poses were 3.49 and 2.71 m off instead of 0.07 and 0.47 m (docs/matching.md).

A database whose samples are box averages (``azimuth_subsamples`` > 1, every database since session 18) is
queried with the true horizons averaged the same way (:func:`observe_box`), a point-sampled one with point
samples: the floor is the database's own, not a sampling mismatch.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

#: fine samples per database step in the floor's queries (an extracted 3600 px panorama's: 0.1 deg)
FINE_PER_STEP = 10


#: sub-samples averaged per query sample when the database's samples are box averages (the truth is every
#: 0.1 deg: ten sub-samples cover a 1-degree step at its own resolution)
BOX_SUBSAMPLES = 10


def observe_box(az_deg: np.ndarray, el_deg: np.ndarray, *, heading_deg: float, n: int, start_deg: float,
                window_deg: float, k: int = BOX_SUBSAMPLES) -> np.ndarray:
    """:func:`board.match.synthetic.observe` averaged over ``window_deg`` centred on each of the ``n`` relative
    azimuths (``k`` sub-samples evenly across it; ``window_deg`` 0: point samples), as a box-sampled database
    or an extracted skyline holds the horizon (degrees)."""
    from board.match.synthetic import observe

    if window_deg <= 0:
        return observe(az_deg, el_deg, heading_deg=heading_deg, n=n, start_deg=start_deg)
    from board.skydb import box_offsets_deg

    offs = box_offsets_deg(k, window_deg)
    return np.mean([observe(az_deg, el_deg, heading_deg=heading_deg, n=n, start_deg=start_deg + o) for o in offs],
                   axis=0)


def truth_queries(run: Path, n_azimuth: int, start_deg: float, *, north: bool = False, fine: bool = True,
                  window_deg: float = 0.0) -> tuple[list[dict], np.ndarray, np.ndarray | None]:
    """The run's accepted poses, their true horizons (degrees) as a level mast sees them at the pose's
    heading (``north``: at heading 0) on ``n_azimuth`` relative azimuths from ``start_deg`` (the resampling
    the campaign's scoring applies to the truth, :func:`board.match.synthetic.observe`), and with ``fine``
    the same every ``1 / FINE_PER_STEP`` step (else None).  ``window_deg`` > 0: each sample the horizon
    averaged over that window centred on its azimuth (a box-sampled database's step: what the extraction's
    samples measure), else point samples."""
    poses = json.loads((run / "poses.json").read_text())["accepted"]
    truth = np.load(run / "truth.npz")["elevation_deg"].astype(np.float64)
    az = np.arange(truth.shape[1]) * 360.0 / truth.shape[1]
    heads = [0.0 if north else float(p["heading_deg"]) for p in poses]
    q = np.stack([observe_box(az, t, heading_deg=h, n=n_azimuth, start_deg=start_deg, window_deg=window_deg)
                  for h, t in zip(heads, truth)])
    qf = (np.stack([observe_box(az, t, heading_deg=h, n=n_azimuth * FINE_PER_STEP, start_deg=start_deg,
                                window_deg=window_deg) for h, t in zip(heads, truth)]) if fine else None)
    return poses, q, qf


def floor_rows(run: Path, *, north: bool = False, fine: bool = True, ground: bool = True) -> list[dict]:
    """One dict per pose: index, status, error_m, sigma_x_m, sigma_y_m, sigma_heading_deg, heading_error_deg,
    aligned_shift_deg (``north``, ``fine``: see :func:`truth_queries`; ``ground`` False: the store's ground
    heights ignored, the eye heights between nodes estimated from the skylines)."""
    from board.conventions import wrap_deg180
    from board.locate import locate
    from board.skydb import SkyDB
    from board.skyline import Skyline

    db = SkyDB.open(run / "db.zarr")
    window = db.meta.azimuth_step_deg if db.meta.azimuth_subsamples > 1 else 0.0   # query as the database samples
    poses, queries, fines = truth_queries(run, db.meta.n_azimuth, db.meta.azimuth_start_deg, north=north, fine=fine,
                                          window_deg=window)
    rows = []
    step = db.meta.azimuth_step_deg
    for i, (p, el) in enumerate(zip(poses, queries)):
        fe = None if fines is None else fines[i]
        sky = Skyline(el, db.meta.azimuth_start_deg, step, {}, fe, None if fe is None else step / FINE_PER_STEP)
        fix = locate(db, sky, mode="lost", stored_heights=ground)
        rows.append({"index": int(p["index"]), "status": fix.status,
                     "error_m": math.hypot(fix.x - p["x"], fix.y - p["y"]),
                     "sigma_x_m": fix.sigma_x_m, "sigma_y_m": fix.sigma_y_m, "sigma_heading_deg": fix.sigma_heading_deg,
                     "heading_error_deg": abs(float(wrap_deg180(fix.heading_deg - (0.0 if north else p["heading_deg"])))),
                     "aligned_shift_deg": fix.aligned_shift_deg})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="campaign output folders (with truth.npz, db.zarr)")
    ap.add_argument("--north", action="store_true",
                    help="see each horizon at heading 0 (samples on the database's azimuths) instead of the pose's")
    ap.add_argument("--no-fine", action="store_true",
                    help="no fine samples: the matcher reads the database between its azimuths (no second pass)")
    ap.add_argument("--no-ground", action="store_true",
                    help="ignore the database's ground heights: estimate the eye heights between nodes from the "
                         "skylines (every database before session 26)")
    a = ap.parse_args(argv)
    for run in a.runs:
        missing = [f for f in ("poses.json", "truth.npz", "db.zarr") if not (run / f).exists()]
        if missing:
            print(f"{run}: not a finished campaign folder (missing {', '.join(missing)})", file=sys.stderr)
            return 2
        rows = floor_rows(run, north=a.north, fine=not a.no_fine, ground=not a.no_ground)
        print(f"\n{run}: {len(rows)} true horizons ({'heading 0' if a.north else 'at the poses headings'}, "
              f"{'no' if a.no_fine else 'with'} fine samples, eye heights "
              f"{'estimated from the skylines' if a.no_ground else 'from the stored ground heights, if any'}) "
              "located against the campaign's database")
        print("| pose | status | error (m) | sigma x / y (m) | heading error (deg) |")
        print("| ---: | --- | ---: | --- | ---: |")
        for r in rows:
            print(f"| {r['index']} | {r['status']} | {r['error_m']:.2f} | {r['sigma_x_m']:.2f} / {r['sigma_y_m']:.2f} "
                  f"| {r['heading_error_deg']:.3f} |")
        e = np.array([r["error_m"] for r in rows])
        ok = sum(r["status"] == "ok" for r in rows)
        print(f"summary: error median {np.median(e):.2f} m, p90 {np.percentile(e, 90):.2f} m, max {e.max():.2f} m; "
              f"within 2.5 m {np.mean(e <= 2.5):.0%}, within 5 m {np.mean(e <= 5.0):.0%}; "
              f"{ok} of {len(rows)} ok; heading error max {max(r['heading_error_deg'] for r in rows):.3f} deg")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
