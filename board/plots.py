"""Pictures of a fix: the score map around it (report fig. 18) and the skyline overlay (fig. 20).

matplotlib (Agg backend) is imported lazily: the rest of ``board`` never needs it.
"""
from __future__ import annotations

import logging
import math
import os
from pathlib import Path

import numpy as np

from board.locate.fix import FixPictures
from board.pose.sphere import enu_az_el

log = logging.getLogger(__name__)


def _plt():
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    return plt


def plot_fix(fix, out: str | os.PathLike, *, truth: tuple[float, float] | None = None, half_window: int = 40) -> Path:
    """Write a PNG with the score map around ``fix`` and the query skyline over the matched one.

    fix : board.locate.Fix; truth : optional true (x, y) metres, drawn as a circle;
    half_window : half-size of the map crop, grid steps.  Returns the path written (atomically).
    """
    plt = _plt()
    from matplotlib.patches import Ellipse  # noqa: PLC0415

    out = Path(out)
    fig, (ax_map, ax_sky) = plt.subplots(1, 2, figsize=(14, 5.5), gridspec_kw={"width_ratios": [1, 1.6]})
    pics = fix.pictures or FixPictures()
    sm, g = pics.score_map, pics.grid
    if sm is not None and g is not None:
        r0, c0 = sm.region.row0, sm.region.col0
        fr, fc = int(round(fix.grid_row)) - r0, int(round(fix.grid_col)) - c0
        i0, i1 = max(fr - half_window, 0), min(fr + half_window + 1, sm.region.nrows)
        j0, j1 = max(fc - half_window, 0), min(fc + half_window + 1, sm.region.ncols)
        crop = sm.score[i0:i1, j0:j1]
        smin = float(np.min(sm.score[np.isfinite(sm.score)]))
        rel = np.log10(np.where(np.isfinite(crop), crop, np.nan) / max(smin, 1e-12))
        xa, ya = g.xy(r0 + i0, c0 + j0)
        xb, yb = g.xy(r0 + i1 - 1, c0 + j1 - 1)
        step = abs(g.geotransform[1])
        extent = (min(xa, xb) - step / 2, max(xa, xb) + step / 2, min(ya, yb) - step / 2, max(ya, yb) + step / 2)
        im = ax_map.imshow(rel, extent=extent, origin="upper", cmap="viridis_r", interpolation="nearest")
        fig.colorbar(im, ax=ax_map, label="log10(score / best score)")
        ax_map.plot(fix.x, fix.y, "r+", ms=14, mew=2, label="fix")
        a, b, az = fix.ellipse95_m
        if all(math.isfinite(v) for v in (a, b, az)):
            ax_map.add_patch(Ellipse((fix.x, fix.y), 2 * a, 2 * b, angle=90.0 - az, fill=False, color="r",
                                     lw=1.5, label="95 % region"))
        if truth is not None:
            ax_map.plot(truth[0], truth[1], "o", mfc="none", mec="w", ms=10, mew=2, label="truth")
        ax_map.set_xlabel("x (m)")
        ax_map.set_ylabel("y (m)")
        ax_map.legend(loc="upper right", fontsize=8)
    else:
        ax_map.text(0.5, 0.5, "heading mode: position given,\nno score map", ha="center", va="center")
        ax_map.set_axis_off()
    ax_map.set_title(f"score map ({fix.mode}): status {fix.status}")
    # skyline overlay in ENU azimuth
    if pics.db_skyline_deg is not None and pics.query_el_deg is not None:
        n = pics.db_skyline_deg.size
        az_db = pics.db_azimuth_start_deg + np.arange(n + 1) * 360.0 / n
        ax_sky.plot(az_db, np.append(pics.db_skyline_deg, pics.db_skyline_deg[0]), "k-", lw=1.2,
                    label="database (interpolated at the fix)")
        seen = np.isfinite(pics.query_el_deg)
        az_q, el_q = enu_az_el(pics.query_theta_deg[seen], pics.query_el_deg[seen], fix.heading_deg, fix.pitch_deg,
                               fix.roll_deg)
        ax_sky.plot(np.mod(az_q, 360.0), el_q - fix.offset_deg, "r.", ms=3,
                    label="query (rotated by the fitted pose, offset removed)")
        ax_sky.set_xlim(0, 360)
        ax_sky.set_xlabel("azimuth (deg, clockwise from grid north)")
        ax_sky.set_ylabel("elevation (deg)")
        ax_sky.legend(loc="upper right", fontsize=8)
    ax_sky.set_title(f"x {fix.x:.1f} y {fix.y:.1f} heading {fix.heading_deg:.2f} pitch {fix.pitch_deg:.2f} "
                     f"roll {fix.roll_deg:.2f} | sigma {fix.sigma_x_m:.2f}/{fix.sigma_y_m:.2f} m, "
                     f"{fix.sigma_heading_deg:.2f} deg", fontsize=9)
    fig.tight_layout()
    tmp = out.with_name(out.name + ".part.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, out)
    return out
