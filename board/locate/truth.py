"""A fix against a known truth: position and heading errors, and whether the truth lies in the 95 % ellipse.

Metres in the database CRS, degrees (heading clockwise from grid north).  Pitch and roll are
compared only when the truth has them and the fix's tilt can be put in the same frame (see
:attr:`TruthComparison.tilt_note`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from board.conventions import wrap_deg180
from board.locate.fix import Fix
from board.pose.confidence import CHI2_2D_95


@dataclass(frozen=True)
class Truth:
    """A true pose: x, y metres in the database CRS; heading, pitch, roll degrees (None: unknown)."""

    x: float
    y: float
    heading_deg: float | None = None
    pitch_deg: float | None = None
    roll_deg: float | None = None
    source: str = "--truth"


@dataclass(frozen=True)
class TruthComparison:
    """Errors of a fix against a truth (fix minus truth).

    dx_m, dy_m, error_m : position error (metres); heading_error_deg : wrapped to [-180, 180);
    pitch_error_deg / roll_error_deg : of the mast tilt ``tilt_offset + fitted tilt`` (None when the truth
    has no tilt); in_ellipse95 : the truth lies inside the fix's 95 % ellipse (None without covariance).
    """

    truth: Truth
    dx_m: float
    dy_m: float
    error_m: float
    heading_error_deg: float | None
    pitch_error_deg: float | None
    roll_error_deg: float | None
    in_ellipse95: bool | None

    def to_json_dict(self) -> dict:
        def f(v):
            return None if v is None or not math.isfinite(v) else round(float(v), 6)

        t = self.truth
        return {"source": t.source, "x": f(t.x), "y": f(t.y), "heading_deg": f(t.heading_deg),
                "pitch_deg": f(t.pitch_deg), "roll_deg": f(t.roll_deg), "dx_m": f(self.dx_m), "dy_m": f(self.dy_m),
                "error_m": f(self.error_m), "heading_error_deg": f(self.heading_error_deg),
                "pitch_error_deg": f(self.pitch_error_deg), "roll_error_deg": f(self.roll_error_deg),
                "in_ellipse95": self.in_ellipse95}


def compare_with_truth(fix: Fix, truth: Truth, *, tilt_offset_deg: tuple[float, float] = (0.0, 0.0)) -> TruthComparison:
    """Errors of ``fix`` against ``truth``.

    tilt_offset_deg : (pitch, roll) the query skyline was levelled with before matching (an acquisition's
        measured attitude), degrees: the fix's pitch/roll are the residual after it, so the mast tilt
        compared with the truth is offset + residual (first order in the angles, exact for a single axis).
    """
    dx, dy = fix.x - truth.x, fix.y - truth.y
    dh = None if truth.heading_deg is None else float(wrap_deg180(fix.heading_deg - truth.heading_deg))
    dp = None if truth.pitch_deg is None else tilt_offset_deg[0] + fix.pitch_deg - truth.pitch_deg
    dr = None if truth.roll_deg is None else tilt_offset_deg[1] + fix.roll_deg - truth.roll_deg
    inside = None
    cov = np.asarray(fix.cov_xy, dtype=float)
    if np.isfinite(cov).all():
        try:
            d2 = float(np.array([dx, dy]) @ np.linalg.solve(cov, np.array([dx, dy])))
            inside = d2 <= CHI2_2D_95
        except np.linalg.LinAlgError:
            inside = None
    return TruthComparison(truth, float(dx), float(dy), math.hypot(dx, dy), dh, dp, dr, inside)
