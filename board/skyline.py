"""The skyline type and its JSON file.

A skyline is a vector of elevations (degrees above the local horizontal) on a regular
azimuth grid: sample ``j`` is the point sample at ``azimuth_start_deg + j * azimuth_step_deg``.
For a rover's (query) skyline azimuths are relative to the heading (0 = optical axis at pan 0);
for a database skyline they are absolute (0 = grid north).  NaN where the camera did not look.

An extracted skyline may also carry the same line sampled finer (``fine_elevation_deg`` every
``fine_step_deg``, from the same start; each fine sample is the same estimator as a coarse one, so the
coarse samples are every k-th fine one).  The matcher uses it to sample the query again where the
database's own azimuths fall once the heading is known (:func:`Skyline.resampled`,
:mod:`board.locate.alignment`): the database is then read on its samples instead of between them.

File::

    {"version": 1, "azimuth_start_deg": 0.0, "azimuth_step_deg": 1.0,
     "elevation_deg": [1.2, null, ...], "meta": {...},
     "fine": {"azimuth_step_deg": 0.1, "elevation_deg": [...]}}      (optional)
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
    """elevation_deg : (N,) float64 degrees, NaN = unseen; N * azimuth_step_deg must be 360.

    fine_elevation_deg, fine_step_deg : optional, the same line every ``fine_step_deg`` (an integer
    fraction of ``azimuth_step_deg``) from ``azimuth_start_deg``; both or neither.
    """

    elevation_deg: np.ndarray
    azimuth_start_deg: float = 0.0
    azimuth_step_deg: float = 1.0
    meta: dict = field(default_factory=dict)
    fine_elevation_deg: np.ndarray | None = None
    fine_step_deg: float | None = None

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
        if (self.fine_elevation_deg is None) != (self.fine_step_deg is None):
            raise InvalidInputError("a skyline's fine samples need both fine_elevation_deg and fine_step_deg")
        if self.fine_elevation_deg is not None:
            fe = np.asarray(self.fine_elevation_deg, dtype=np.float64)
            step = float(self.fine_step_deg)
            ratio = self.azimuth_step_deg / step if step > 0 else float("nan")
            if (fe.ndim != 1 or not math.isclose(fe.size * step, 360.0, rel_tol=0, abs_tol=1e-6)
                    or not (ratio >= 2 and abs(ratio - round(ratio)) < 1e-6)):
                raise InvalidInputError(
                    f"fine samples ({fe.size} of {step} degrees) must cover 360 degrees at an integer fraction "
                    f"(1/2 or finer) of the skyline's {self.azimuth_step_deg} degree step")
            object.__setattr__(self, "fine_elevation_deg", fe)
            object.__setattr__(self, "fine_step_deg", step)

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

    @property
    def has_fine(self) -> bool:
        """True when the skyline carries fine samples."""
        return self.fine_elevation_deg is not None

    def resampled(self, azimuth_start_deg: float) -> "Skyline":
        """The skyline on the same step from another start (degrees), read off the fine samples (periodic
        linear interpolation; NaN next to an unseen fine sample), without fine samples of its own.

        The coarse samples are fine samples, so ``resampled(self.azimuth_start_deg)`` is ``self``'s line."""
        if not self.has_fine:
            raise ValueError("resampling a skyline needs its fine samples (Skyline.fine_elevation_deg)")
        fe = self.fine_elevation_deg
        az = float(azimuth_start_deg) + np.arange(self.n) * self.azimuth_step_deg
        u = (az - self.azimuth_start_deg) / self.fine_step_deg
        n = fe.size
        u = np.mod(u, n)
        i0 = np.floor(u).astype(np.intp) % n
        t = u - np.floor(u)
        e0, e1 = fe[i0], fe[(i0 + 1) % n]
        el = np.where(t < 1e-9, e0, np.where(t > 1 - 1e-9, e1, (1.0 - t) * e0 + t * e1))
        return Skyline(el, float(azimuth_start_deg), self.azimuth_step_deg, dict(self.meta))

    def to_dict(self) -> dict:
        d = {
            "version": SKYLINE_VERSION,
            "azimuth_start_deg": float(self.azimuth_start_deg),
            "azimuth_step_deg": float(self.azimuth_step_deg),
            "elevation_deg": [None if not np.isfinite(v) else round(float(v), 6) for v in self.elevation_deg],
            "meta": self.meta,
        }
        if self.has_fine:
            d["fine"] = {"azimuth_step_deg": float(self.fine_step_deg),
                         "elevation_deg": [None if not np.isfinite(v) else round(float(v), 6)
                                           for v in self.fine_elevation_deg]}
        return d

    @classmethod
    def from_dict(cls, d: dict, where: str = "skyline") -> "Skyline":
        if not isinstance(d, dict):
            raise FormatError(f"{where}: expected a JSON object with 'elevation_deg'")
        if d.get("version") != SKYLINE_VERSION:
            raise FormatError(f"{where}: skyline version {d.get('version')!r} is not supported "
                              f"(this skyloc reads version {SKYLINE_VERSION})")
        try:
            el = np.array([np.nan if v is None else float(v) for v in d["elevation_deg"]], dtype=np.float64)
            fine = d.get("fine")
            fe, fs = None, None
            if fine is not None:
                fe = np.array([np.nan if v is None else float(v) for v in fine["elevation_deg"]], dtype=np.float64)
                fs = float(fine["azimuth_step_deg"])
            return cls(el, float(d.get("azimuth_start_deg", 0.0)), float(d.get("azimuth_step_deg", 360.0 / len(el))),
                       dict(d.get("meta", {})), fe, fs)
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
