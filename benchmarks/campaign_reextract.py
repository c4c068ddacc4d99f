"""Re-extract and re-locate a finished campaign's panoramas with the code as it is now.

A campaign (``skyloc campaign --out RUN``) keeps every rendered panorama (``cases/<id>/panorama``) and
NavCam acquisition (``cases/<id>/acquisition``, scored as the look's name with ``-navcam``),
the ray-marched true horizon of every pose (``truth.npz``) and its database (``db.zarr``).  Running
the extraction and the matcher again on those renders measures a change of the image chain on the
same pictures, without rendering them again (minutes instead of a campaign's half hour), and the
per-azimuth errors it saves show *where* the chain errs (bias, smooth error, outliers).

    python -m benchmarks.campaign_reextract RUN [RUN ...] [--looks clean,realistic] [--out rows.json]
        [--compare old_rows.json] [--errors errors.npz] [--jobs 2] [--grey]

``--grey`` turns each colour panorama into what a monochrome camera of the same spectral response would
have stored (the linear luminance, Rec. 709 weights, encoded again with the picture's transfer), to
measure the detector without its colour feature.

Scoring is the campaign's own (:mod:`render_service.campaign.scoring`: the true skyline in the mast
frame, the seen azimuths of the picture, wrong beyond 25 m or 2 degrees).  The printed table has one
line per run and look: cases, skylines returned, kept / seen, median extraction error, share of kept
samples more than 1 degree off, median / p90 / max position error, share within 2.5 m and 0.5 deg and
within 5 m and 1 deg, ``ok`` count, wrong fixes and wrong fixes reported ``ok``.
"""
from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

#: the product folder and manifest of each case kind that has pictures
PRODUCTS = {"panorama": ("panorama", "panorama.json"), "acquisition": ("acquisition", "acquisition.json")}


def _cases(run: Path, looks: set[str] | None) -> list[tuple[Path, dict]]:
    """(case folder, its row) of every finished panorama or NavCam acquisition case of ``run`` whose preset
    is in ``looks``."""
    out = []
    for folder in sorted((run / "cases").iterdir()):
        row_path = folder / "row.json"
        if not row_path.is_file():
            continue
        row = json.loads(row_path.read_text())
        product = PRODUCTS.get(row.get("kind"))
        if product is None or not (folder / product[0] / product[1]).is_file():
            continue
        if looks and row.get("preset") not in looks:
            continue
        out.append((folder, row))
    return out


def monochrome(image: np.ndarray, transfer: str) -> np.ndarray:
    """The grey picture a monochrome camera would store for a BGR ``image`` (same dtype): linear luminance
    (Rec. 709 weights on the decoded channels), encoded with ``transfer`` ("srgb" or "linear") again."""
    from board.transfer import srgb_encode, to_linear

    img = np.asarray(image)
    if img.ndim == 2:
        return img
    lin = to_linear(img, transfer).astype(np.float64)
    y = lin[..., 2] * 0.2126 + lin[..., 1] * 0.7152 + lin[..., 0] * 0.0722
    enc = srgb_encode(y) if transfer == "srgb" else y
    full = np.iinfo(img.dtype).max if np.issubdtype(img.dtype, np.integer) else 1.0
    out = np.clip(enc, 0.0, 1.0) * full
    return (np.round(out) if np.issubdtype(img.dtype, np.integer) else out).astype(img.dtype)


