"""Where a campaign's position errors come from: the extraction error's sub-pixel phase bias and its
smooth and rough parts, each located alone against the campaign's database.

Input: a finished campaign (``RUN``: ``poses.json``, ``truth.npz``, ``db.zarr``, the cases' rows) and the
per-case rows of ``python -m benchmarks.campaign_reextract RUN --out rows.json`` (their ``err_deg``: the
extracted minus the true skyline, degrees, on the database's azimuths in the mast frame).

* **Phase bias**: the mean extraction error against where the true horizon falls inside its pixel row
  (0 = the row's centre, 0.5 = the boundary with the row below).  A sub-pixel estimator that is pulled
  towards its samples shows a sine of that phase; along a level horizon the phase changes slowly, so
  that bias is smooth in azimuth and moves the fix.
* **Smooth / rough**: each case's error is split by a circular Gaussian low-pass in azimuth (``--width``
  degrees, default 10) and the truth plus each part is located lost in space; the truth alone is the
  database floor (``benchmarks.campaign_db_floor``).  Which part keeps a fix beyond 2.5 m says where to
  work: a smooth error is a bias (light, optics, estimator), a rough one is noise (the renders' Monte
  Carlo noise, the sensor).

* **By distance** (``--by-distance``): the extraction error by the distance of the true horizon (ray-marched
  again from the campaign's terrain: where along each azimuth the horizon is), and the truth plus the error
  of the near horizon only (closer than ``--near-m``, default 8 km), of the far horizon only, and of the
  case's median error only (a constant offset), each located alone; and what a matcher could do about the far
  horizon: the whole error with a free offset for the far horizon (or one for each), and the near horizon's
  samples alone (:func:`distance_parts`).  A near horizon moves with the rover and
  fixes its position; a far one (tens of km) barely moves, and its error reaches the position through the
  heading and the tilt, more so on a partial arc.

    python -m benchmarks.campaign_error_anatomy RUN rows.json [--looks clean,realistic] [--width 10]
        [--by-distance [--near-m 8000]]
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np


def circular_lowpass(e: np.ndarray, width_deg: float, step_deg: float) -> np.ndarray:
    """``e`` (one value per ``step_deg`` around the circle) smoothed by a Gaussian of ``width_deg`` sigma."""
    n = e.size
    k = np.arange(n)
    d = np.minimum(k, n - k) * step_deg
    g = np.exp(-0.5 * (d / width_deg) ** 2)
    g /= g.sum()
    return np.real(np.fft.ifft(np.fft.fft(e) * np.fft.fft(g)))


def _truth_for(run: Path, row: dict, n: int) -> tuple[np.ndarray, dict]:
    from render_service.campaign import scoring

    poses = json.loads((run / "poses.json").read_text())["accepted"]
    k = [int(p["index"]) for p in poses].index(int(row["pose"]))
    case = json.loads((run / "cases" / row["case_id"] / "row.json").read_text())
    el = np.load(run / "truth.npz")["elevation_deg"][k].astype(np.float64)
    truth = scoring.true_skyline(el, heading_deg=float(case["true_heading_deg"]), pitch_deg=float(row.get("pitch_deg") or 0),
                                 roll_deg=float(row.get("roll_deg") or 0), n_azimuth=n)
    return truth, case


def phase_bias(run: Path, rows: list[dict], n_bins: int = 10) -> list[tuple[float, float, int]]:
    """(phase bin centre, mean error in pixels (median of each case removed), samples) over ``rows``."""
    errs, phases = [], []
    for r in rows:
        e = np.asarray(r["err_deg"], dtype=np.float64)
        truth, _ = _truth_for(run, r, e.size)
        pm = json.loads((run / "cases" / r["case_id"] / "panorama" / "panorama.json").read_text())
        step = float(pm["elevation_step_deg"])
        rt = (float(pm["elevation_row0_deg"]) - truth) / step
        ok = np.isfinite(e) & np.isfinite(rt)
        errs.append((e[ok] - np.median(e[ok])) / step)
        phases.append(rt[ok] - np.floor(rt[ok]))
    e, f = np.concatenate(errs), np.concatenate(phases)
    out = []
    for k in range(n_bins):
        m = (f >= k / n_bins) & (f < (k + 1) / n_bins)
        out.append(((k + 0.5) / n_bins, float(e[m].mean()) if m.any() else float("nan"), int(m.sum())))
    return out


def _locate_parts(run: Path, rows: list[dict], parts) -> list[dict]:
    """Per case, the position error (m) and heading error (deg) of each query ``parts(row, truth, e)`` names
    (``e``: the case's extraction error, NaN where masked; each query is NaN where ``e`` is), located lost in
    space against the campaign's database, beside the campaign's own (``image``)."""
    from board.locate import locate
    from board.locate.truth import Truth, compare_with_truth
    from board.skydb import SkyDB
    from board.skyline import Skyline

    db = SkyDB.open(run / "db.zarr")
    out = []
    for r in rows:
        e = np.asarray(r["err_deg"], dtype=np.float64)
        step = 360.0 / e.size
        truth, case = _truth_for(run, r, e.size)
        ok = np.isfinite(e)
        t = Truth(float(case["true_x"]), float(case["true_y"]), float(case["true_heading_deg"]))
        res = {"case_id": r["case_id"], "preset": r["preset"], "image": float(r["error_m"]),
               "heading_image": float(r.get("heading_error_deg", 0.0)),
               "sigma_m": math.hypot(r.get("sigma_x_m", 0.0), r.get("sigma_y_m", 0.0))}
        for name, q in parts(r, truth, e):
            q = np.where(ok, q, np.nan)
            if not np.isfinite(q).any():
                res[name], res["heading_" + name] = math.inf, math.inf
                continue
            fix = locate(db, Skyline(q, 0.0, step), mode="lost")
            c = compare_with_truth(fix, t)
            res[name], res["heading_" + name] = c.error_m, abs(c.heading_error_deg)
        out.append(res)
    return out


def split_rows(run: Path, rows: list[dict], width_deg: float) -> list[dict]:
    """Per case: the position error (m) of the truth, truth + smooth error, truth + rough error, and the campaign's."""
    def parts(r, truth, e):
        e0 = np.where(np.isfinite(e), e, 0.0)
        smooth = circular_lowpass(e0, width_deg, 360.0 / e.size)
        return (("truth", truth), ("smooth", truth + smooth), ("rough", truth + e0 - smooth))

    return _locate_parts(run, rows, parts)


#: distance bands of the extraction error table (metres)
DISTANCE_BANDS_M = (0.0, 2_000.0, 8_000.0, 32_000.0, math.inf)


def mast_frame_values(az_deg: np.ndarray, el_deg: np.ndarray, values: np.ndarray, *, heading_deg: float,
                      pitch_deg: float = 0.0, roll_deg: float = 0.0, n: int = 360) -> np.ndarray:
    """A per-direction quantity of an ENU horizon (``values`` at the fine ENU azimuths ``az_deg`` and horizon
    elevations ``el_deg``, degrees) on ``n`` mast-frame azimuths from 0: each takes the value of the horizon
    direction nearest to it in the mast frame (the rotation of :func:`board.match.synthetic.observe`, which
    gives the true skyline itself; nearest, not interpolated: a distance jumps where one ridge hides another)."""
    from board.conventions import azimuth_grid_deg, enu_from_az_el_deg, rotation_enu_from_camera
    from board.pose.sphere import rel_az_el_from_body

    v = enu_from_az_el_deg(az_deg, el_deg) @ rotation_enu_from_camera(heading_deg, pitch_deg, roll_deg)
    th, _ = rel_az_el_from_body(v)
    th = np.mod(th, 360.0)
    order = np.argsort(th)
    th, vals = th[order], np.asarray(values)[order]
    q = azimuth_grid_deg(n, 0.0)
    i = np.searchsorted(th, q) % th.size
    j = (i - 1) % th.size
    di = np.abs((th[i] - q + 180.0) % 360.0 - 180.0)
    dj = np.abs((th[j] - q + 180.0) % 360.0 - 180.0)
    return np.where(di <= dj, vals[i], vals[j])


def horizon_distances(run: Path, rows: list[dict]) -> dict[str, np.ndarray]:
    """Per case id, the true horizon's distance (metres) on the case's mast-frame azimuths (``err_deg``'s
    grid), ray-marched again from the campaign's terrain (``terrain/truth``) at each pose."""
    from board.conventions import body_from_name
    from render_service.campaign.tasks import TRUTH_N_AZIMUTH, truth_task

    args = json.loads((run / "campaign.json").read_text())["arguments"]
    body = args.get("body") or json.loads((run / "summary.json").read_text())["campaign"]["body"]
    height = float(args["profile"]["camera_height_m"])
    poses = {int(p["index"]): p for p in json.loads((run / "poses.json").read_text())["accepted"]}
    wanted = sorted({int(r["pose"]) for r in rows})
    rays = truth_task(str(run / "terrain" / "truth"), [(poses[i]["x"], poses[i]["y"]) for i in wanted], height,
                      body_from_name(body).radius_m)
    horizon = dict(zip(wanted, rays))
    az = np.arange(TRUTH_N_AZIMUTH) * 360.0 / TRUTH_N_AZIMUTH
    out = {}
    for r in rows:
        el, dist = horizon[int(r["pose"])]
        _, case = _truth_for(run, r, len(r["err_deg"]))
        out[r["case_id"]] = mast_frame_values(az, el.astype(np.float64), dist.astype(np.float64),
                                              heading_deg=float(case["true_heading_deg"]),
                                              pitch_deg=float(r.get("pitch_deg") or 0.0),
                                              roll_deg=float(r.get("roll_deg") or 0.0), n=len(r["err_deg"]))
    return out


def distance_table(rows: list[dict], dists: dict[str, np.ndarray],
                   bands: tuple[float, ...] = DISTANCE_BANDS_M) -> list[dict]:
    """Kept samples' extraction error per band of horizon distance: count, median (deg, signed), spread
    (median absolute deviation about it, deg) and the shares more than 0.05 and 0.1 deg off."""
    e = np.concatenate([np.asarray(r["err_deg"], dtype=np.float64) for r in rows])
    d = np.concatenate([dists[r["case_id"]] for r in rows])
    ok = np.isfinite(e) & np.isfinite(d)
    e, d = e[ok], d[ok]
    out = []
    for lo, hi in zip(bands[:-1], bands[1:]):
        m = (d >= lo) & (d < hi)
        if not m.any():
            continue
        em = e[m]
        med = float(np.median(em))
        out.append({"from_m": lo, "to_m": hi, "samples": int(m.sum()), "median_deg": med,
                    "mad_deg": float(np.median(np.abs(em - med))), "over_0_05": float(np.mean(np.abs(em) > 0.05)),
                    "over_0_1": float(np.mean(np.abs(em) > 0.1))})
    return out


def distance_parts(truth: np.ndarray, e: np.ndarray, near: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """The queries :func:`split_by_distance` locates for one case (degrees; NaN for ``near_only`` beyond the
    near horizon; :func:`_locate_parts` masks the samples the extraction masked in all of them): the truth;
    plus the near horizon's error only (``near``), the far one's only (``far``), the case's median error
    (``offset``); the whole error with the far horizon's median taken out (``far_offset``: what a free offset term for the far horizon could do at best), with both
    horizons' medians taken out (``near_far_offsets``), and the near horizon's samples alone (``near_only``:
    the most a weighting that trusts the far horizon less can give)."""
    ok = np.isfinite(e)
    e0 = np.where(ok, e, 0.0)

    def median(m: np.ndarray) -> float:
        return float(np.median(e[m])) if m.any() else 0.0

    fm, nm = median(ok & ~near), median(ok & near)
    return [("truth", truth), ("near", truth + np.where(near, e0, 0.0)), ("far", truth + np.where(near, 0.0, e0)),
            ("offset", truth + median(ok)), ("far_offset", truth + np.where(near, e0, e0 - fm)),
            ("near_far_offsets", truth + np.where(near, e0 - nm, e0 - fm)),
            ("near_only", np.where(near, truth + e0, np.nan))]


def split_by_distance(run: Path, rows: list[dict], dists: dict[str, np.ndarray], near_m: float) -> list[dict]:
    """Per case: the position error (m) of each of :func:`distance_parts`' queries (``near_m``: the near
    horizon's limit), located lost in space (infinite where a query has no sample left)."""
    return _locate_parts(run, rows, lambda r, truth, e: distance_parts(truth, e, dists[r["case_id"]] < near_m))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="finished campaign folder")
    ap.add_argument("rows", type=Path, help="rows of benchmarks.campaign_reextract RUN --out rows.json")
    ap.add_argument("--looks", default="clean,realistic", help="comma-separated looks (default clean,realistic)")
    ap.add_argument("--width", type=float, default=10.0, help="low-pass sigma in azimuth, degrees (default 10)")
    ap.add_argument("--by-distance", action="store_true",
                    help="also the error by the true horizon's distance and the near / far / offset parts located")
    ap.add_argument("--near-m", type=float, default=8000.0, help="--by-distance: near horizon limit, metres (default 8000)")
    a = ap.parse_args(argv)
    if not (a.run / "db.zarr").exists() or not a.rows.is_file():
        print(f"need a finished campaign folder ({a.run}) and a rows file ({a.rows})", file=sys.stderr)
        return 2
    rows_all = [r for r in json.loads(a.rows.read_text()) if r.get("returned") and "err_deg" in r]
    for look in [x for x in a.looks.split(",") if x]:
        rows = [r for r in rows_all if r["preset"] == look and not r.get("pitch_deg") and not r.get("roll_deg")]
        if not rows:
            continue
        print(f"\n{a.run.name} {look}: {len(rows)} cases")
        print("phase in the row (0 = centre) | mean error (px) | samples")
        for c, m, n in phase_bias(a.run, rows):
            print(f"{c:.2f} | {m:+.3f} | {n}")
        split = split_rows(a.run, rows, a.width)
        print(f"| part (low-pass {a.width:g} deg) | median error (m) | mean (m) | within 2.5 m |")
        print("| --- | ---: | ---: | ---: |")
        for k in ("truth", "smooth", "rough", "image"):
            v = np.array([s[k] for s in split])
            print(f"| {k} | {np.median(v):.2f} | {v.mean():.2f} | {np.sum(v <= 2.5)} of {v.size} |")
        if a.by_distance:
            dists = horizon_distances(a.run, rows)
            print("| true horizon distance | kept samples | median error (deg) | spread, MAD (deg) | > 0.05 deg | > 0.1 deg |")
            print("| --- | ---: | ---: | ---: | ---: | ---: |")
            for b in distance_table(rows, dists):
                hi = "" if math.isinf(b["to_m"]) else f"{b['to_m'] / 1000:g}"
                print(f"| {b['from_m'] / 1000:g}-{hi} km | {b['samples']} | {b['median_deg']:+.4f} | {b['mad_deg']:.4f} | "
                      f"{b['over_0_05']:.1%} | {b['over_0_1']:.1%} |")
            parts = split_by_distance(a.run, rows, dists, a.near_m)
            print(f"| truth plus (near < {a.near_m / 1000:g} km) | median error (m) | within 2.5 m & 0.5 deg | within 5 m & 1 deg |")
            print("| --- | ---: | ---: | ---: |")
            for k in ("truth", "offset", "near", "far", "far_offset", "near_far_offsets", "near_only", "image"):
                v = np.array([p[k] for p in parts])
                h = np.array([p["heading_" + k] for p in parts])
                print(f"| {k} | {np.median(v):.2f} | {np.sum((v <= 2.5) & (h <= 0.5))} of {v.size} | "
                      f"{np.sum((v <= 5.0) & (h <= 1.0))} of {v.size} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
