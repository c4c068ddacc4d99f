"""Parsing of command-line values shared by every package's `skyloc` subcommands."""
from __future__ import annotations

import math

from board.errors import InvalidInputError


def parse_xy(value: str, name: str = "--at") -> tuple[float, float]:
    """Parse "X,Y" (two finite numbers, metres or the CRS's units) given to option ``name``."""
    try:
        x, y = (float(v) for v in value.split(","))
    except ValueError:
        raise InvalidInputError(f"{name} must be X,Y (two numbers separated by a comma), got {value!r}") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise InvalidInputError(f"{name} must be finite numbers, got {value!r}")
    return x, y