def evaluate_case(run: str, folder: str, row: dict, detector: dict | None = None, transfer: str | None = None,
                  options: dict | None = None, grey: bool = False) -> dict:
    """Extract, locate (lost in space against the run's database) and score one panorama or acquisition case
    (an acquisition's panorama is levelled with its manifest's attitude, as the campaign does).

    detector : :class:`board.detect.DetectorParams` fields to change (a variant of the detector);
    options : :class:`board.extraction.ExtractionOptions` fields to change (such as ``clipped_sky_gain``);
    transfer : the image transfer to assume instead of the manifest's (``"linear"``: the stored values);
    grey : extract from the picture a monochrome camera would have taken (:func:`monochrome`).
    """
    from dataclasses import replace

    from board.acquisition import load_acquisition, load_panorama
    from board.extraction import ExtractionOptions, extract_from_panorama
    from board.locate import locate
    from board.locate.truth import Truth, compare_with_truth
    from board.panorama import build_panorama
    from board.skydb import SkyDB
    from render_service.campaign import scoring

    runp, fold = Path(run), Path(folder)
    db = SkyDB.open(runp / "db.zarr")
    n = db.meta.n_azimuth
    poses = json.loads((runp / "poses.json").read_text())["accepted"]
    k = [int(p["index"]) for p in poses].index(int(row["pose"]))
    truth_el = np.load(runp / "truth.npz")["elevation_deg"][k].astype(np.float64)
    pitch, roll = float(row["pitch_deg"] or 0.0), float(row["roll_deg"] or 0.0)
    tx, ty, th = float(row["true_x"]), float(row["true_y"]), float(row["true_heading_deg"])
    levelled = row.get("kind") == "acquisition"
    out = {"run": run, "case_id": row["case_id"], "preset": row["preset"] + ("-navcam" if levelled else ""),
           "pose": int(row["pose"]), "pitch_deg": pitch, "roll_deg": roll}
    pano = build_panorama(load_acquisition(fold / "acquisition")) if levelled else load_panorama(fold / "panorama")
    if transfer:
        pano.transfer = transfer
    if grey:
        pano.image = monochrome(pano.image, pano.transfer)
    opts = replace(ExtractionOptions(), **(options or {}))
    if detector:
        opts = replace(opts, detector=replace(opts.detector, **detector))
    res = extract_from_panorama(pano, azimuth_step_deg=360.0 / n, azimuth_start_deg=0.0, options=opts)
    out["extract_status"] = res.status
    out["extract_s"] = res.elapsed_s
    if res.skyline is None:
        out.update(status="no_fix", reason=res.reason, returned=False)
        return out
    out["returned"] = True
    truth = scoring.true_skyline(truth_el, heading_deg=th, pitch_deg=0.0 if levelled else pitch,
                                 roll_deg=0.0 if levelled else roll, n_azimuth=n)
    view = scoring.view_limits(res.panorama, n)
    ex = scoring.extraction_errors(res.skyline.elevation_deg, truth, res.skyline.azimuth_step_deg, view)
    out.update(ex)
    out["err_deg"] = (np.asarray(res.skyline.elevation_deg) - truth).tolist()
    fix = locate(db, res.skyline, mode="lost")
    cmp = compare_with_truth(fix, Truth(tx, ty, th))
    herr = abs(cmp.heading_error_deg)
    wrong = cmp.error_m > scoring.WRONG_M or herr > scoring.WRONG_HEADING_DEG
    out.update(status=fix.status, error_m=cmp.error_m, heading_error_deg=herr, sigma_x_m=fix.sigma_x_m,
               sigma_y_m=fix.sigma_y_m, wrong=bool(wrong), wrong_ok=bool(wrong and fix.status == "ok"),
               dx=cmp.dx_m, dy=cmp.dy_m, reason=fix.reason, rms_residual_deg=fix.rms_residual_deg,
               noise_deg=fix.noise_deg, fix_pitch_deg=fix.pitch_deg, fix_roll_deg=fix.roll_deg,
               in_ellipse95=bool(cmp.in_ellipse95))
    return out


