"""Typed options of :func:`board.locate.locate`: what to search, how to score and refine, which parts to run.

Every field has the default the matcher was tuned with; the ablation switches (``reweight``,
``parallax``) are read at call time from here, never from the environment.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from board.errors import InvalidInputError
from board.match.fft_score import MODELS
from board.pose.confidence import Thresholds
from board.pose.refine import PARAMS

#: search modes: the whole grid, a disc around a prior position, or the heading at a known position
MODES = ("lost", "window", "heading")
#: default search radius of window mode (metres)
DEFAULT_RADIUS_M = 30.0


@dataclass(frozen=True)
class LocateOptions:
    """How :func:`board.locate.locate` searches (metres in the database CRS, degrees).

    mode : "lost" (whole grid), "window" (within ``radius_m`` of ``prior_xy``, default 30 m),
        "heading" (position ``prior_xy`` known to ``position_sigma_m``; heading within
        ``heading_window_deg`` of ``heading_prior_deg``)
    prior_xy : (x, y) metres in the database CRS
    radius_m : window mode's search radius (metres); None: :data:`DEFAULT_RADIUS_M`
    heading_prior_deg : heading prior (degrees clockwise from grid north); restricts the heading in
        "heading" mode, and in the other modes too when given
    heading_window_deg : half-width of the allowed heading window around the prior (degrees)
    tilt_prior : (pitch, roll, sigma) degrees from an IMU
    model : coarse score, "tilt" (invariant to small pitch/roll) or "offset" (the report's metric)
    prune : exact Parseval pruning for full panoramas (the result is identical either way)
    n_candidates : coarse candidates (non-maximum suppressed) refined on the sphere
    thresholds : the status policy's thresholds (:class:`board.pose.confidence.Thresholds`)
    position_sigma_m : heading mode: uncertainty of the given position (metres); position and heading are
        estimated together within it (0: the position is taken as exact and only the heading and tilt fitted)
    reweight : run the final refinement weighted by the grid error (ablation switch; True as tuned)
    parallax : the weighted refinement interpolates with parallax when the database stores horizon
        distances (ablation switch; True as tuned)
    stored_heights : the parallax interpolation moves the eye between nodes by the database's stored ground
        heights when it holds them (False: estimated from the skylines, as for a store without them; ablation
        switch, docs/matching.md "Eye heights between nodes")
    robust : mask the query columns the first fix cannot explain and locate again without them
        (:mod:`board.locate.robust`; a clean query is unaffected)
    align : a query with fine samples is located again, sampled on the database's azimuths at the first
        fix's heading (:mod:`board.locate.alignment`; a query without them is unaffected)
    """

    mode: str = "lost"
    prior_xy: tuple[float, float] | None = None
    radius_m: float | None = None
    heading_prior_deg: float | None = None
    heading_window_deg: float = 10.0
    tilt_prior: tuple[float, float, float] | None = None
    model: str = "tilt"
    prune: bool = True
    n_candidates: int = 5
    thresholds: Thresholds = field(default_factory=Thresholds)
    position_sigma_m: float = 20.0
    reweight: bool = True
    parallax: bool = True
    stored_heights: bool = True
    robust: bool = True
    align: bool = True

    @classmethod
    def from_keywords(cls, base: LocateOptions | None = None, **kw) -> LocateOptions:
        """``base`` (default options when None) with the fields named in ``kw`` replaced.

        The keyword form of :func:`board.locate.locate` (``mode=..., prior_xy=...``) goes through
        here; ``thresholds=None`` means the defaults.  An unknown name is a ``TypeError``.
        """
        names = {f.name for f in fields(cls)}
        bad = sorted(set(kw) - names)
        if bad:
            raise TypeError(f"locate() got unknown option(s) {', '.join(bad)}: use one of {', '.join(sorted(names))}")
        if kw.get("thresholds", 0) is None:
            kw["thresholds"] = Thresholds()
        base = base or cls()
        return cls(**{**{n: getattr(base, n) for n in names}, **kw})

    def validate(self) -> None:
        """Raise :class:`InvalidInputError` naming the option and the fix when the options contradict."""
        if self.mode not in MODES:
            raise InvalidInputError(f"unknown mode {self.mode!r}: use one of {', '.join(MODES)}")
        if self.model not in MODELS:
            raise InvalidInputError(f"unknown model {self.model!r}: use one of {', '.join(MODELS)}")
        if self.mode in ("window", "heading") and self.prior_xy is None:
            raise InvalidInputError(f"mode {self.mode!r} needs a prior position: pass --prior X,Y")
        if self.mode == "heading" and self.heading_prior_deg is None:
            raise InvalidInputError("mode 'heading' needs --heading-prior DEG")
        tp = self.tilt_prior
        if tp is not None and not (len(tp) == 3 and tp[2] > 0):
            raise InvalidInputError("tilt prior must be (pitch_deg, roll_deg, sigma_deg) with sigma > 0")
        if not (self.heading_window_deg > 0 and math.isfinite(self.heading_window_deg)):
            raise InvalidInputError(f"heading window must be a positive number of degrees, got "
                                    f"{self.heading_window_deg}")
        if self.n_candidates < 1:
            raise InvalidInputError(f"n_candidates must be at least 1, got {self.n_candidates}")

    @property
    def free(self) -> tuple[str, ...]:
        """Pose parameters the position refinements fit: all five with the tilt model, else no tilt."""
        return PARAMS if self.model == "tilt" else ("row", "col", "heading")

    @property
    def fixed_position(self) -> bool:
        """Heading mode with an exact position: no search, only heading (and tilt) fitted."""
        return self.mode == "heading" and self.position_sigma_m <= 0
