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
import sys
from pathlib import Path

import numpy as np

# the floor's code is the campaign's own (it writes the floor beside every case): this is its command line
from render_service.campaign.floor import floor_rows


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
