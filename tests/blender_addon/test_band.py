"""The panorama's elevation band (bpy-free): one check for the simulator, its CLI and the campaign."""
import math

import pytest

from blender_addon.core.band import FULL_SPHERE_DEG, checked_band, panorama_band
from board.errors import InvalidInputError


def test_checked_band_names_the_users_input_and_the_fix():
    assert checked_band(["-45", "45"]) == (-45.0, 45.0)
    assert checked_band((-45, 90), what="pano_band_deg") == (-45.0, 90.0)
    for bad in ((10.0, -10.0), (5.0, 5.0), (-95.0, 10.0), (0.0, 91.0), (float("nan"), 10.0), (-10.0,),
                (-10.0, 0.0, 10.0), ("low", "high"), None):
        with pytest.raises(InvalidInputError, match=r"--band .*e\.g\. --band=-45,45"):
            checked_band(bad, what="--band", example="--band=-45,45")


@pytest.mark.parametrize("width", [64, 256, 1800, 3600])
@pytest.mark.parametrize("band", [FULL_SPHERE_DEG, (-45.0, 45.0), (-45.0, 90.0), (-44.3, 12.7), (-90.0, 10.0)])
def test_panorama_band_is_square_pixels_covering_the_band(width, band):
    """Brute force: the fewest whole rows of 360/width degrees, from the top down, that cover the band
    (stopping at the nadir)."""
    height, bottom, top = panorama_band(width, band)
    step = 360.0 / width
    rows = 0
    while band[1] - rows * step > band[0] + 1e-9 and band[1] - (rows + 1) * step >= -90.0 - 1e-9:
        rows += 1
    assert height == max(rows, 1) and top == band[1]
    assert math.isclose(bottom, top - height * step) and bottom >= -90.0 - 1e-9
    assert bottom <= band[0] + 1e-9 or math.isclose(bottom, -90.0, abs_tol=step)
