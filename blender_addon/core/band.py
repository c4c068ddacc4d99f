"""The elevation band a panorama covers (bpy-free): checked in one place for the simulator, its CLI, the
add-on and the campaign profiles, each of which names its own input in the message.

Elevations are degrees above the mast's horizontal (mast frame), -90 at the nadir, +90 at the zenith.
"""
from __future__ import annotations

import math
from collections.abc import Iterable

from board.errors import InvalidInputError

#: The whole sphere, nadir to zenith (degrees, mast frame).
FULL_SPHERE_DEG = (-90.0, 90.0)


def checked_band(band: Iterable, *, what: str = "panorama elevation band",
                 example: str = "-45,45") -> tuple[float, float]:
    """``(bottom, top)`` degrees from any pair of numbers (or numeric strings).

    Raises :class:`InvalidInputError` naming ``what`` (the user's input: ``--band``, ``pano_band_deg``)
    and showing ``example`` unless ``-90 <= bottom < top <= 90``.
    """
    try:
        bottom, top = (float(v) for v in band)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{what} {band!r}: give BOTTOM,TOP in degrees, e.g. {example}") from None
    if not (math.isfinite(bottom) and math.isfinite(top) and -90.0 <= bottom < top <= 90.0):
        raise InvalidInputError(f"{what} {bottom:g},{top:g}: need -90 <= BOTTOM < TOP <= 90 degrees (bottom < top, "
                                f"mast frame), e.g. {example}")
    return bottom, top


def panorama_band(width: int, elevation_range_deg: Iterable = FULL_SPHERE_DEG) -> tuple[int, float, float]:
    """Rows and pixel-edge elevations (degrees, mast frame) of a panorama ``width`` pixels wide over a band.

    Pixels are square (``360 / width`` degrees): the band is widened to a whole number of rows (the bottom
    edge moves down, by less than one row), except at the nadir, which it never passes (there the band loses
    the fraction of a row instead).  Returns ``(height, bottom_deg, top_deg)``.
    """
    if width < 8 or width % 2:
        raise InvalidInputError(f"panorama width must be an even number >= 8 pixels, got {width}")
    bottom, top = checked_band(elevation_range_deg)
    step = 360.0 / width
    height = int(math.ceil((top - bottom) / step - 1e-6))
    height = max(1, min(height, int(math.floor((top + 90.0) / step + 1e-6))))   # never below the nadir
    return height, top - height * step, top


__all__ = ["FULL_SPHERE_DEG", "checked_band", "panorama_band"]
