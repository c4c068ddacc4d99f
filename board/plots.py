"""Pictures of a fix: the score map around it (report fig. 18) and the skyline overlay (fig. 20).

The map's axes are metres east and north of the fix (the CRS coordinates of the fix are in the
labels), so UTM northings do not turn into a 1e6 offset.  Positions the exact pruning skipped hold
only a lower bound of their score (blocks of them would show as stepped rectangles): they are drawn
in grey and named in the legend.  The 95 % ellipse is drawn on the map and, enlarged, in an inset
(on a +-200 m crop a metre-sized ellipse would be invisible).  matplotlib (Agg backend) is
imported lazily: the rest of ``board`` never needs it.
"""
from __future__ import annotations

import logging
import math
import os
from pathlib import Path

import numpy as np

from board.atomic import atomic_path
from board.locate.fix import FixPictures
from board.pose.sphere import enu_az_el

log = logging.getLogger(__name__)


def _plt():
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    return plt


def _ellipse(fix, color: str = "r", lw: float = 1.5, label: str | None = "95 % region"):
    from matplotlib.patches import Ellipse  # noqa: PLC0415

    a, b, az = fix.ellipse95_m
    if not all(math.isfinite(v) for v in (a, b, az)):
        return None
    # axes are (east, north) offsets from the fix; az is clockwise from north, matplotlib's angle anticlockwise
    return Ellipse((0.0, 0.0), 2 * a, 2 * b, angle=90.0 - az, fill=False, color=color, lw=lw, label=label)


def plot_fix(fix, out: str | os.PathLike, *, truth: tuple[float, float] | None = None, half_window: int = 40) -> Path:
    """Write a PNG with the score map around ``fix`` and the query skyline over the matched one.

    fix : board.locate.Fix; truth : optional true (x, y) metres in the database CRS, drawn as a circle
    and its error written in the title; half_window : half-size of the map crop, grid steps.
    Returns the path written (atomically).
    """
    plt = _plt()
    out = Path(out)
    fig = draw_fix(fix, truth=truth, half_window=half_window)
    try:
        with atomic_path(out, suffix=".part.png") as tmp:
            fig.savefig(tmp, dpi=110)
    finally:
        plt.close(fig)
    return out


