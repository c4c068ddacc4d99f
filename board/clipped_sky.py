"""The line of a clipped sky: where it is placed, and where the edge is.

Where the sky is brighter than full scale, the blurred sky/ground step is clipped on its sky side and the
steepest step that remains, where the detector places the line, lies below the edge (towards the ground).
The offset grows with how far the sky exceeds full scale and with the width of the line spread function
(:mod:`board.detect.clipped_edge` measures what stands in for both: the clipped band's height above the line
and the view's unclipped step width).  Its model, per column:

    offset (elevation pixels, the line too low) = CLIPPED_SHIFT_GAIN * width_px ** 2 * min(band_deg, MAX_BAND_DEG)

with ``band_deg`` the clipped band's height in degrees of elevation and ``width_px`` the view's step sigma
(pixels; ``EDGE_WIDTH_FALLBACK_PX`` when the view has too few unclipped steps to measure it).  The form is an
empirical fit: on the simulator's renders the offset grows about linearly with the band's height up to
20 degrees, and about twice as fast with the lens blur of the ``distorted`` look (width 0.75 px) as without
(0.54 px).  The band is counted over the mixed row just above the line (``DetectorParams.clipped_gap_rows``):
a third of a high sun's clipped columns have that row below full scale.  ``CLIPPED_SHIFT_GAIN`` was fitted on
Aristoteles 114's 30 pitched views (Moon, realistic look; session 30) by ``python -m
benchmarks.calibrate_clipped_sky RUN --cases 't5-{look}-pitch-p*'``; docs/benchmarks.md (session 30) gives the
held-out checks (session 10's gain, 0.029, was fitted with a count that missed those columns and took them
for unclipped ones).  A sky clipped in every column of a view is moved as much as one clipped in part of it; a
clipped ground (a black sky over saturated ground) is not modelled.
"""
from __future__ import annotations

import math

import numpy as np

#: offset per degree of clipped band and per squared pixel of step width (fitted, see the module docstring)
CLIPPED_SHIFT_GAIN = 0.053
#: step width assumed where a view has too few unclipped steps to measure it (pixels; the simulator's
#: renders without lens blur measure 0.53-0.57)
EDGE_WIDTH_FALLBACK_PX = 0.55
#: the band's height is counted up to this (degrees; the fit's range)
MAX_BAND_DEG = 25.0


def clipped_line_offset_px(clipped_rows: np.ndarray, elevation_step_deg: float, edge_width_px: float,
                           gain: float = CLIPPED_SHIFT_GAIN) -> np.ndarray:
    """How far below the edge (elevation pixels) the line of each column lies, from its clipped band
    (``clipped_rows`` rows of ``elevation_step_deg`` degrees) and the view's step width (pixels; NaN: the
    fallback).  0 where the sky above the line is not clipped."""
    w = edge_width_px if edge_width_px is not None and math.isfinite(edge_width_px) else EDGE_WIDTH_FALLBACK_PX
    band = np.minimum(np.asarray(clipped_rows, dtype=np.float64) * abs(float(elevation_step_deg)), MAX_BAND_DEG)
    return gain * w * w * band


__all__ = ["CLIPPED_SHIFT_GAIN", "EDGE_WIDTH_FALLBACK_PX", "MAX_BAND_DEG", "clipped_line_offset_px"]
