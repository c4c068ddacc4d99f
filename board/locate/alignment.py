"""Second pass with the query sampled on the database's own azimuths.

The database stores each node's skyline every ``azimuth_step_deg`` from grid north.  A query's samples sit
at the rover's heading plus multiples of the same step, so in general between the database's azimuths,
where the matcher interpolates the database linearly.  Skylines have structure finer than a degree (a
DEM feature of 100-250 m seen 20-40 km away spans 0.2-0.4 deg), so that interpolation is the database's
largest model error on open terrain: on the flat Aristoteles floor (seed 48) the true horizon, located
at the true position, left 0.012 deg RMS at its own heading against 0.0034 deg (the database's 0.01 deg
quantisation) with its samples on the database's azimuths.  The extra error spreads the score map's
likelihood, and correct fixes are reported ``ambiguous`` (docs/matching.md, "Aligned second pass").

When the query carries fine samples (:attr:`board.skyline.Skyline.fine_elevation_deg`, the extraction
writes them) and the first fix gives the heading, the query is sampled again from a start shifted by
less than half a step, so that heading + azimuth falls on the database's azimuths, and located again.
Tilt moves a sample's ENU azimuth by up to tilt x tan(elevation): the shift is the level one, the
residual misalignment of a tilted query is that small term.  Degrees throughout.
"""
from __future__ import annotations

from board.skydb import SkyDBMeta
from board.skyline import Skyline

#: a first fix whose samples already sit within this fraction of a step of the database's azimuths is kept
MIN_SHIFT_STEPS = 0.05


def alignment_shift_deg(meta: SkyDBMeta, skyline: Skyline, heading_deg: float) -> float:
    """The shift of the query's start (degrees, in [-step/2, step/2)) that puts heading + relative azimuth
    on the database's azimuth grid."""
    step = skyline.azimuth_step_deg
    d = (meta.azimuth_start_deg - heading_deg - skyline.azimuth_start_deg) % step
    return d - step if d >= 0.5 * step else d


def aligned_query(meta: SkyDBMeta, skyline: Skyline, heading_deg: float) -> tuple[Skyline, float] | None:
    """The query resampled onto the database's azimuths at ``heading_deg`` and the shift applied, or None
    when the skyline has no fine samples or is already within ``MIN_SHIFT_STEPS`` of them."""
    if not skyline.has_fine:
        return None
    shift = alignment_shift_deg(meta, skyline, heading_deg)
    if abs(shift) < MIN_SHIFT_STEPS * skyline.azimuth_step_deg:
        return None
    return skyline.resampled(skyline.azimuth_start_deg + shift), shift
