"""Image transfer functions: how a pixel's stored value relates to the light it received.

A sub-pixel edge is where the *light* steps from the sky's level to the ground's: the optics' blur
and a pixel's area average the light linearly.  An 8-bit image stores it through a non-linear transfer
function (sRGB for the simulator's products and most 8-bit PNG products), which moves the half-way
point of a blurred step towards the darker side by a tenth to half a pixel, depending on the two
levels (docs/extraction.md, step 3).  The detector therefore places the line on the linearised image.

Transfers: ``"srgb"`` (IEC 61966-2-1) and ``"linear"`` (raw counts proportional to the light).
Values are fractions of full scale, in [0, 1].
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from board.errors import InvalidInputError

#: transfer functions a manifest may name (``camera.transfer`` / panorama ``transfer``)
TRANSFERS = ("srgb", "linear")
#: what an image is taken to be when its manifest does not say: the simulator writes sRGB, as 8-bit
#: camera products usually are
DEFAULT_TRANSFER = "srgb"


def check_transfer(name: str) -> str:
    """``name`` lower-cased, or InvalidInputError naming the accepted values."""
    key = str(name).strip().lower()
    if key not in TRANSFERS:
        raise InvalidInputError(f"unknown image transfer function {name!r}: use one of {', '.join(TRANSFERS)} "
                                "(the manifest's 'transfer' field)")
    return key


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """sRGB transfer function on linear values in [0, 1] (clipped)."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def srgb_decode(encoded: np.ndarray) -> np.ndarray:
    """Inverse sRGB transfer function (encoded [0, 1] -> linear, clipped)."""
    x = np.clip(encoded, 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4))


@lru_cache(maxsize=4)
def _lut(levels: int) -> np.ndarray:
    return srgb_decode(np.arange(levels, dtype=np.float64) / (levels - 1)).astype(np.float32)


def to_linear(image: np.ndarray, transfer: str) -> np.ndarray:
    """The image as linear light, float32 fractions of full scale (same shape).

    uint8 / uint16 values are decoded through a lookup table; floats are taken in [0, 1]; bool as 0 / 1.
    """
    t = check_transfer(transfer)
    img = np.asarray(image)
    if img.dtype == bool:
        return img.astype(np.float32)
    if img.dtype in (np.uint8, np.uint16):
        levels = 256 if img.dtype == np.uint8 else 65536
        if t == "linear":
            return img.astype(np.float32) * np.float32(1.0 / (levels - 1))
        return _lut(levels)[img]
    x = img.astype(np.float32)
    return x if t == "linear" else srgb_decode(x).astype(np.float32)
