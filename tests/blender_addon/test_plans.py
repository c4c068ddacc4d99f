"""Pan-tilt plans: overlap and coverage against a brute-force sweep of the horizon."""
from __future__ import annotations

import numpy as np
import pytest

from blender_addon.core.plans import coverage_mask, frames_for_overlap, plan_frames, plan_overlap
from board.errors import InvalidInputError


def _brute_overlap(plan, n=36000):
    """Fraction of a frame's width shared with its neighbour, counted on a fine azimuth grid."""
    az = np.arange(n) * 360.0 / n
    half = plan.hfov_deg / 2

    def inside(pan):
        return np.abs(np.mod(az - pan + 180, 360) - 180) <= half

    a, b = inside(plan.pan_deg[0]), inside(plan.pan_deg[1])
    return (a & b).sum() / a.sum()


def test_report_full_circle_plan():
    plan = plan_frames(13, 360, 65.0)
    assert plan.n_frames == 13
    np.testing.assert_allclose(np.diff(plan.pan_deg), 360 / 13)
    assert plan.overlap == pytest.approx(1 - (360 / 13) / 65)
    assert plan.overlap == pytest.approx(_brute_overlap(plan), abs=1e-3)
    assert 0.5 <= plan.overlap <= 0.6    # "about 50 %"
    assert coverage_mask(plan, np.arange(0, 360, 0.1)).all()


def test_partial_arc_is_covered_exactly():
    plan = plan_frames(5, 242, 65.0, center_pan_deg=10.0)
    az = np.arange(-180, 180, 0.05)
    seen = coverage_mask(plan, az)
    # the union of frames spans exactly [center - 121, center + 121]
    assert az[seen].min() == pytest.approx(10 - 121, abs=0.06)
    assert az[seen].max() == pytest.approx(10 + 121, abs=0.06)
    assert seen[(az > 10 - 120.9) & (az < 10 + 120.9)].all()
    assert plan.overlap == pytest.approx(_brute_overlap(plan), abs=1e-3)


@pytest.mark.parametrize("overlap,arc,fov", [(0.5, 360, 65), (0.3, 242, 62), (0.2, 180, 96), (0.0, 100, 40)])
def test_fewest_frames_for_an_overlap(overlap, arc, fov):
    n = frames_for_overlap(overlap, arc, fov)
    plan = plan_overlap(overlap, arc, fov)
    assert plan.n_frames == n
    assert plan.overlap >= overlap - 1e-9
    # one frame fewer is not enough: its step (computed independently) exceeds fov * (1 - overlap)
    m = n - 1
    if arc >= 360:
        assert 360 / m > fov * (1 - overlap)
    elif m == 1:
        assert arc > fov
    else:
        assert (arc - fov) / (m - 1) > fov * (1 - overlap)


def test_gaps_and_bad_arcs_are_refused():
    with pytest.raises(InvalidInputError, match="gaps"):
        plan_frames(4, 360, 65.0)
    with pytest.raises(InvalidInputError, match="narrower"):
        plan_frames(2, 30, 65.0)
    with pytest.raises(InvalidInputError, match="arc"):
        plan_frames(3, 400, 65.0)
    gappy = plan_frames(3, 360, 65, tilt_deg=-5, allow_gaps=True)
    assert gappy.tilt_deg == (-5.0, -5.0, -5.0)
    assert not coverage_mask(gappy, np.arange(0, 360, 1.0)).all()
