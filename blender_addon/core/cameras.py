"""NavCam presets from the reference report's annex, and custom cameras.

A preset is a pinhole with square pixels, centred principal point and a mast height.
Its field of view is fixed by the horizontal angle: ``fx = (width / 2) / tan(hfov / 2)``
and ``fy = fx``, so the vertical angle follows from the image aspect ratio.

Two annex entries cannot both hold for a pinhole with square pixels; this module keeps the
horizontal angle and says so in each preset's ``note``:

* ExoMars NavCam: 1024 x 1024 px, 65 deg horizontal.  The annex also gives 35 deg vertical,
  which would need pixels 1.9 times taller than wide on a square sensor.  We keep 65 x 65 deg
  (square sensor, square pixels), which is the published ExoMars NavCam field of view.
* Mars 2020 NavCam: 5120 x 3840 px, 96 x 73 deg.  These angles are ``pixels x IFOV``
  (0.33 mrad/px, an angle-linear lens); a pinhole with square pixels and 96 deg across
  sees 79.6 deg vertically.  We keep 96 deg horizontal (what sets the pan-tilt overlap).

The Magellium bench (1600 x 1200, 62 x 48 deg) is consistent: 62 deg across gives 48.5 deg.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

from board.camera import CameraModel
from board.errors import InvalidInputError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CameraPreset:
    """A camera on a mast.

    name : preset key ("exomars", "mars2020", "magellium", "custom")
    width, height : image size, pixels
    hfov_deg : horizontal field of view of the pinhole, degrees edge to edge
    mast_height_m : height of the optical centre above the ground, metres
    note : where the numbers come from and which were kept when they conflict
    """

    name: str
    width: int
    height: int
    hfov_deg: float
    mast_height_m: float
    note: str = ""

    def __post_init__(self) -> None:
        if int(self.width) < 8 or int(self.height) < 8:
            raise InvalidInputError(f"camera {self.name!r}: size {self.width}x{self.height} px is too small; "
                                    "give at least 8 x 8 pixels")
        if not (1.0 <= self.hfov_deg <= 170.0):
            raise InvalidInputError(f"camera {self.name!r}: horizontal field of view {self.hfov_deg} deg must be "
                                    "between 1 and 170 degrees (a pinhole cannot see 180)")
        if not (0.0 < self.mast_height_m <= 100.0):
            raise InvalidInputError(f"camera {self.name!r}: mast height {self.mast_height_m} m must be in (0, 100]")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (fx = fy)."""
        return (self.width / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def vfov_deg(self) -> float:
        """Vertical field of view implied by square pixels, degrees edge to edge."""
        return 2.0 * math.degrees(math.atan((self.height / 2.0) / self.focal_px))

    def camera_model(self, *, k1: float = 0.0, k2: float = 0.0, p1: float = 0.0, p2: float = 0.0,
                     k3: float = 0.0) -> CameraModel:
        """The calibrated camera (board.camera.CameraModel) with the given Brown-Conrady coefficients."""
        return CameraModel.from_fov(self.width, self.height, self.hfov_deg, k1=k1, k2=k2, p1=p1, p2=p2, k3=k3)

    def resized(self, width: int, height: int | None = None) -> "CameraPreset":
        """Same camera at another pixel count: same horizontal angle; height keeps the aspect ratio if omitted."""
        if height is None:
            height = max(8, int(round(width * self.height / self.width)))
        return replace(self, width=int(width), height=int(height))


PRESETS: dict[str, CameraPreset] = {
    "exomars": CameraPreset(
        "exomars", 1024, 1024, 65.0, 2.05,
        note="ExoMars NavCam, annex: 1024x1024 px, 65 deg, mast 2.05 m. The annex's 35 deg vertical contradicts "
             "square pixels on a square sensor; 65 x 65 deg kept."),
    "mars2020": CameraPreset(
        "mars2020", 5120, 3840, 96.0, 1.98,
        note="Mars 2020 NavCam, annex: 5120x3840 px, 96x73 deg (pixels x 0.33 mrad IFOV), mast 1.98 m. "
             "Pinhole with square pixels: 96 deg horizontal kept, 79.6 deg vertical follows."),
    "magellium": CameraPreset(
        "magellium", 1600, 1200, 62.0, 0.75,
        note="Magellium test bench, annex: 1600x1200 px, 62x48 deg, mast 0.75 m (consistent: 48.5 deg vertical)."),
}


def get_preset(name: str, *, width: int | None = None, height: int | None = None, hfov_deg: float | None = None,
               mast_height_m: float | None = None) -> CameraPreset:
    """A preset by name, with optional overrides; ``"custom"`` needs width, height and hfov_deg.

    Overriding only ``width`` keeps the field of view and aspect ratio (a smaller render of
    the same camera).  Raises InvalidInputError naming the known presets.
    """
    key = str(name).strip().lower()
    if key == "custom":
        missing = [n for n, v in (("width", width), ("height", height), ("hfov_deg", hfov_deg)) if v is None]
        if missing:
            raise InvalidInputError(f"a custom camera needs {', '.join(missing)}: give width, height (pixels) "
                                    "and hfov_deg (horizontal field of view, degrees)")
        return CameraPreset("custom", int(width), int(height), float(hfov_deg),
                            float(mast_height_m if mast_height_m is not None else 2.0), note="custom camera")
    if key not in PRESETS:
        raise InvalidInputError(f"unknown camera {name!r}: use one of {', '.join(PRESETS)} or custom")
    p = PRESETS[key]
    if width is not None or height is not None:
        p = p.resized(int(width if width is not None else round(height * p.width / p.height)),
                      None if height is None else int(height))
    if hfov_deg is not None:
        p = replace(p, hfov_deg=float(hfov_deg))
    if mast_height_m is not None:
        p = replace(p, mast_height_m=float(mast_height_m))
    return p
