"""The reference report's campaign figures (section 12, tables 4-8), for side-by-side tables.

Errors are the report's, in metres and degrees; the position error is the norm of its x and y
errors.  The report's grid was 1 x 1 km at 5 m (tables 4-6), 20 x 20 m at 1 m (table 7) and
50 x 50 m at 1 m (table 8).  Its table 8 offsets were dx = dy = d, i.e. an offset of norm d * sqrt(2).
"""
from __future__ import annotations

import math


def _norm(x: float, y: float) -> float:
    return round(math.hypot(x, y), 2)


#: Table 4: (panorama id, noise level 1 binary / 2 realistic / 3 distorted) -> (position error m, heading error deg)
TABLE4 = {
    (1, "binary"): (_norm(1.5, 3), 0.0), (1, "realistic"): (_norm(1.5, 2), 0.0),
    (1, "distorted"): (_norm(1.5, 13), 12.0),
    (2, "binary"): (_norm(0.75, 2), 0.0), (2, "realistic"): (_norm(0.75, 2), 0.0),
    (2, "distorted"): (_norm(19.2, 28), 8.0),
    (3, "binary"): (_norm(1.5, 2), 0.0), (3, "realistic"): (_norm(1.5, 2), 0.0),
    (3, "distorted"): (_norm(3.5, 13), 0.0),
}
#: Table 5 (binary panoramas, 10 degrees of pitch or roll): id -> {"pitch": (m, deg), "roll": (m, deg)}
TABLE5 = {
    4: {"pitch": (_norm(265, 930), 173.0), "roll": (_norm(175, 320), 169.0)},
    5: {"pitch": (_norm(365, 270), 154.0), "roll": (_norm(565, 610), 119.0)},
    6: {"pitch": (_norm(320, 420), 0.0), "roll": (_norm(205, 105), 107.0)},
}
#: Table 6 (after landing, whole algorithm): kind -> (position error m, heading error deg or None, seconds)
TABLE6 = {"real": (_norm(4.52, 0.55), None, 20.3), "simulated": (0.0, 0.0, 36.61)}
#: Table 7 (end of traverse, 20 x 20 m at 1 m): kind -> (position error m, heading error deg or None, seconds)
TABLE7 = {"real": (_norm(5.52, 0.55), None, 6.69), "simulated": (0.0, 0.0, 18.45)}
#: Table 8 (heading only, simulated acquisition): per-axis offset d (m) -> heading error (deg)
TABLE8_SIMULATED = {0: 0.0, 2: 0.0, 4: 1.0, 6: 1.0, 8: 1.0, 10: 2.0, 15: 2.0, 20: 2.0}
TABLE8_REAL = {0: 0.0, 2: 0.0, 4: 1.0, 6: 1.0, 8: 1.0, 10: 1.0, 15: 3.0, 20: 4.0}


def table4_summary() -> dict[str, dict[str, float]]:
    """Per noise level: median and max position error (m) and max heading error (deg) of the report."""
    out = {}
    for level in ("binary", "realistic", "distorted"):
        errs = sorted(v[0] for k, v in TABLE4.items() if k[1] == level)
        heads = [v[1] for k, v in TABLE4.items() if k[1] == level]
        out[level] = {"n": len(errs), "median_m": errs[len(errs) // 2], "max_m": errs[-1],
                      "max_heading_deg": max(heads)}
    return out


def table5_summary() -> dict[str, dict[str, float]]:
    out = {}
    for axis in ("pitch", "roll"):
        errs = sorted(v[axis][0] for v in TABLE5.values())
        out[axis] = {"n": len(errs), "median_m": errs[len(errs) // 2], "max_m": errs[-1],
                     "max_heading_deg": max(v[axis][1] for v in TABLE5.values())}
    return out


def table8_reference(offset_m: float) -> float | None:
    """The report's simulated heading error at the nearest per-axis offset it tested (deg)."""
    keys = sorted(TABLE8_SIMULATED)
    k = min(keys, key=lambda d: abs(d - offset_m))
    return TABLE8_SIMULATED[k] if abs(k - offset_m) <= 1.0 else None
