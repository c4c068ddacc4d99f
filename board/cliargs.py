"""Parsing of command-line values shared by every package's `skyloc` subcommands.

Values are parsed here and turned into :class:`InvalidInputError` naming the option and the
expected form; the root group maps it to a one-line message and exit status 1.
"""
from __future__ import annotations

import math

from board.errors import InvalidInputError


def parse_floats(value: str, name: str, counts: tuple[int, ...], form: str) -> tuple[float, ...]:
    """Parse comma-separated finite numbers given to option ``name``; ``counts``: the allowed how-many.

    form : the expected form for the message, e.g. "pitch,roll,sigma in degrees".
    """
    try:
        v = tuple(float(s) for s in value.split(","))
    except ValueError:
        v = ()
    if len(v) not in counts:
        raise InvalidInputError(f"{name} must be {form}, got {value!r}")
    if not all(math.isfinite(x) for x in v):
        raise InvalidInputError(f"{name} must be finite numbers ({form}), got {value!r}")
    return v


def parse_xy(value: str, name: str = "--at") -> tuple[float, float]:
    """Parse "X,Y" (two finite numbers, metres or the CRS's units) given to option ``name``."""
    x, y = parse_floats(value, name, (2,), "X,Y: two numbers separated by a comma")
    return x, y
