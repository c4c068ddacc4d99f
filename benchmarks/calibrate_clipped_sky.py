"""Fit (or check) the clipped-sky line model of :mod:`board.clipped_sky` on finished campaign runs.

Every panorama column of the chosen looks is extracted with the model off; its line is compared with the
ray-marched truth at the column's azimuth (``truth.npz``, 0.1 degree), in elevation pixels.  Columns whose sky
is clipped above the line are binned by the clipped band's height; the excess of their error over the
unclipped columns' mean is what the model has to explain:

    excess = - gain * width ** 2 * band_deg

The printed table gives, per run and look, the bins' mean excess and the model's prediction at the current
``CLIPPED_SHIFT_GAIN`` and at the gain fitted (least squares through the origin) on the runs given, and the
mean error of clipped and unclipped columns with the model on (what matters to the pose: the difference).

    python -m benchmarks.calibrate_clipped_sky RUN [RUN ...] [--looks realistic,distorted] [--cases GLOB] [--jobs 2]
"""
from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

BINS_DEG = (0.01, 1.0, 2.0, 4.0, 8.0, 12.0, 16.0, 25.0)


def case_columns(run: str, folder: str) -> dict:
    """Per kept column of one panorama case: error (elevation pixels, + = line too high), clipped band
    (degrees) and the view's step width (pixels)."""
    from dataclasses import replace

    from board.acquisition import load_panorama
    from board.extraction import ExtractionOptions, extract_from_panorama
    from render_service.campaign import scoring

    runp, fold = Path(run), Path(folder)
    row = json.loads((fold / "row.json").read_text())
    poses_doc = json.loads((runp / "poses.json").read_text())
    k = [int(p["index"]) for p in poses_doc["accepted"]].index(int(row["pose"]))
    n_truth = int(poses_doc.get("truth_n_azimuth", 3600))
    truth_el = np.load(runp / "truth.npz")["elevation_deg"][k].astype(np.float64)
    pitch, roll = float(row["pitch_deg"] or 0.0), float(row["roll_deg"] or 0.0)
    truth = scoring.true_skyline(truth_el, heading_deg=float(row["true_heading_deg"]), pitch_deg=pitch,
                                 roll_deg=roll, n_azimuth=n_truth)
    pano = load_panorama(fold / "panorama")
    res = extract_from_panorama(pano, options=replace(ExtractionOptions(), clipped_sky_gain=0.0))
    det, g = res.detection, pano.geometry
    if det is None or det.clipped_rows is None:
        return {"err": [], "band": [], "width": float("nan")}
    cols = np.where(np.isfinite(det.line_row))[0]
    az = g.azimuth_col0_deg + cols * g.azimuth_step_deg
    tr = np.interp(az, np.arange(n_truth) * (360.0 / n_truth), truth, period=360.0)
    el = g.elevation_row0_deg - det.line_row[cols] * g.elevation_step_deg
    err = (el - tr) / g.elevation_step_deg
    band = det.clipped_rows[cols] * g.elevation_step_deg
    ok = np.isfinite(err)
    return {"err": err[ok].tolist(), "band": band[ok].tolist(),
            "width": float(det.diagnostics.get("edge_width_px", float("nan")))}


def main(argv: list[str] | None = None) -> int:
    from board.clipped_sky import CLIPPED_SHIFT_GAIN, EDGE_WIDTH_FALLBACK_PX, MAX_BAND_DEG

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--looks", default="realistic")
    ap.add_argument("--cases", default="t4-{look}-p*",
                    help="case folders to read, a glob with {look} (default the level panoramas; "
                         "t5-{look}-*-p* the tilted ones)")
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args(argv)
    looks = [x for x in a.looks.split(",") if x]
    jobs = []
    for run in a.runs:
        for look in looks:
            for f in sorted((run / "cases").glob(a.cases.format(look=look))):
                if (f / "row.json").is_file() and (f / "panorama" / "panorama.json").is_file():
                    jobs.append((str(run), str(f), run.name, look))
    if not jobs:
        print("no panorama cases of those looks in those runs", file=sys.stderr)
        return 2
    with ProcessPoolExecutor(max_workers=max(1, a.jobs)) as ex:
        outs = list(ex.map(case_columns, [j[0] for j in jobs], [j[1] for j in jobs]))
    cases: dict[tuple[str, str], list] = {}
    for (_, _, name, look), o in zip(jobs, outs):
        w = o["width"] if np.isfinite(o["width"]) else EDGE_WIDTH_FALLBACK_PX
        cases.setdefault((name, look), []).append((np.asarray(o["err"]), np.asarray(o["band"]), w))
    # per run and look: every column's error, clipped band (capped as the model caps it), squared view width
    groups = {key: (np.concatenate([c[0] for c in cs]),
                    np.minimum(np.concatenate([c[1] for c in cs]), MAX_BAND_DEG),
                    np.concatenate([np.full(c[0].size, c[2] ** 2) for c in cs]),
                    float(np.sqrt(np.median([c[2] ** 2 for c in cs]))))
              for key, cs in cases.items()}
    # a group needs clipped and unclipped columns: the unclipped ones are its reference
    both = [g for g in groups.values() if (g[1] > 0).any() and (g[1] == 0).any()]
    x = np.concatenate([w2[band > 0] * band[band > 0] for _, band, w2, _ in both]) if both else np.zeros(0)
    y = np.concatenate([err[band > 0] - err[band == 0].mean() for err, band, _, _ in both]) if both else np.zeros(0)
    fitted = float(-(x @ y) / (x @ x)) if x.size else float("nan")
    print(f"gain: current {CLIPPED_SHIFT_GAIN:.4f}, fitted on these runs {fitted:.4f} (excess = -gain * width^2 * band)")
    print("| run | look | width (px) | band (deg) | columns | excess (px) | model, current gain | model, fitted |")
    print("| --- | --- | ---: | --- | ---: | ---: | ---: | ---: |")
    for (name, look), (err, band, w2, wmed) in groups.items():
        if not (band > 0).any() or not (band == 0).any():
            print(f"| {name} | {look} | | {int((band > 0).sum())} clipped, {int((band == 0).sum())} unclipped columns: "
                  "nothing to compare | | | |")
            continue
        base = err[band == 0].mean()
        for lo, hi in zip(BINS_DEG[:-1], BINS_DEG[1:]):
            m = (band >= lo) & (band < hi)
            if m.sum() < 20:
                continue
            pred = w2[m] * band[m]
            print(f"| {name} | {look} | {wmed:.2f} | {lo:g}-{hi:g} | {m.sum()} | {err[m].mean() - base:+.3f} | "
                  f"{-CLIPPED_SHIFT_GAIN * pred.mean():+.3f} | {-fitted * pred.mean():+.3f} |")
        corr = err + CLIPPED_SHIFT_GAIN * w2 * band
        print(f"| {name} | {look} | | model on: clipped - unclipped mean | {int((band > 0).sum())} | "
              f"{corr[band > 0].mean() - corr[band == 0].mean():+.3f} (off: {err[band > 0].mean() - base:+.3f}) | | |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
