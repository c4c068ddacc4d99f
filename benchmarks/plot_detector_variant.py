"""Overlay of two detector variants on one rendered label, against the ray-marched truth.

A label of :mod:`benchmarks.detector_labels` (``/tmp/labels/<key>``: ``pano/`` and ``truth.npz``) is
extracted twice: with the detector as it is and with the ``--before`` variant (``DetectorParams`` fields),
and drawn as two panels: the panorama, the true horizon, the kept skyline and the seen azimuths masked, with
the kept share and the kept samples more than 1 degree off in each title.

    python -m benchmarks.plot_detector_variant LABEL_FOLDER OUT.png --before reseat_on_step_above=False
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("label", type=Path, help="a label folder (pano/, truth.npz)")
    ap.add_argument("out", type=Path, help="PNG to write")
    ap.add_argument("--before", action="append", default=[], metavar="FIELD=VALUE",
                    help="a DetectorParams field of the earlier variant (repeatable; VALUE is Python)")
    a = ap.parse_args(argv)
    if not (a.label / "truth.npz").is_file():
        print(f"plot_detector_variant: {a.label} is not a label folder (no truth.npz); make one with "
              "`python -m benchmarks.detector_labels`", file=sys.stderr)
        return 1
    from benchmarks.campaign_reextract import field_values
    from board.detect import DetectorParams

    try:
        before = field_values(a.before, "--before", DetectorParams)
    except ValueError as e:
        print(f"plot_detector_variant: {e}", file=sys.stderr)
        return 1

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from benchmarks.bench_detector import in_view, truth_on_grid
    from benchmarks.detector_labels import load_label
    from board.acquisition import load_panorama
    from board.extraction import ExtractionOptions, extract_from_panorama

    _, fine, _ = load_label(a.label)
    pano = load_panorama(a.label / "pano")
    truth = truth_on_grid(fine)
    view = in_view(truth, pano.geometry)
    g = pano.geometry
    img = pano.image[..., ::-1] if pano.image.ndim == 3 else pano.image
    az = g.azimuths_deg()
    extent = [az[0], az[-1], g.el_of_row(g.height - 1), g.el_of_row(0)]
    fig, axes = plt.subplots(2, 1, figsize=(14, 6.4), sharex=True)
    for ax, (name, fields) in zip(axes, (("before: " + ", ".join(a.before), before), ("now", {}))):
        opts = ExtractionOptions()
        opts = replace(opts, detector=replace(opts.detector, **fields))
        res = extract_from_panorama(pano, options=opts)
        el = res.skyline.elevation_deg if res.skyline is not None else np.full(truth.shape, np.nan)
        rel = (np.arange(el.size) * 360.0 / el.size + 180.0) % 360.0 - 180.0   # heading-relative, as the picture
        k = np.argsort(rel)
        kept = view & np.isfinite(el)
        n_bad = int((np.abs(el[kept] - truth[kept]) > 1.0).sum())
        ax.imshow(img, extent=extent, aspect="auto", cmap="gray")
        ax.plot(rel[k], truth[k], "c--", lw=0.8, label="true horizon (ray-marched)")
        ax.plot(rel[k], el[k], color="lime", lw=1.2, label="kept skyline")
        miss = view & ~np.isfinite(el)
        ax.plot(rel[miss], truth[miss], "r|", ms=8, label="seen, masked")
        lo, hi = np.nanmin(truth[view]), np.nanmax(truth[view])
        ax.set_ylim(lo - 8.0, hi + 4.0)
        ax.set_xlim(-180.0, 180.0)
        ax.set_ylabel("elevation (deg)")
        ax.set_title(f"{name}: {res.status}, kept {kept.sum() / max(view.sum(), 1):.0%} of the seen azimuths, "
                     f"{n_bad} kept samples > 1 deg off")
        ax.legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("azimuth relative to the heading (deg)")
    fig.tight_layout()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.out, dpi=90)
    print(f"written {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
