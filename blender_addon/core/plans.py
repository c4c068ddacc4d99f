"""Pan-tilt acquisition plans: which pan and tilt angles a NavCam takes its frames at.

Angles follow :mod:`board.camera`: pan in degrees clockwise from the rover's heading
(seen from above), tilt in degrees up.  A plan covers an azimuth ``arc_deg`` centred on
``center_pan_deg``:

* a full circle (``arc_deg >= 360``): ``n`` frames ``360 / n`` apart, the first at the centre;
* a partial arc: the outer frame edges sit on the arc's ends, so the frames are
  ``(arc - hfov) / (n - 1)`` apart and the arc is covered exactly.

Overlap of two neighbouring frames is ``1 - step / hfov`` (fraction of a frame's width, in
angle, at the horizon of a level pinhole).  The report's plans: 13 frames over 360 deg at
65 deg give a step of 27.7 deg and 57 % overlap ("about 50 %"); 5 frames over 242 deg.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from board.errors import InvalidInputError

log = logging.getLogger(__name__)

FULL_CIRCLE_DEG = 360.0


@dataclass(frozen=True)
class PanTiltPlan:
    """Frames of an acquisition.

    pan_deg, tilt_deg : (n,) pan and tilt of every frame, degrees
    hfov_deg : horizontal field of view the plan was made for, degrees
    arc_deg : the azimuth arc the plan covers, degrees (360 = full circle)
    """

    pan_deg: tuple[float, ...]
    tilt_deg: tuple[float, ...]
    hfov_deg: float
    arc_deg: float

    @property
    def n_frames(self) -> int:
        return len(self.pan_deg)

    @property
    def step_deg(self) -> float:
        """Pan step between neighbouring frames, degrees (the full circle when there is one frame)."""
        if self.n_frames < 2:
            return FULL_CIRCLE_DEG
        return float(np.mod(self.pan_deg[1] - self.pan_deg[0], 360.0))

    @property
    def overlap(self) -> float:
        """Overlap of neighbouring frames as a fraction of the frame width (negative = gap)."""
        return overlap_fraction(self.step_deg, self.hfov_deg)

    def frames(self) -> list[tuple[float, float]]:
        """[(pan_deg, tilt_deg), ...] in acquisition order."""
        return list(zip(self.pan_deg, self.tilt_deg))


def overlap_fraction(step_deg: float, hfov_deg: float) -> float:
    """Overlap of two frames ``step_deg`` apart with a ``hfov_deg`` field of view (fraction of a frame)."""
    return 1.0 - step_deg / hfov_deg


def _check(n_frames: int, arc_deg: float, hfov_deg: float) -> None:
    if int(n_frames) < 1:
        raise InvalidInputError(f"a pan-tilt plan needs at least 1 frame, got {n_frames}")
    if not (0.0 < hfov_deg < 180.0):
        raise InvalidInputError(f"field of view {hfov_deg} deg must be in (0, 180)")
    if not (0.0 < arc_deg <= FULL_CIRCLE_DEG):
        raise InvalidInputError(f"arc {arc_deg} deg must be in (0, 360]: use 360 for a full panorama")


def plan_frames(n_frames: int, arc_deg: float, hfov_deg: float, *, tilt_deg: float = 0.0,
                center_pan_deg: float = 0.0, allow_gaps: bool = False) -> PanTiltPlan:
    """``n_frames`` frames spread over ``arc_deg`` (see the module docstring), all at ``tilt_deg``.

    Raises InvalidInputError when the frames leave gaps in the arc (step larger than the
    field of view) unless ``allow_gaps``, or when a partial arc is narrower than one frame.
    """
    _check(n_frames, arc_deg, hfov_deg)
    n = int(n_frames)
    if arc_deg >= FULL_CIRCLE_DEG:
        step = FULL_CIRCLE_DEG / n
        pans = center_pan_deg + step * np.arange(n)
    else:
        if arc_deg < hfov_deg - 1e-9:
            raise InvalidInputError(f"an arc of {arc_deg} deg is narrower than one frame ({hfov_deg} deg): "
                                    "widen the arc or use a narrower camera")
        step = 0.0 if n == 1 else (arc_deg - hfov_deg) / (n - 1)
        if n == 1 and arc_deg > hfov_deg + 1e-9 and not allow_gaps:
            raise InvalidInputError(f"one frame of {hfov_deg} deg cannot cover {arc_deg} deg: use more frames")
        pans = center_pan_deg + step * (np.arange(n) - (n - 1) / 2.0)
    if n > 1 and step > hfov_deg + 1e-9 and not allow_gaps:
        raise InvalidInputError(f"{n} frames of {hfov_deg:.1f} deg over {arc_deg:.1f} deg leave gaps "
                                f"({step:.1f} deg apart): use at least "
                                f"{frames_for_overlap(0.0, arc_deg, hfov_deg)} frames")
    pans = np.mod(pans, 360.0)
    return PanTiltPlan(tuple(float(p) for p in pans), tuple(float(tilt_deg) for _ in range(n)),
                       float(hfov_deg), float(arc_deg))


def frames_for_overlap(overlap: float, arc_deg: float, hfov_deg: float) -> int:
    """Fewest frames covering ``arc_deg`` with at least ``overlap`` (fraction of a frame) between neighbours."""
    _check(1, arc_deg, hfov_deg)
    if not (0.0 <= overlap < 1.0):
        raise InvalidInputError(f"overlap {overlap} must be a fraction in [0, 1)")
    max_step = hfov_deg * (1.0 - overlap)
    if arc_deg >= FULL_CIRCLE_DEG:
        return max(1, math.ceil(FULL_CIRCLE_DEG / max_step - 1e-9))
    if arc_deg <= hfov_deg:
        return 1
    return 1 + math.ceil((arc_deg - hfov_deg) / max_step - 1e-9)


def plan_overlap(overlap: float, arc_deg: float, hfov_deg: float, *, tilt_deg: float = 0.0,
                 center_pan_deg: float = 0.0) -> PanTiltPlan:
    """The plan with the fewest frames giving at least ``overlap`` over ``arc_deg``."""
    n = frames_for_overlap(overlap, arc_deg, hfov_deg)
    return plan_frames(n, arc_deg, hfov_deg, tilt_deg=tilt_deg, center_pan_deg=center_pan_deg)


def coverage_mask(plan: PanTiltPlan, az_rel_deg) -> np.ndarray:
    """True where a heading-relative azimuth (degrees) is inside at least one frame's horizontal field.

    Exact for a level pinhole at tilt 0 on the horizon line (frames span ``pan +- hfov/2``).
    """
    az = np.asarray(az_rel_deg, dtype=float)
    seen = np.zeros(az.shape, dtype=bool)
    half = plan.hfov_deg / 2.0
    for pan in plan.pan_deg:
        d = np.abs(np.mod(az - pan + 180.0, 360.0) - 180.0)
        seen |= d <= half + 1e-9
    return seen
