"""The database's own error floor at a campaign's poses: each true horizon located as a query.

A campaign keeps the ray-marched true horizon of every hidden pose (``truth.npz``, level, every 0.1 deg
from grid north) and the database it located against (``db.zarr``).  Locating each true horizon, sampled
at the database's azimuths, against that database measures what the database and the matcher alone
contribute to the campaign's position errors: the grid's interpolation between nodes, the terrain levels,
the horizon's quantisation, and the site itself (a hollow whose walls constrain the position poorly gives
a wide, ``ambiguous`` fix even from the exact horizon).  What a case loses beyond its pose's floor is the
image chain (render, detection, sampling).  The campaign writes it beside every case it located against
that database (``floor_error_m``, ``floor_status`` in results.csv; ``floor`` in summary.json), and
``python -m benchmarks.campaign_db_floor RUN`` prints it for a finished run.

Each true horizon is seen at the pose's own heading (the rover's: its samples fall between the database's
azimuths) with fine samples every tenth of a step, as an extracted skyline carries them, so that the
matcher's second pass reads it on the database's azimuths (:mod:`board.locate.alignment`).  A database of
box-averaged samples is queried with the true horizons averaged the same way (:func:`observe_box`).
Metres and degrees; x, y in the DEM's metric CRS.
"""
from __future__ import annotations

import json
import math
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
                     "heading_error_deg": abs(float(wrap_deg180(fix.heading_deg
                                                                - (0.0 if north else p["heading_deg"])))),
                     "aligned_shift_deg": fix.aligned_shift_deg})
    return rows


def floor_summary(rows: list[dict]) -> dict:
    """Site-level figures of :func:`floor_rows`' rows: the error's median, p90 and max (m), how many fixes are
    ``ok``, and the poses whose true horizon alone lands beyond 2.5 m or is not ``ok`` (``limited_poses``: their
    places in ``poses.json``'s accepted list, the ``pNN`` of the case names): there the site or the database,
    not the image chain, limits the campaign."""
    e = np.array([r["error_m"] for r in rows], dtype=float)
    if e.size == 0:
        return {"n": 0}
    return {"n": int(e.size), "error_m_median": round(float(np.median(e)), 4),
            "error_m_p90": round(float(np.percentile(e, 90)), 4), "error_m_max": round(float(e.max()), 4),
            "ok": sum(r["status"] == "ok" for r in rows),
            "limited_poses": [k for k, r in enumerate(rows) if r["error_m"] > 2.5 or r["status"] != "ok"]}
