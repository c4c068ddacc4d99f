"""Everything a campaign draws from its seed: the site, the hidden poses and the list of cases.

All coordinates are metres in the DEM's metric working CRS; angles in degrees (azimuths clockwise
from grid north).  Each candidate pose is drawn from its own random stream
(``SeedSequence([seed, 0xCA4, i])``), so the i-th candidate is the same whatever happens to the
others; a candidate whose true horizon has too little relief is rejected and reported, never
silently dropped.  Positions are always off the database grid: at least 20 % of a step away from
every node line in x and y.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from board.errors import InvalidInputError
from render_service.campaign.profiles import Profile

#: Position of a candidate inside its grid cell, in steps: never closer than this to a node line.
OFF_GRID_MARGIN = 0.2
#: Sun elevation range for dressed looks (degrees above the horizon).
SUN_ELEVATION_DEG = (12.0, 60.0)


@dataclass(frozen=True)
class Site:
    """The search area: centre and side (metres), grid step (metres), DEM bounds."""

    center_x: float
    center_y: float
    area_m: float
    step_m: float
    dem_bounds: tuple[float, float, float, float]

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Candidate:
    """A hidden pose drawn from the seed (metres, degrees); ``sun_*`` for dressed looks."""

    index: int
    x: float
    y: float
    heading_deg: float
    sun_azimuth_deg: float
    sun_elevation_deg: float
    texture_seed: int
    tilt_sign: float
    prior_angle_deg: float
    prior_fraction: float
    heading_prior_offset_deg: float

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Case:
    """One row of results.csv: which table, which look, which pose, what to do.

    kind : "panorama" (render + extract + locate), "acquisition" (NavCam frames + panorama building
        + extract + locate), "window" (a window database around a prior + locate the skyline of
        ``source``), "heading" (heading-only mode on the skyline of ``source``), "lost_large"
        (lost in space over the profile's large area, on the skyline of ``source``)
    source : case_id whose extracted skyline this case reuses (window and heading cases)
    """

    case_id: str
    table: str
    kind: str
    preset: str
    pose: int
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    mode: str = "lost"
    source: str = ""
    prior_offset_m: float = 0.0
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)


def choose_site(profile: Profile, bounds: tuple[float, float, float, float], rng: np.random.Generator,
                area_m: float | None = None) -> Site:
    """A search area of ``profile.area_m`` inside the DEM, centred at random away from its edges.

    The margin left to the DEM's edge is ``profile.site_margin_m`` when set, else the larger of 300 m
    and 15 % of the DEM's smaller side, so that horizons are not cut by the DEM's end on the near side.
    Raises InvalidInputError, with the largest area and margin that would fit, when the DEM is too small.
    """
    area = float(area_m if area_m is not None else profile.area_m)
    xmin, ymin, xmax, ymax = (float(b) for b in bounds)
    side = min(xmax - xmin, ymax - ymin)
    margin = float(profile.site_margin_m) if profile.site_margin_m > 0 else max(300.0, 0.15 * side)
    lo_x, hi_x = xmin + margin + area / 2, xmax - margin - area / 2
    lo_y, hi_y = ymin + margin + area / 2, ymax - margin - area / 2
    if lo_x > hi_x or lo_y > hi_y:
        fits = side - 2 * margin
        hint = (f"a smaller area (--set area_m=M, at most {fits:.0f} m with this margin)" if fits > 0 else
                f"a smaller margin (--set site_margin_m=M, at most {(side - area) / 2:.0f} m for this area; "
                "horizons then end at the DEM's edge sooner)" if side > area else "a smaller area (--set area_m=M)")
        raise InvalidInputError(
            f"the DEM ({xmax - xmin:.0f} x {ymax - ymin:.0f} m) is too small for a {area:.0f} m search area with "
            f"{margin:.0f} m of terrain around it: use a larger DEM or {hint}")
    cx = float(rng.uniform(lo_x, hi_x))
    cy = float(rng.uniform(lo_y, hi_y))
    # snap the centre to the step so that grids of several runs line up; the poses stay off the grid
    step = float(profile.step_m)
    cx, cy = round(cx / step) * step, round(cy / step) * step
    return Site(cx, cy, area, step, (xmin, ymin, xmax, ymax))


def prior_margin_m(profile: Profile) -> float:
    """How far a position prior may lie from its pose (metres): the window cases' largest prior offset and,
    when the profile runs heading-only cases, their largest (table 8's 20 m)."""
    heading = max(profile.heading_offsets_m, default=0.0) if profile.heading_presets else 0.0
    return max(profile.window_prior_max_m, heading)


def pose_half_m(profile: Profile) -> float:
    """Half side of the square where poses are drawn: the area less the window and prior margins, so that every
    position prior a case is given lies on the database's grid (a prior off it is refused by the matcher)."""
    half = profile.area_m / 2 - profile.window_m / 2 - prior_margin_m(profile) - profile.step_m
    if half < 2 * profile.step_m:
        raise InvalidInputError(f"a {profile.area_m:g} m area is too small for {profile.window_m:g} m windows with "
                                f"priors {prior_margin_m(profile):g} m off: enlarge the area")
    return half


def draw_candidate(seed: int, index: int, site: Site, profile: Profile) -> Candidate:
    """The ``index``-th candidate pose of a campaign seeded ``seed`` (independent of the others)."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, 0xCA4, int(index)]))
    half = pose_half_m(profile)
    step = site.step_m
    n_cells = int(math.floor(half / step))

    def coord(c0: float) -> float:
        k = int(rng.integers(-n_cells, n_cells))
        frac = float(rng.uniform(OFF_GRID_MARGIN, 1.0 - OFF_GRID_MARGIN))
        return c0 + (k + frac) * step

    x, y = coord(site.center_x), coord(site.center_y)
    return Candidate(
        index=int(index), x=x, y=y, heading_deg=float(rng.uniform(0.0, 360.0)),
        sun_azimuth_deg=float(rng.uniform(0.0, 360.0)),
        sun_elevation_deg=float(rng.uniform(*SUN_ELEVATION_DEG)),
        texture_seed=int(rng.integers(1, 2**31 - 1)), tilt_sign=float(rng.choice([-1.0, 1.0])),
        prior_angle_deg=float(rng.uniform(0.0, 360.0)), prior_fraction=float(rng.uniform(0.0, 1.0)),
        heading_prior_offset_deg=float(rng.uniform(-1.0, 1.0)))


def horizon_relief_deg(el_deg: np.ndarray) -> float:
    """How much the true horizon rises above its lowest part: 98th minus 2nd percentile, degrees."""
    el = np.asarray(el_deg, dtype=float)
    el = el[np.isfinite(el)]
    if el.size == 0:
        return 0.0
    return float(np.percentile(el, 98) - np.percentile(el, 2))


def off_grid_distance_steps(x: float, y: float, site: Site) -> float:
    """Distance of (x, y) to the nearest node line of the site's grid, in steps (0 = on a line)."""
    fx = ((x - site.center_x) / site.step_m) % 1.0
    fy = ((y - site.center_y) / site.step_m) % 1.0
    return float(min(fx, 1 - fx, fy, 1 - fy))


def plan_cases(profile: Profile, n_poses: int) -> list[Case]:
    """The cases of a profile over ``n_poses`` accepted poses (indices 0..n_poses-1), in run order."""
    cases: list[Case] = []
    for k in range(n_poses):
        for preset in profile.t4_presets:
            cases.append(Case(f"t4-{preset}-p{k:02d}", "4", "panorama", preset, k))
        for preset in profile.t5_presets:
            for axis in ("pitch", "roll"):
                cases.append(Case(f"t5-{preset}-{axis}-p{k:02d}", "5", "panorama", preset, k,
                                  extra={"tilt_axis": axis}))
    for k in range(min(profile.n_acquisitions, n_poses)):
        axis = ""
        if profile.acq_tilt_every and k % profile.acq_tilt_every == profile.acq_tilt_every - 1:
            axis = "pitch" if (k // profile.acq_tilt_every) % 2 == 0 else "roll"
        cases.append(Case(f"t6-{profile.acq_preset}{'-' + axis if axis else ''}-p{k:02d}", "6", "acquisition",
                          profile.acq_preset, k, extra={"tilt_axis": axis}))
    for k in range(min(profile.n_window_poses, n_poses)):
        for preset in profile.window_presets:
            cases.append(Case(f"t7-{preset}-p{k:02d}", "7", "window", preset, k, mode="window",
                              source=f"t4-{preset}-p{k:02d}"))
    for k in range(min(profile.n_heading_poses, n_poses)):
        for preset in profile.heading_presets:
            for d in profile.heading_offsets_m:
                cases.append(Case(f"t8-{preset}-d{d:04.1f}-p{k:02d}", "8", "heading", preset, k, mode="heading",
                                  source=f"t4-{preset}-p{k:02d}", prior_offset_m=float(d)))
    if profile.large_area_m > 0:
        for k in range(n_poses):
            for preset in profile.t4_presets:
                cases.append(Case(f"t4L-{preset}-p{k:02d}", "4L", "lost_large", preset, k,
                                  source=f"t4-{preset}-p{k:02d}",
                                  extra={"area_m": float(profile.large_area_m)}))
    ids = [c.case_id for c in cases]
    if len(set(ids)) != len(ids):
        raise AssertionError("duplicate case ids")  # a programming error, not bad input
    for c in cases:
        if c.source and c.source not in ids:
            raise InvalidInputError(f"case {c.case_id} reuses the skyline of {c.source}, which the profile does "
                                    f"not render: add {c.preset!r} to t4_presets")
    return cases


def tilt_of(case: Case, cand: Candidate, profile: Profile) -> tuple[float, float]:
    """(pitch, roll) degrees of a case at a candidate pose."""
    axis = case.extra.get("tilt_axis", "")
    t = profile.tilt_deg * cand.tilt_sign
    return (t, 0.0) if axis == "pitch" else ((0.0, t) if axis == "roll" else (0.0, 0.0))


def prior_of(case: Case, cand: Candidate, profile: Profile) -> tuple[float, float, float]:
    """(x, y, offset m) of the position prior of a window or heading case."""
    if case.kind == "window":
        d = profile.window_prior_max_m * cand.prior_fraction
    else:
        d = case.prior_offset_m
    a = math.radians(cand.prior_angle_deg)
    return cand.x + d * math.sin(a), cand.y + d * math.cos(a), d
