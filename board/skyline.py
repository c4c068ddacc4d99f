"""The skyline type and its JSON file.

A skyline is a vector of elevations (degrees above the local horizontal) on a regular
azimuth grid: sample ``j`` is the point sample at ``azimuth_start_deg + j * azimuth_step_deg``.
For a rover's (query) skyline azimuths are relative to the heading (0 = optical axis at pan 0);
for a database skyline they are absolute (0 = grid north).  NaN where the camera did not look.

File::

    {"version": 1, "azimuth_start_deg": 0.0, "azimuth_step_deg": 1.0,
     "elevation_deg": [1.2, null, ...], "meta": {...}}
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from board.atomic import write_text_atomic
from board.errors import FormatError, InvalidInputError

SKYLINE_VERSION = 1


@dataclass(frozen=True)
class Skyline:
    """elevation_deg : (N,) float64 degrees, NaN = unseen; N * azimuth_step_deg must be 360."""

    elevation_deg: np.ndarray
    azimuth_start_deg: float = 0.0
    azimuth_step_deg: float = 1.0
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        el = np.asarray(self.elevation_deg, dtype=np.float64)
        if el.ndim != 1 or el.size == 0:
            raise InvalidInputError(f"a skyline is a non-empty 1-D vector of elevations, got shape {el.shape}")
        if not (self.azimuth_step_deg > 0) or not math.isclose(el.size * self.azimuth_step_deg, 360.0,
                                                               rel_tol=0, abs_tol=1e-6):
            raise InvalidInputError(
                f"{el.size} samples of {self.azimuth_step_deg} degrees do not cover 360 degrees: "
                "a skyline covers the full circle, with NaN where unseen")
        object.__setattr__(self, "elevation_deg", el)

    @property
    def n(self) -> int:
        return int(self.elevation_deg.size)

    def azimuths_deg(self) -> np.ndarray:
        """Azimuth of every sample, degrees (not wrapped)."""
        return self.azimuth_start_deg + np.arange(self.n) * self.azimuth_step_deg

    @property
    def seen(self) -> np.ndarray:
        """(N,) bool: samples that were observed."""
        return np.isfinite(self.elevation_deg)

    @property
    def coverage_deg(self) -> float:
        """Observed arc, degrees."""
        return float(self.seen.sum() * self.azimuth_step_deg)

    def to_dict(self) -> dict:
        return {
            "version": SKYLINE_VERSION,
            "azimuth_start_deg": float(self.azimuth_start_deg),
            "azimuth_step_deg": float(self.azimuth_step_deg),
            "elevation_deg": [None if not np.isfinite(v) else round(float(v), 6) for v in self.elevation_deg],
            "meta": self.meta,
        }

    @classmethod
    def from_dict(cls, d: dict, where: str = "skyline") -> "Skyline":
        if not isinstance(d, dict):
            raise FormatError(f"{where}: expected a JSON object with 'elevation_deg'")
        if d.get("version") != SKYLINE_VERSION:
            raise FormatError(f"{where}: skyline version {d.get('version')!r} is not supported "
                              f"(this skyloc reads version {SKYLINE_VERSION})")
        try:
            el = np.array([np.nan if v is None else float(v) for v in d["elevation_deg"]], dtype=np.float64)
            return cls(el, float(d.get("azimuth_start_deg", 0.0)), float(d.get("azimuth_step_deg", 360.0 / len(el))),
                       dict(d.get("meta", {})))
        except (KeyError, TypeError, ValueError, ZeroDivisionError) as exc:
            raise FormatError(f"{where}: malformed skyline ({exc})") from exc

    def save(self, path: str | os.PathLike) -> None:
        """Write the JSON file (atomically: a temp file renamed over ``path``)."""
        write_text_atomic(path, json.dumps(self.to_dict()))

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Skyline":
        path = Path(path)
        try:
            d = json.loads(path.read_text())
        except FileNotFoundError:
            raise FormatError(f"skyline file {path} does not exist") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise FormatError(f"skyline file {path} is not valid JSON ({exc})") from exc
        return cls.from_dict(d, where=str(path))
