"""Hillshade against Lambert's law on planes."""
from __future__ import annotations

import math

import numpy as np
import pytest

from blender_addon.terrain.preview import hillshade


def test_flat_ground_is_lit_by_sin_altitude():
    z = np.zeros((20, 20))
    assert np.allclose(hillshade(z, 5.0, altitude_deg=30.0), 0.5)


@pytest.mark.parametrize("az", [0.0, 90.0, 225.0, 315.0])
def test_slope_facing_the_sun_is_fully_lit(az):
    alt = 40.0
    # a plane whose upward normal points at the sun: it rises away from the sun with slope cot(alt)
    rows, cols, cell = 30, 30, 2.0
    r, c = np.mgrid[0:rows, 0:cols]
    east, north = c * cell, -r * cell
    s = 1.0 / math.tan(math.radians(alt))
    z = -(east * math.sin(math.radians(az)) + north * math.cos(math.radians(az))) * s
    assert np.allclose(hillshade(z, cell, azimuth_deg=az, altitude_deg=alt), 1.0, atol=1e-9)
    # the opposite slope is in shadow
    assert np.allclose(hillshade(-z, cell, azimuth_deg=az, altitude_deg=alt), 0.0, atol=1e-9)


def test_nodata_stays_nodata():
    z = np.zeros((5, 5))
    z[2, 2] = np.nan
    h = hillshade(z, 1.0)
    assert np.isnan(h[2, 2]) and np.isfinite(h[0, 0])
