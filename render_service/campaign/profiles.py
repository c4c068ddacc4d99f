"""Campaign profiles: how big each part of the campaign is (sizes in metres, angles in degrees).

``ci`` runs the whole chain on a small procedural site in minutes on 2 cores (the test suite runs
it); ``report`` is the reference report's protocol on a 1 x 1 km area at 5 m; ``full`` adds the
robustness sets of ``scenes/robustness.toml`` and the 7 x 7 km lost-in-space area (for a cluster).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

from blender_addon.core.band import FULL_SPHERE_DEG, checked_band
from blender_addon.core.cameras import PRESETS as CAMERAS
from blender_addon.core.cameras import get_preset
from board.errors import InvalidInputError
from board.skydb import AZIMUTH_SUBSAMPLES, ELEVATION_SCALE_DEG, MAX_AZIMUTH_SUBSAMPLES, checked_elevation_scale


@dataclass(frozen=True)
class Profile:
    """What a campaign runs.

    area_m, step_m : lost-in-space search area side and grid step (metres)
    procedural_size_m, procedural_res_m : size and cell of the procedural DEM made for ``procedural:``
    n_poses : hidden poses for tables 4, 5, 7 and 8 (drawn off the grid, horizon relief checked)
    t4_presets : looks rendered at every pose, level (table 4)
    t5_presets, tilt_deg : looks rendered at every pose with ``tilt_deg`` of pitch, then of roll (table 5)
    n_acquisitions, camera, camera_width, frames, acq_preset : NavCam acquisitions (table 6): a
        pan-tilt plan of ``frames`` frames over 360 degrees with that camera (resized to
        ``camera_width`` pixels), in the ``acq_preset`` look; ``acq_tilt_every`` makes every k-th
        acquisition tilted by ``tilt_deg`` (pitch then roll)
    pano_width, samples : equirectangular panorama width (pixels) and Cycles samples of dressed looks
    pano_band_deg : bottom and top elevations (degrees, mast frame) the panoramas cover; the whole sphere
        by default.  A band such as -45,45 renders half the rows (the ground below it is the costly part
        of a dressed render); azimuths whose true horizon falls outside it count as not seen
    window_m, window_step_m, window_prior_max_m, window_presets : table 7, a window database
        around a prior that is up to ``window_prior_max_m`` off the truth
    heading_offsets_m, heading_window_deg, heading_presets : table 8, the heading-only mode with
        the position prior off by each offset and the heading prior within the window
    n_heading_poses, n_window_poses : how many of the poses tables 7 and 8 use
    robustness : also run the robustness sets of ``robustness_scene`` (``full``), at its sizes unless
        ``robustness_limit`` (acquisitions per set) or ``robustness_width`` (camera pixels) are set (0: the scene's)
    large_area_m : also a lost-in-space search over this area side (``full``; 0 = none)
    min_relief_deg : a pose is used only where the true horizon rises this much above its lowest point
    camera_height_m : mast height for panoramas and databases (acquisitions use the camera's)
    db_elevation_unit_deg : the databases' int16 elevation unit (degrees; board.skydb.ELEVATION_SCALE_DEG,
        0.005; before session 17 every database stored 0.01)
    db_azimuth_subsamples : rays averaged per database sample across its azimuth step (board.skydb.AZIMUTH_SUBSAMPLES,
        4: the horizon averaged over the step, as an extracted sample measures it; 1: point samples, every
        database before session 18)
    site_margin_m : terrain kept between the search area and the DEM's edge (metres); 0 = automatic, the
        larger of 300 m and 15 % of the DEM's smaller side.  Smaller margins let rover-scale DEMs (a few
        hundred metres) be used, with horizons that end at the DEM's edge sooner
    """

    name: str
    area_m: float
    step_m: float
    procedural_size_m: float
    procedural_res_m: float
    n_poses: int
    t4_presets: tuple[str, ...]
    t5_presets: tuple[str, ...]
    tilt_deg: float
    n_acquisitions: int
    camera: str
    camera_width: int
    frames: int
    acq_preset: str
    pano_width: int
    samples: int
    window_m: float
    window_step_m: float
    window_prior_max_m: float
    window_presets: tuple[str, ...]
    n_window_poses: int
    heading_offsets_m: tuple[float, ...]
    heading_window_deg: float
    heading_presets: tuple[str, ...]
    n_heading_poses: int
    acq_tilt_every: int = 0
    robustness: bool = False
    robustness_scene: str = "scenes/robustness.toml"
    robustness_limit: int = 0
    robustness_width: int = 0
    large_area_m: float = 0.0
    min_relief_deg: float = 1.0
    camera_height_m: float = 2.05
    site_margin_m: float = 0.0
    pano_band_deg: tuple[float, ...] = FULL_SPHERE_DEG
    db_elevation_unit_deg: float = ELEVATION_SCALE_DEG
    db_azimuth_subsamples: int = AZIMUTH_SUBSAMPLES
    notes: tuple[str, ...] = field(default_factory=tuple)

    def to_dict(self) -> dict:
        from dataclasses import asdict

        return asdict(self)


#: The report profile's panoramas: 3600 px (0.1 deg per pixel, still coarser than the rover's NavCam at
#: about 0.06 deg) over 45 degrees below the mast's horizontal up to the zenith.  On smooth lunar sites
#: 1800 px left 60-83 % of the clean / realistic fixes within 2.5 m where 3600 px gives 92-100 %
#: (docs/benchmarks.md, sessions 12-14); the ground below -45 degrees (the costly part of a dressed
#: render, no skyline) is not rendered, and the sky above is cheap and never cuts an alpine horizon.
REPORT_BAND_DEG = (-45.0, 90.0)

#: The report profile's NavCam frames: the ExoMars NavCam's own 1024 px (65 deg, 0.063 deg per pixel).  At
#: 512 px the lunar acquisitions of Aristoteles 45 had 60 % of the fixes within 2.5 m, at 1024 px 80 % (the
#: rest `ambiguous`), the extraction error halved (docs/benchmarks.md, session 15); a frame costs about 4.5
#: times as much to render.
NAVCAM_WIDTH = get_preset("exomars").width

PROFILES: dict[str, Profile] = {
    "ci": Profile(
        name="ci", area_m=400.0, step_m=10.0, procedural_size_m=8000.0, procedural_res_m=10.0,
        n_poses=2, t4_presets=("binary", "clean", "realistic", "distorted"), t5_presets=("binary",),
        tilt_deg=10.0, n_acquisitions=1, camera="exomars", camera_width=192, frames=9, acq_preset="clean",
        pano_width=720, samples=2, window_m=40.0, window_step_m=2.0, window_prior_max_m=20.0,
        window_presets=("binary",), n_window_poses=1, heading_offsets_m=(0.0, 10.0, 20.0),
        heading_window_deg=10.0, heading_presets=("binary",), n_heading_poses=1,
        notes=("the chain on a tiny site: checks the harness, not the accuracy",)),
    "report": Profile(
        name="report", area_m=1000.0, step_m=5.0, procedural_size_m=20000.0, procedural_res_m=5.0,
        n_poses=30, t4_presets=("binary", "clean", "realistic", "distorted"), t5_presets=("binary", "clean"),
        tilt_deg=10.0, n_acquisitions=10, camera="exomars", camera_width=NAVCAM_WIDTH, frames=13,
        acq_preset="realistic",
        pano_width=3600, samples=8, pano_band_deg=REPORT_BAND_DEG, window_m=40.0, window_step_m=1.0,
        window_prior_max_m=20.0, window_presets=("binary", "realistic"), n_window_poses=30,
        heading_offsets_m=(0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 14.0, 16.0, 18.0, 20.0), heading_window_deg=10.0,
        heading_presets=("binary", "realistic"), n_heading_poses=30, acq_tilt_every=3,
        notes=("the report's protocol (section 12) at 30 poses per look",)),
}
PROFILES["full"] = replace(PROFILES["report"], name="full", robustness=True, large_area_m=7000.0,
                           notes=("report + the robustness sets + the 7 x 7 km lost-in-space area (for a cluster)",))


def get_profile(name: str, **overrides) -> Profile:
    """The profile ``name`` with optional field overrides (None values ignored)."""
    key = str(name).strip().lower()
    if key not in PROFILES:
        raise InvalidInputError(f"unknown campaign profile {name!r}: use one of {', '.join(PROFILES)}")
    p = PROFILES[key]
    kw = {k: v for k, v in overrides.items() if v is not None}
    unknown = set(kw) - set(p.__dataclass_fields__)
    if unknown:
        raise InvalidInputError(f"unknown profile fields {sorted(unknown)}")
    p = replace(p, **kw)
    if p.n_poses < 1 or p.area_m <= 0 or p.step_m <= 0:
        raise InvalidInputError(f"profile {p.name}: n_poses >= 1, area_m > 0 and step_m > 0 are needed")
    if p.site_margin_m < 0:
        raise InvalidInputError(f"site_margin_m = {p.site_margin_m:g}: use 0 (automatic) or a margin in metres")
    from blender_addon.core.degrade import PRESETS as LOOKS  # noqa: PLC0415

    for what in ("t4_presets", "t5_presets", "window_presets", "heading_presets"):
        bad = [x for x in getattr(p, what) if x not in LOOKS]
        if bad:
            raise InvalidInputError(f"{what}: unknown look(s) {bad}: use {', '.join(LOOKS)}")
    if p.acq_preset not in LOOKS:
        raise InvalidInputError(f"acq_preset {p.acq_preset!r} is not a look: use {', '.join(LOOKS)}")
    if p.camera not in CAMERAS:
        raise InvalidInputError(f"camera {p.camera!r} is not a camera preset: use {', '.join(CAMERAS)}")
    if p.pano_width < 64 or p.pano_width % 2:
        raise InvalidInputError(f"panorama width {p.pano_width} must be an even number of at least 64 pixels")
    band = checked_band(p.pano_band_deg, what="pano_band_deg", example="--set pano_band_deg=-45,45")
    try:
        unit = checked_elevation_scale(p.db_elevation_unit_deg)
    except InvalidInputError as exc:
        raise InvalidInputError(f"db_elevation_unit_deg: {exc} (e.g. --set db_elevation_unit_deg=0.01)") from exc
    if not 1 <= p.db_azimuth_subsamples <= MAX_AZIMUTH_SUBSAMPLES:
        raise InvalidInputError(f"db_azimuth_subsamples = {p.db_azimuth_subsamples}: use 1 (point samples) to "
                                f"{MAX_AZIMUTH_SUBSAMPLES} rays per sample (e.g. --set db_azimuth_subsamples=4)")
    return replace(p, pano_band_deg=band, db_elevation_unit_deg=unit)


def parse_setting(text: str) -> tuple[str, object]:
    """``FIELD=VALUE`` -> (field, value typed like the profile field: number, bool or comma-separated tuple)."""
    from dataclasses import fields  # noqa: PLC0415

    if "=" not in text:
        raise InvalidInputError(f"--set {text!r}: use FIELD=VALUE, e.g. --set t4_presets=binary,clean")
    key, raw = (t.strip() for t in text.split("=", 1))
    types = {f.name: f.type for f in fields(Profile)}
    if key not in types or key == "name":
        names = ", ".join(k for k in types if k != "name")
        raise InvalidInputError(f"--set {key}: not a profile field; fields: {names}")
    t = str(types[key])
    try:
        if t.startswith("tuple[str"):
            return key, tuple(v.strip() for v in raw.split(",") if v.strip())
        if t.startswith("tuple[float"):
            return key, tuple(float(v) for v in raw.split(",") if v.strip())
        if t == "int":
            return key, int(raw)
        if t == "float":
            return key, float(raw)
        if t == "bool":
            if raw.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError(raw)
            return key, raw.lower() in ("true", "1", "yes")
        return key, raw
    except ValueError:
        raise InvalidInputError(f"--set {key}={raw}: expected {t}") from None
