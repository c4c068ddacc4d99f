"""The result of :func:`board.locate.locate`: a pose with its confidence, and the pictures' payload apart."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from board.match.search import ScoreMap
from board.skydb import GridSpec


@dataclass
class FixPictures:
    """What :func:`board.plots.plot_fix` draws besides the numbers (not serialised).

    score_map : the coarse score map (None in heading mode with an exact position)
    query_theta_deg, query_el_deg : (N,) the query skyline, azimuths relative to the heading, degrees
    db_skyline_deg : (N,) the database skyline interpolated at the fix, ENU azimuths from
        ``db_azimuth_start_deg``, degrees
    grid : the database's grid (to turn score-map indices into coordinates)
    """

    score_map: ScoreMap | None = None
    query_theta_deg: np.ndarray | None = None
    query_el_deg: np.ndarray | None = None
    db_skyline_deg: np.ndarray | None = None
    grid: GridSpec | None = None
    db_azimuth_start_deg: float = 0.0


@dataclass
class Fix:
    """A pose estimate with its confidence (metres in the database CRS, degrees).

    status is one of :data:`board.pose.confidence.STATUSES` ("ok", "ambiguous", "failed"); reason says why
    when it is not "ok".  cov_xy : 2x2 position covariance (m^2); ellipse95_m : (semi-major, semi-minor,
    azimuth of the major axis).  pitch_deg and roll_deg are the mast's tilt from the local vertical as
    fitted (the query skyline is taken as observed, not levelled).  grid_row/grid_col are the fractional
    grid indices of the fix; at_grid_edge is True when it lies within one grid step of the database
    grid's edge (the rover may be beyond it).  n_outliers : query columns masked because the fix could
    not explain them (:mod:`board.locate.robust`); above_dem / below_dem : those columns as sectors
    (``{"from_deg", "to_deg", "n", "excess_deg"}``, azimuths in the query's frame, degrees) where the
    query's boundary stands above the DEM's skyline (a near rock or an object not in the DEM: a real
    boundary, not the DEM's skyline) or lies below it (the detector missed the skyline there).
    aligned_shift_deg : the shift of the query's azimuths for the second pass on the database's own
    azimuths (:mod:`board.locate.alignment`; 0 when there was none).
    """

    x: float
    y: float
    heading_deg: float
    pitch_deg: float
    roll_deg: float
    sigma_x_m: float
    sigma_y_m: float
    sigma_heading_deg: float
    cov_xy: np.ndarray
    status: str
    reason: str
    elapsed_s: float
    mode: str = "lost"
    sigma_pitch_deg: float = float("nan")
    sigma_roll_deg: float = float("nan")
    ellipse95_m: tuple[float, float, float] = (float("nan"),) * 3
    offset_deg: float = 0.0
    rms_residual_deg: float = float("nan")
    noise_deg: float = float("nan")
    n_eff: float = float("nan")
    ambiguity_ratio: float = float("nan")
    far_mass: float = float("nan")
    coverage_deg: float = 0.0
    n_scored: int = 0
    n_pruned: int = 0
    grid_row: float = float("nan")
    grid_col: float = float("nan")
    at_grid_edge: bool = False
    n_outliers: int = 0
    aligned_shift_deg: float = 0.0
    above_dem: list = field(default_factory=list)
    below_dem: list = field(default_factory=list)
    pictures: FixPictures | None = field(default=None, repr=False)

    def to_json_dict(self) -> dict:
        """JSON-able dict: the pose, its uncertainty and the confidence details (NaN -> null)."""
        def f(v):
            v = float(v)
            return None if not math.isfinite(v) else round(v, 6)

        return {
            "x": f(self.x), "y": f(self.y), "heading_deg": f(self.heading_deg),
            "pitch_deg": f(self.pitch_deg), "roll_deg": f(self.roll_deg),
            "sigma_x_m": f(self.sigma_x_m), "sigma_y_m": f(self.sigma_y_m),
            "sigma_heading_deg": f(self.sigma_heading_deg),
            "sigma_pitch_deg": f(self.sigma_pitch_deg), "sigma_roll_deg": f(self.sigma_roll_deg),
            "cov_xy": [[f(v) for v in row] for row in np.asarray(self.cov_xy)],
            "ellipse95_m": {"semi_major": f(self.ellipse95_m[0]), "semi_minor": f(self.ellipse95_m[1]),
                            "major_azimuth_deg": f(self.ellipse95_m[2])},
            "status": self.status, "reason": self.reason, "elapsed_s": f(self.elapsed_s), "mode": self.mode,
            "offset_deg": f(self.offset_deg), "rms_residual_deg": f(self.rms_residual_deg),
            "noise_deg": f(self.noise_deg), "n_eff": f(self.n_eff),
            "ambiguity_ratio": f(self.ambiguity_ratio), "far_mass": f(self.far_mass),
            "coverage_deg": f(self.coverage_deg), "positions_scored": self.n_scored,
            "positions_pruned": self.n_pruned, "grid_row": f(self.grid_row), "grid_col": f(self.grid_col),
            "at_grid_edge": bool(self.at_grid_edge), "outliers_masked": int(self.n_outliers),
            "query_aligned_shift_deg": f(self.aligned_shift_deg),
            "above_dem_skyline": list(self.above_dem), "below_dem_skyline": list(self.below_dem),
        }
