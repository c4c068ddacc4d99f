"""Debug picture of an extraction: the panorama, the detected line, the masked columns (matplotlib, lazy)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from board.atomic import atomic_path


def save_extraction_picture(result, path: str | os.PathLike, *, truth_row: np.ndarray | None = None,
                            dpi: int = 110) -> Path:
    """Write a PNG: panorama in grey, detected line in green where kept, masked columns shaded red,
    unseen pixels dimmed, per-column confidence underneath.  ``truth_row`` (optional, (W,) rows) in blue."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from board.detect.preprocess import to_grey01

    pano = result.panorama
    if pano is None:
        raise ValueError("this extraction has no panorama to draw")
    geom = pano.geometry
    grey, _ = to_grey01(pano.image)
    H, W = grey.shape
    extent = (geom.azimuth_col0_deg - geom.azimuth_step_deg / 2, geom.azimuths_deg()[-1] + geom.azimuth_step_deg / 2,
              geom.el_of_row(H - 0.5), geom.el_of_row(-0.5))
    fig, (ax, axc) = plt.subplots(2, 1, figsize=(min(24, 4 + W / 200), 2 + 6 * H / max(W, 1) + 1.5),
                                  gridspec_kw={"height_ratios": [max(1, 6 * H / max(W, 1)), 1]}, sharex=True)
    shown = np.where(pano.seen, grey, 0.5 * grey) if pano.seen is not None else grey
    ax.imshow(shown, cmap="gray", vmin=0, vmax=1, extent=extent, aspect="auto", interpolation="nearest")
    az = geom.azimuths_deg()
    det = result.detection
    if det is not None:
        raw_el = geom.el_of_row(det.raw_row)
        ax.plot(az, np.where(det.valid, raw_el, np.nan), color="lime", lw=0.8, label="skyline (kept)")
        ax.plot(az, np.where(det.valid, np.nan, raw_el), color="orange", lw=0.5, ls=":", label="line (masked)")
        masked = ~det.valid
        if masked.any():
            ax.fill_between(az, extent[2], extent[3], where=masked, color="red", alpha=0.18, step="mid",
                            label="masked columns")
        axc.plot(az, det.confidence, color="k", lw=0.7)
        axc.axhline(0.5, color="red", lw=0.5, ls="--")
    if truth_row is not None:
        ax.plot(az, geom.el_of_row(truth_row), color="deepskyblue", lw=0.6, ls="--", label="truth")
    ax.set_ylabel("elevation (deg)")
    ax.set_title(f"skyline extraction: {result.status} ({result.reason})", fontsize=9)
    ax.legend(loc="upper right", fontsize=7)
    axc.set_ylabel("confidence")
    axc.set_ylim(-0.05, 1.05)
    axc.set_xlabel(f"azimuth (deg, relative to {geom.azimuth_reference})")
    fig.tight_layout()
    path = Path(path)
    try:
        with atomic_path(path, suffix=".part.png") as tmp:
            fig.savefig(tmp, dpi=dpi)
    finally:
        plt.close(fig)
    return path
