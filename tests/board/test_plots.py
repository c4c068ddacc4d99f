"""The fix picture a GNC engineer reads at a glance (issue 13 point 6): offsets in plain metres, the 95 %
ellipse visible in an inset, the truth marked, pruned positions named instead of stepped rectangles."""
from __future__ import annotations

import math

import numpy as np
import pytest

from board.match.synthetic import MountainField
from board.skydb import GridSpec, SkyDBMeta, SkyDBWriter
from board.skyline import Skyline

pytest.importorskip("matplotlib")

X0, Y0 = 512_345.0, 4_456_789.0  # UTM-sized coordinates: matplotlib would show a 1e6 offset on these


@pytest.fixture(scope="module")
def utm_db(tmp_path_factory):
    mf = MountainField.random(31, r_min=500.0)
    mf = MountainField(mf.px + X0, mf.py + Y0, mf.height, mf.width)
    grid = GridSpec.from_center((X0, Y0), 200.0, 5.0)
    meta = SkyDBMeta(grid=grid, camera_height_m=2.0, tile_size=32, renderer="analytic")
    w = SkyDBWriter.create(tmp_path_factory.mktemp("utm") / "db.zarr", meta)
    for t in w.tiles:
        ii, jj = np.mgrid[t.row0:t.row0 + t.nrows, t.col0:t.col0 + t.ncols]
        gx, gy = grid.xy(ii, jj)
        w.write_tile(t, mf.horizon_chunked(gx.ravel(), gy.ravel(), meta.azimuths_deg()).reshape(t.nrows, t.ncols, -1))
    return w.finalize(), mf


def test_fix_picture_metre_offsets_inset_truth_and_pruned(utm_db, tmp_path):
    import matplotlib.pyplot as plt
    from matplotlib.patches import Ellipse

    from board.locate import locate
    from board.plots import draw_fix, plot_fix
    from board.pose.confidence import CHI2_2D_95

    db, mf = utm_db
    tx, ty = X0 + 13.3, Y0 - 31.7
    rng = np.random.default_rng(2)
    el = mf.horizon(tx, ty, np.arange(360.0))[0] + rng.normal(0, 0.05, 360)
    fix = locate(db, Skyline(el))
    fig = draw_fix(fix, truth=(tx, ty))
    try:
        fig.canvas.draw()
        ax_map = fig.axes[0]
        # plain metres from the fix: no offset text, limits within the crop around 0
        assert ax_map.xaxis.get_offset_text().get_text() == "" and ax_map.yaxis.get_offset_text().get_text() == ""
        lo, hi = ax_map.get_xlim()
        assert lo < 0 < hi and hi - lo <= (2 * 40 + 1) * 5.0 + 1e-6
        assert f"{fix.x:.1f}" in ax_map.get_xlabel() and f"{fix.y:.1f}" in ax_map.get_ylabel()
        # the truth, at its offset from the fix
        (truth,) = [ln for ln in ax_map.get_lines() if ln.get_label() == "truth"]
        np.testing.assert_allclose(truth.get_xydata()[0], [tx - fix.x, ty - fix.y])
        # the inset holds the 95 % ellipse (axes from the covariance's eigenvalues), fully in view
        (inset,) = ax_map.child_axes
        (ell,) = [p for p in inset.patches if isinstance(p, Ellipse)]
        w = np.linalg.eigvalsh(np.asarray(fix.cov_xy))
        assert ell.width == pytest.approx(2 * math.sqrt(CHI2_2D_95 * w[1]), rel=1e-6)
        assert ell.height == pytest.approx(2 * math.sqrt(CHI2_2D_95 * w[0]), rel=1e-6)
        assert inset.get_xlim()[1] >= ell.width / 2 and inset.get_ylim()[1] >= ell.width / 2
        # pruned positions are named in the legend exactly when the crop has some
        sm = fix.pictures.score_map
        fr, fc = int(round(fix.grid_row)) - sm.region.row0, int(round(fix.grid_col)) - sm.region.col0
        crop = (slice(max(fr - 40, 0), fr + 41), slice(max(fc - 40, 0), fc + 41))
        has_pruned = bool((np.isfinite(sm.score[crop]) & ~sm.exact[crop]).any())
        labels = [t.get_text() for t in ax_map.get_legend().get_texts()]
        assert any(lb.startswith("pruned") for lb in labels) is has_pruned
        assert "truth error" in ax_map.get_title()
    finally:
        plt.close(fig)
    png = plot_fix(fix, tmp_path / "fix.png", truth=(tx, ty))
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and not list(tmp_path.glob("*.part*"))