def draw_fix(fix, *, truth: tuple[float, float] | None = None, half_window: int = 40):
    """The figure :func:`plot_fix` writes (matplotlib Figure; axes[0] the map, axes[1] the skyline overlay,
    the map's inset ``axes[0].child_axes[0]``).  Map axes: metres east and north of the fix."""
    plt = _plt()
    from matplotlib.colors import ListedColormap  # noqa: PLC0415

    fig, (ax_map, ax_sky) = plt.subplots(1, 2, figsize=(14, 5.8), gridspec_kw={"width_ratios": [1, 1.6]})
    pics = fix.pictures or FixPictures()
    sm, g = pics.score_map, pics.grid
    tx, ty = (None, None) if truth is None else (truth[0] - fix.x, truth[1] - fix.y)
    if sm is not None and g is not None:
        r0, c0 = sm.region.row0, sm.region.col0
        fr, fc = int(round(fix.grid_row)) - r0, int(round(fix.grid_col)) - c0
        i0, i1 = max(fr - half_window, 0), min(fr + half_window + 1, sm.region.nrows)
        j0, j1 = max(fc - half_window, 0), min(fc + half_window + 1, sm.region.ncols)
        crop = sm.score[i0:i1, j0:j1]
        exact = sm.exact[i0:i1, j0:j1]
        smin = float(np.min(sm.score[np.isfinite(sm.score)]))
        rel = np.log10(np.where(np.isfinite(crop) & exact, crop, np.nan) / max(smin, 1e-12))
        xa, ya = g.xy(r0 + i0, c0 + j0)
        xb, yb = g.xy(r0 + i1 - 1, c0 + j1 - 1)
        step = abs(g.geotransform[1])
        extent = (min(xa, xb) - step / 2 - fix.x, max(xa, xb) + step / 2 - fix.x,
                  min(ya, yb) - step / 2 - fix.y, max(ya, yb) + step / 2 - fix.y)
        pruned = np.isfinite(crop) & ~exact
        if pruned.any():
            ax_map.imshow(np.where(pruned, 1.0, np.nan), extent=extent, origin="upper", interpolation="nearest",
                          cmap=ListedColormap(["0.8"]), vmin=0, vmax=1)
            ax_map.plot([], [], "s", color="0.8", ms=8, label="pruned: cannot compete (lower bound only)")
        im = ax_map.imshow(rel, extent=extent, origin="upper", cmap="viridis_r", interpolation="nearest")
        fig.colorbar(im, ax=ax_map, label="log10(score / best score)")
        ax_map.plot(0, 0, "r+", ms=14, mew=2, label="fix")
        e = _ellipse(fix)
        if e is not None:
            ax_map.add_patch(e)
        if truth is not None:
            ax_map.plot(tx, ty, "o", mfc="none", mec="w", ms=10, mew=2, label="truth")
        ax_map.set_xlabel(f"east of the fix (m); fix x = {fix.x:.1f}")
        ax_map.set_ylabel(f"north of the fix (m); fix y = {fix.y:.1f}")
        ax_map.legend(loc="upper right", fontsize=7)
        _inset(ax_map, fix, truth=None if truth is None else (tx, ty))
    else:
        ax_map.text(0.5, 0.5, "heading mode: position given,\nno score map", ha="center", va="center")
        ax_map.set_axis_off()
    title = f"score map ({fix.mode}): status {fix.status}"
    if truth is not None:
        title += f" | truth error {math.hypot(tx, ty):.2f} m"
    ax_map.set_title(title, fontsize=10)
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
        for sectors, color, label in ((getattr(fix, "above_dem", []), "tab:orange", "masked: above the DEM (rock?)"),
                                      (getattr(fix, "below_dem", []), "tab:blue", "masked: below the DEM")):
            for i, sec in enumerate(sectors):  # query-frame azimuths: shifted by the heading (level approximation)
                a0 = (sec["from_deg"] + fix.heading_deg - 0.5) % 360.0
                a1 = (sec["to_deg"] + fix.heading_deg + 0.5) % 360.0
                spans = [(a0, a1)] if a0 <= a1 else [(a0, 360.0), (0.0, a1)]
                for j, (u, v) in enumerate(spans):
                    ax_sky.axvspan(u, v, color=color, alpha=0.25, lw=0, label=label if i == 0 and j == 0 else None)
        ax_sky.set_xlim(0, 360)
        ax_sky.set_xticks(np.arange(0, 361, 45))
        ax_sky.set_xlabel("azimuth (deg, clockwise from grid north)")
        ax_sky.set_ylabel("elevation (deg)")
        ax_sky.legend(loc="upper right", fontsize=8)
    ax_sky.set_title(f"x {fix.x:.1f} y {fix.y:.1f} heading {fix.heading_deg:.2f} pitch {fix.pitch_deg:.2f} "
                     f"roll {fix.roll_deg:.2f} | sigma {fix.sigma_x_m:.2f}/{fix.sigma_y_m:.2f} m, "
                     f"{fix.sigma_heading_deg:.2f} deg", fontsize=9)
    fig.tight_layout()
    return fig


def _inset(ax, fix, *, truth: tuple[float, float] | None) -> None:
    """An inset zoomed on the fix: the 95 % ellipse (and the truth when it is near) at a readable scale."""
    a, b, _ = fix.ellipse95_m
    if not (math.isfinite(a) and a > 0):
        return
    half = 1.5 * a
    if truth is not None and math.hypot(*truth) < 4 * a:
        half = max(half, 1.2 * max(abs(truth[0]), abs(truth[1])))
    ins = ax.inset_axes([0.02, 0.02, 0.34, 0.34])
    ins.set_facecolor("white")
    ins.add_patch(_ellipse(fix, lw=1.2, label=None))
    ins.plot(0, 0, "r+", ms=9, mew=1.5)
    if truth is not None and max(abs(truth[0]), abs(truth[1])) <= half:
        ins.plot(*truth, "o", mfc="none", mec="k", ms=7, mew=1.5)
    ins.set_xlim(-half, half)
    ins.set_ylim(-half, half)
    ins.set_aspect("equal")
    ins.tick_params(labelsize=6)
    ins.set_title(f"95 %: {a:.2f} x {b:.2f} m", fontsize=7)
