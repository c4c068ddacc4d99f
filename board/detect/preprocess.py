"""Image preparation shared by the detectors: grey float image in [0, 1] and the seen mask."""
from __future__ import annotations

import numpy as np

from board.errors import InvalidInputError


def to_grey01(image: np.ndarray) -> tuple[np.ndarray, float]:
    """Grey float32 image scaled to [0, 1] and the full-scale value of the input dtype.

    image : (H, W) or (H, W, 3) BGR, uint8 / uint16 / float (floats are taken as already in [0, 1]).
    """
    import cv2

    img = np.asarray(image)
    if img.ndim == 3:
        if img.shape[2] != 3:
            raise InvalidInputError(f"colour images must have 3 channels (BGR), got {img.shape[2]}")
        img = cv2.cvtColor(img.astype(np.float32) if img.dtype not in (np.uint8, np.uint16) else img,
                           cv2.COLOR_BGR2GRAY)
    elif img.ndim != 2:
        raise InvalidInputError(f"an image is (H, W) or (H, W, 3), got shape {img.shape}")
    if img.dtype == np.uint8:
        full = 255.0
    elif img.dtype == np.uint16:
        full = 65535.0
    elif img.dtype == bool:
        return img.astype(np.float32), 1.0
    else:
        full = 1.0
    out = img.astype(np.float32)
    out *= np.float32(1.0 / full)
    return out, full


def seen_or_all(seen: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray:
    """The seen mask as bool (H, W); everything seen when None."""
    if seen is None:
        return np.ones(shape, dtype=bool)
    seen = np.asarray(seen, dtype=bool)
    if seen.shape != shape:
        raise InvalidInputError(f"seen mask shape {seen.shape} differs from the image {shape}")
    return seen


def fill_unseen_rows(image: np.ndarray, seen: np.ndarray, *, block_columns: int = 256) -> np.ndarray:
    """The image with every unseen pixel replaced by the nearest seen pixel of its column (above or below).

    The detector's features (vertical blur, second differences, colour) are computed over a few rows;
    at the top and bottom of a panorama built from frames, the unseen pixels next to the seen ones are
    black, and a sky blurred with black reads as a dark band: a "sky-to-ground step" above the line,
    or texture.  Filled, the seen pixels next to the border are as if the image went on (replicated
    border, per column).  The unseen pixels are still no evidence: ``seen`` is used as before.
    Columns with nothing seen are left as they are.  Returns ``image`` itself when all is seen, else a
    copy; the index arrays are made ``block_columns`` columns at a time (a few MB for a 3600 x 1800 image).
    """
    img = np.asarray(image)
    seen = np.asarray(seen, dtype=bool)
    if seen.all():
        return img
    H, W = seen.shape
    out = img.copy()
    rows = np.arange(H, dtype=np.int32)[:, None]
    for c0 in range(0, W, block_columns):
        c1 = min(c0 + block_columns, W)
        sb = seen[:, c0:c1]
        if sb.all():
            continue
        above = np.where(sb, rows, np.int32(-1))
        np.maximum.accumulate(above, axis=0, out=above)       # last seen row at or above, -1 if none
        below = np.where(sb, rows, np.int32(H))
        below = np.minimum.accumulate(below[::-1], axis=0)[::-1]  # first seen row at or below, H if none
        use_below = (above < 0) | ((below < H) & (below - rows < rows - above))
        src = np.where(use_below, below, above)
        src[:, ~sb.any(axis=0)] = rows                        # nothing seen: the column as it is
        np.clip(src, 0, H - 1, out=src)
        out[:, c0:c1] = img[src, np.arange(c0, c1)[None, :]]
    return out