def summarise(rows: list[dict]) -> list[dict]:
    """One summary per (run, preset): the figures of issue 11's targets."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        groups.setdefault((Path(r["run"]).name, r["preset"]), []).append(r)
    out = []
    for (run, preset), rs in sorted(groups.items()):
        fixed = [r for r in rs if r.get("status") not in (None, "no_fix")]
        e = np.array([r["error_m"] for r in fixed]) if fixed else np.array([np.nan])
        h = np.array([r["heading_error_deg"] for r in fixed]) if fixed else np.array([np.nan])
        n_kept = sum(r.get("n_kept", 0) for r in rs)
        out.append({
            "run": run, "preset": preset, "cases": len(rs),
            "returned": sum(bool(r.get("returned")) for r in rs) / len(rs),
            "kept_fraction_median": float(np.nanmedian([r.get("kept_fraction", np.nan) for r in rs])),
            "ext_median_deg": float(np.nanmedian([r.get("extract_median_abs_err_deg", np.nan) for r in rs])),
            "gt1_share": sum(r.get("n_gt1deg", 0) for r in rs) / max(n_kept, 1),
            "err_median_m": float(np.nanmedian(e)), "err_p90_m": float(np.nanpercentile(e, 90)),
            "err_max_m": float(np.nanmax(e)),
            "within_2_5": float(np.sum((e <= 2.5) & (h <= 0.5)) / len(rs)),
            "within_5": float(np.sum((e <= 5.0) & (h <= 1.0)) / len(rs)),
            "ok": sum(r.get("status") == "ok" for r in rs),
            "wrong": sum(bool(r.get("wrong")) for r in rs), "wrong_ok": sum(bool(r.get("wrong_ok")) for r in rs),
            "ok_in_ellipse": (sum(r.get("status") == "ok" and bool(r.get("in_ellipse95")) for r in rs)
                              / max(sum(r.get("status") == "ok" for r in rs), 1)),
        })
    return out


def table(summary: list[dict]) -> str:
    """Markdown table of :func:`summarise`."""
    head = ("| run | look | cases | returned | kept / seen | median ext. err (deg) | kept > 1 deg | "
            "median / p90 / max error (m) | within 2.5 m, 0.5 deg | within 5 m, 1 deg | ok | ok inside 95 % | wrong | wrong and ok |\n"
            "| --- | --- | ---: | ---: | ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    lines = [head]
    for s in summary:
        lines.append(f"| {s['run']} | {s['preset']} | {s['cases']} | {s['returned']:.0%} | {s['kept_fraction_median']:.0%} | "
                     f"{s['ext_median_deg']:.3f} | {s['gt1_share']:.2%} | {s['err_median_m']:.2f} / {s['err_p90_m']:.2f} / "
                     f"{s['err_max_m']:.1f} | {s['within_2_5']:.0%} | {s['within_5']:.0%} | {s['ok']} | {s['ok_in_ellipse']:.0%} | "
                     f"{s['wrong']} | "
                     f"{s['wrong_ok']} |")
    return "\n".join(lines)


def field_values(items: list[str], flag: str, of: type) -> dict:
    """``FIELD=VALUE`` arguments (VALUE a Python literal) for fields of the dataclass ``of``, as a dict;
    ValueError naming ``flag``, the item and what is wrong with it."""
    import ast
    from dataclasses import fields

    names = {f.name for f in fields(of)}
    out = {}
    for item in items:
        key, _, value = item.partition("=")
        if key.strip() not in names:
            raise ValueError(f"{flag} {item!r}: {of.__name__} has no field {key.strip()!r} "
                             f"(its fields: {', '.join(sorted(names))})")
        try:
            out[key.strip()] = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):
            raise ValueError(f"{flag} {item!r}: use FIELD=VALUE with a Python literal") from None
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="finished campaign folders (cases/, truth.npz, db.zarr)")
    ap.add_argument("--looks", default="", help="comma-separated presets to re-run (default: every panorama case)")
    ap.add_argument("--out", type=Path, default=None, help="JSON file for the per-case rows")
    ap.add_argument("--compare", type=Path, default=None, help="an earlier --out to print beside this run")
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    ap.add_argument("--detector", action="append", default=[], metavar="FIELD=VALUE",
                    help="a DetectorParams field for a variant of the detector (repeatable; VALUE is Python)")
    ap.add_argument("--option", action="append", default=[], metavar="FIELD=VALUE",
                    help="an ExtractionOptions field for a variant of the extraction (repeatable; VALUE is Python)")
    ap.add_argument("--transfer", choices=("srgb", "linear"), default=None,
                    help="assume this image transfer instead of the manifests' ('linear': place the line on the "
                         "stored values, as before session 9)")
    ap.add_argument("--grey", action="store_true",
                    help="extract from monochrome versions of the panoramas (linear luminance, re-encoded)")
    a = ap.parse_args(argv)
    looks = {s for s in a.looks.split(",") if s} or None
    from board.detect import DetectorParams
    from board.extraction import ExtractionOptions

    try:
        detector = field_values(a.detector, "--detector", DetectorParams)
        options = field_values(a.option, "--option", ExtractionOptions)
    except ValueError as e:
        print(f"campaign_reextract: {e}", file=sys.stderr)
        return 1
    todo = []
    for run in a.runs:
        if not (run / "db.zarr").exists() or not (run / "truth.npz").is_file():
            print(f"campaign_reextract: {run} is not a finished campaign (no db.zarr or truth.npz); "
                  "run `skyloc campaign --out` there first", file=sys.stderr)
            return 1
        todo += [(str(run.resolve()), str(f), r) for f, r in _cases(run, looks)]
    if not todo:
        print("campaign_reextract: no finished panorama or acquisition case matches", file=sys.stderr)
        return 1
    rows: list[dict] = []
    with ProcessPoolExecutor(max_workers=max(a.jobs, 1)) as pool:
        futs = [pool.submit(evaluate_case, *t, detector or None, a.transfer, options or None, a.grey) for t in todo]
        for i, f in enumerate(futs, 1):
            rows.append(f.result())
            print(f"\r{i}/{len(futs)} cases", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    if a.out:
        a.out.write_text(json.dumps(rows))
    if a.compare:
        print("before:\n" + table(summarise(json.loads(a.compare.read_text()))) + "\n\nnow:")
    print(table(summarise(rows)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
