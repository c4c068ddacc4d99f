"""Camera presets: field of view against the intrinsics, and the annex's numbers."""
from __future__ import annotations

import math

import numpy as np
import pytest

from blender_addon.core.cameras import PRESETS, get_preset
from board.errors import InvalidInputError


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_edge_pixels_see_half_the_field_of_view(name):
    p = PRESETS[name]
    cam = p.camera_model()
    # the outer edges of the edge pixels (u = -0.5 and width - 0.5) are hfov/2 off axis
    d = cam.unproject(np.array([-0.5, cam.width - 0.5]), np.array([cam.cy, cam.cy]))
    ang = np.degrees(np.arctan2(d[:, 0], d[:, 2]))
    np.testing.assert_allclose(ang, [-p.hfov_deg / 2, p.hfov_deg / 2], atol=1e-9)
    d = cam.unproject(np.array([cam.cx, cam.cx]), np.array([-0.5, cam.height - 0.5]))
    ang = np.degrees(np.arctan2(d[:, 1], d[:, 2]))
    np.testing.assert_allclose(ang, [-p.vfov_deg / 2, p.vfov_deg / 2], atol=1e-9)
    assert cam.fx == cam.fy  # square pixels


def test_annex_values():
    ex, m20, mag = PRESETS["exomars"], PRESETS["mars2020"], PRESETS["magellium"]
    assert (ex.width, ex.height, ex.hfov_deg, ex.mast_height_m) == (1024, 1024, 65.0, 2.05)
    assert ex.vfov_deg == pytest.approx(65.0)          # square sensor, square pixels: 65 x 65 kept
    assert (m20.width, m20.height, m20.hfov_deg, m20.mast_height_m) == (5120, 3840, 96.0, 1.98)
    assert m20.vfov_deg == pytest.approx(2 * math.degrees(math.atan(math.tan(math.radians(48)) * 0.75)))
    assert (mag.width, mag.height, mag.mast_height_m) == (1600, 1200, 0.75)
    assert mag.vfov_deg == pytest.approx(48.0, abs=0.6)  # the annex's 48 deg within rounding


def test_resized_keeps_angles_and_custom_needs_everything():
    small = get_preset("exomars", width=64)
    assert (small.width, small.height) == (64, 64)
    assert small.vfov_deg == pytest.approx(65.0)
    m = get_preset("mars2020", width=160)
    assert m.height == 120 and m.hfov_deg == 96.0
    c = get_preset("custom", width=100, height=50, hfov_deg=40.0, mast_height_m=1.0)
    assert c.vfov_deg == pytest.approx(2 * math.degrees(math.atan(math.tan(math.radians(20)) / 2)))
    with pytest.raises(InvalidInputError, match="hfov_deg"):
        get_preset("custom", width=100, height=50)
    with pytest.raises(InvalidInputError, match="exomars"):
        get_preset("pancam")
    with pytest.raises(InvalidInputError, match="field of view"):
        get_preset("custom", width=100, height=50, hfov_deg=200)
