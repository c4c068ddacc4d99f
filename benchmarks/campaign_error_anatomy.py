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

    python -m benchmarks.campaign_error_anatomy RUN rows.json [--looks clean,realistic] [--width 10]
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


def split_rows(run: Path, rows: list[dict], width_deg: float) -> list[dict]:
    """Per case: the position error (m) of the truth, truth + smooth error, truth + rough error, and the campaign's."""
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
        e0 = np.where(ok, e, 0.0)
        smooth = circular_lowpass(e0, width_deg, step)
        res = {"case_id": r["case_id"], "preset": r["preset"], "image": float(r["error_m"]),
               "sigma_m": math.hypot(r.get("sigma_x_m", 0.0), r.get("sigma_y_m", 0.0))}
        t = Truth(float(case["true_x"]), float(case["true_y"]), float(case["true_heading_deg"]))
        for name, q in (("truth", truth), ("smooth", truth + smooth), ("rough", truth + e0 - smooth)):
            fix = locate(db, Skyline(np.where(ok, q, np.nan), 0.0, step), mode="lost")
            res[name] = compare_with_truth(fix, t).error_m
        out.append(res)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="finished campaign folder")
    ap.add_argument("rows", type=Path, help="rows of benchmarks.campaign_reextract RUN --out rows.json")
    ap.add_argument("--looks", default="clean,realistic", help="comma-separated looks (default clean,realistic)")
    ap.add_argument("--width", type=float, default=10.0, help="low-pass sigma in azimuth, degrees (default 10)")
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
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
