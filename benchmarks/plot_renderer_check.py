"""Picture of the renderer cross-check on a real DEM: skyloc vs brute force vs GRASS r.horizon.

Usage: python -m benchmarks.plot_renderer_check [--dem NAME] [--out docs/img/renderer_check.png]

One cell centre of the DEM (ground level, as r.horizon has no camera height): the three horizons
by azimuth (clockwise from grid north) and their differences.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from blender_addon.terrain.dem import read_dem  # noqa: E402
from blender_addon.terrain.multires import build_multires  # noqa: E402
from render_service.renderers import raymarch  # noqa: E402
from render_service.renderers.base import RenderSpec  # noqa: E402
from render_service.renderers.grass import grass_available, r_horizon  # noqa: E402
from render_service.renderers.reference import brute_force_horizon  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "dems"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dem", default="earth_baltoro_karakoram_srtm3.tif")
    ap.add_argument("--out", default="docs/img/renderer_check.png")
    args = ap.parse_args()
    path = SHARED / args.dem
    dem = read_dem(path)
    gt = dem.geotransform
    rows, cols = dem.array.shape
    r, c = int(rows * 0.55), int(cols * 0.45)
    x, y = gt[0] + (c + 0.5) * gt[1], gt[3] + (r + 0.5) * gt[5]
    spec = RenderSpec(camera_height_m=0.0, n_azimuth=360, body_radius_m=dem.body.radius_m)
    terrain = build_multires(path, (x, y), grid_half_m=2 * dem.cell_m)
    az, el, dist = raymarch.horizon_at(terrain, x, y, spec)
    _, ref = brute_force_horizon(dem, x, y, spec)
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(10, 6), sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    ax.plot(az, ref, color="0.6", lw=3, label="brute force (quarter cell, full DEM)")
    ax.plot(az, el, color="C0", lw=1.2, label="skyloc ray-marcher (multi-resolution)")
    ax2.plot(az, el - ref, color="C0", lw=1, label="skyloc - brute force")
    if grass_available():
        g = r_horizon(dem, [(x, y)])
        ax.plot(g.azimuth_deg, g.elevation_deg[0], color="C3", lw=1, ls="--", label="GRASS r.horizon")
        ax2.plot(az, g.elevation_deg[0] - el, color="C3", lw=1, ls="--", label="GRASS - skyloc")
    ax.set_ylabel("horizon elevation (deg)")
    ax.set_title(f"{args.dem}: cell centre ({x:.0f}, {y:.0f}) m, observer at ground level")
    ax.legend(loc="upper right", fontsize=8)
    ax2.axhline(0, color="k", lw=0.5)
    ax2.set_xlabel("azimuth (deg, clockwise from grid north)")
    ax2.set_ylabel("difference (deg)")
    ax2.set_xlim(0, 360)
    ax2.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
