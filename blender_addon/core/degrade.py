"""Image degradations applied in numpy after rendering, and the degradation parameters.

A Blender render is a linear-light image of an ideal pinhole, slightly larger than the
simulated camera.  :func:`degrade_frame` turns it into what the NavCam records:

1. exposure error: linear gain ``2 ** exposure_ev``;
2. sun glare: veiling glare around the sun's direction (also when the sun is just out of view);
3. lens: Brown-Conrady distortion of the calibrated camera (:class:`board.camera.CameraModel`,
   the coefficients written in the manifest) by remapping the pinhole render, with chromatic
   dispersion as a slightly different magnification per colour channel (lateral colour),
   then an optional Gaussian blur;
4. sensor: shot noise (Poisson in electrons) and read noise (Gaussian), clipping at full well;
5. sRGB encoding and quantisation to 8 or 16 bits.

Image values are linear, 1.0 = full well.  Every random draw comes from the
``numpy.random.Generator`` passed in, so a seed reproduces the bytes.

The calibrated model describes the green channel exactly; dispersion, blur and noise are
not in the manifest and cannot be corrected.
"""
from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np

from board.camera import CameraModel
from board.conventions import BODIES
from board.errors import InvalidInputError
from board.transfer import srgb_decode, srgb_encode  # noqa: F401  (re-exported: the simulator's transfer)

log = logging.getLogger(__name__)

#: Renders are made this many stops darker than full well so highlights up to 2**EV survive.
RENDER_HEADROOM_EV: int = 2


# --------------------------------------------------------------------------------------------
# parameters
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SunParams:
    """Sun direction and strength.

    azimuth_deg : degrees clockwise from grid north, or from the rover heading when ``relative``
    elevation_deg : degrees above the horizon (low values: long shadows, low light)
    strength : sun irradiance scale (1 = clear Mars noon, before dust extinction)
    """

    azimuth_deg: float = 135.0
    elevation_deg: float = 35.0
    relative: bool = False
    strength: float = 1.0


@dataclass(frozen=True)
class SkyParams:
    """Dusty Mars sky and haze.

    dust_tau : vertical dust optical depth (0.3 clear to 3 dust storm); it tints and
        brightens the sky, dims the sun by ``exp(-tau / sin(elevation))`` and fades distant
        terrain towards the horizon sky colour with horizontal extinction ``tau / scale_height``
    scale_height_m : dust scale height, metres (about 11 km on Mars)
    clear : a clear, dust-free dark sky (the 'clean' look)
    black : an airless sky: black, no sky light (the ground is lit by the sun and by itself only), no dust,
        no haze; what a camera on the Moon or Europa sees (the opposite polarity to the dressed skies)
    """

    dust_tau: float = 0.5
    scale_height_m: float = 11_100.0
    clear: bool = False
    black: bool = False


@dataclass(frozen=True)
class RockParams:
    """Rocks and pebbles (see :mod:`blender_addon.core.rocks`).

    density_per_m2 : rocks of diameter >= d_min_m per square metre
    d_min_m, d_max_m : diameter range, metres
    exponent : b of the cumulative size-frequency law N(>D) proportional to D**-b
    radius_m : scatter radius around the rover, metres
    near_count : extra large rocks close to the mast (occlusions)
    near_distance_m, near_diameter_m : (min, max) distance from the mast and diameter of those, metres
    """

    density_per_m2: float = 0.0
    d_min_m: float = 0.05
    d_max_m: float = 1.5
    exponent: float = 2.5
    radius_m: float = 40.0
    near_count: int = 0
    near_distance_m: tuple[float, float] = (2.0, 6.0)
    near_diameter_m: tuple[float, float] = (0.5, 1.5)


@dataclass(frozen=True)
class LensParams:
    """Lens: Brown-Conrady coefficients (written in the manifest), dispersion and blur.

    dispersion : relative magnification difference of red (+) and blue (-) against green
        (0.002 = 1 px fringe 500 px from the centre)
    blur_px : Gaussian blur sigma, pixels (0 = none)
    vignetting : relative light loss at the image corner (0 = none)
    """

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    dispersion: float = 0.0
    blur_px: float = 0.0
    vignetting: float = 0.0

    @property
    def distortion(self) -> dict[str, float]:
        return {"k1": self.k1, "k2": self.k2, "p1": self.p1, "p2": self.p2, "k3": self.k3}


@dataclass(frozen=True)
class SensorParams:
    """Exposure and sensor.

    exposure_ev : exposure error in stops (+1 = twice the light; saturates highlights)
    full_well_e : electrons at saturation (1.0 in linear units); 0 disables noise
    read_noise_e : read noise standard deviation, electrons
    glare : veiling glare strength around the sun (0 = none)
    bit_depth : 8 or 16 bits per channel in the written image
    auto_exposure : the camera sets its exposure for the scene, as a NavCam does: sunlight and regolith
        albedo that differ from Mars' are compensated (:func:`auto_exposure_gain`), so an Earth scene
        under 2.3 times Mars' sunlight is not rendered clipped to white; ``exposure_ev`` is an error on top
    """

    exposure_ev: float = 0.0
    full_well_e: float = 0.0
    read_noise_e: float = 0.0
    glare: float = 0.0
    bit_depth: int = 8
    auto_exposure: bool = True


@dataclass(frozen=True)
class Degradation:
    """Everything that makes a frame differ from an ideal render.

    binary : terrain white, sky black, nothing else (the report's noise level 1)
    regolith_albedo : mean regolith albedo; albedo_variation : relative spread of its texture
    body : the body the look is made for ("mars", "earth", "moon", "europa"), or None for a look that fits
        any body (binary, clean); :func:`check_look_body` warns when it dresses another body's terrain
    """

    name: str = "clean"
    body: str | None = None
    binary: bool = False
    regolith_albedo: float = 0.22
    albedo_variation: float = 0.35
    sun: SunParams = field(default_factory=SunParams)
    sky: SkyParams = field(default_factory=SkyParams)
    rocks: RockParams = field(default_factory=RockParams)
    lens: LensParams = field(default_factory=LensParams)
    sensor: SensorParams = field(default_factory=SensorParams)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict, *, base: "Degradation | None" = None, where: str = "degradation") -> "Degradation":
        """Build from a (possibly partial) dict over ``base``; unknown keys raise InvalidInputError."""
        return _merge(base or cls(), d, where)


_SECTIONS = {"sun": SunParams, "sky": SkyParams, "rocks": RockParams, "lens": LensParams, "sensor": SensorParams}


def _merge(obj, d: dict, where: str):
    if not isinstance(d, dict):
        raise InvalidInputError(f"{where}: expected a table of settings, got {d!r}")
    known = {f.name: f for f in fields(obj)}
    changes = {}
    for key, value in d.items():
        if key not in known:
            raise InvalidInputError(f"{where}: unknown setting {key!r}; known: {', '.join(known)}")
        current = getattr(obj, key)
        if key in _SECTIONS and isinstance(obj, Degradation):
            changes[key] = _merge(current, value, f"{where}.{key}")
        elif isinstance(current, bool):
            if not isinstance(value, bool):
                raise InvalidInputError(f"{where}.{key}: expected true or false, got {value!r}")
            changes[key] = value
        elif isinstance(current, tuple):
            if not (isinstance(value, (list, tuple)) and len(value) == 2 and value[0] <= value[1]):
                raise InvalidInputError(f"{where}.{key}: expected [min, max], got {value!r}")
            changes[key] = (float(value[0]), float(value[1]))
        elif isinstance(current, (int, float)) and not isinstance(current, bool):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise InvalidInputError(f"{where}.{key}: expected a number, got {value!r}")
            if isinstance(current, int) and not float(value).is_integer():
                raise InvalidInputError(f"{where}.{key}: expected a whole number, got {value!r}")
            changes[key] = int(value) if isinstance(current, int) else float(value)
        elif key == "body" and isinstance(obj, Degradation):
            if value is not None and str(value).strip().lower() not in BODIES:
                raise InvalidInputError(f"{where}.body: expected one of {', '.join(BODIES)}, got {value!r}")
            changes[key] = None if value is None else str(value).strip().lower()
        elif isinstance(current, str):
            changes[key] = str(value)
        else:  # pragma: no cover - all fields are covered above
            changes[key] = value
    out = replace(obj, **changes)
    _validate(out, where)
    return out


def _validate(obj, where: str) -> None:
    def need(cond: bool, msg: str) -> None:
        if not cond:
            raise InvalidInputError(f"{where}: {msg}")

    if isinstance(obj, SunParams):
        need(-10.0 <= obj.elevation_deg <= 90.0, f"sun elevation {obj.elevation_deg} deg must be in [-10, 90]")
        need(obj.strength >= 0, "sun strength must be >= 0")
    elif isinstance(obj, SkyParams):
        need(0.0 <= obj.dust_tau <= 10.0, f"dust optical depth {obj.dust_tau} must be in [0, 10]")
        need(obj.scale_height_m > 0, "dust scale height must be positive (metres)")
        need(not obj.black or obj.dust_tau == 0.0, f"a black (airless) sky has no dust: set dust_tau = 0, got "
                                                   f"{obj.dust_tau}")
    elif isinstance(obj, RockParams):
        need(obj.density_per_m2 >= 0, "rock density must be >= 0 per square metre")
        need(0 < obj.d_min_m < obj.d_max_m, f"rock diameters need 0 < d_min_m < d_max_m, got {obj.d_min_m}, "
                                             f"{obj.d_max_m}")
        need(obj.exponent > 0, "the size-frequency exponent must be positive")
        need(obj.radius_m > 0, "rock scatter radius must be positive (metres)")
        need(obj.near_count >= 0, "near_count must be >= 0")
        need(obj.near_distance_m[0] > 0, "rocks near the mast need a positive minimum distance")
        need(obj.near_diameter_m[0] > 0, "rocks near the mast need a positive minimum diameter")
    elif isinstance(obj, LensParams):
        need(abs(obj.dispersion) < 0.05, f"dispersion {obj.dispersion} is implausible: keep |dispersion| < 0.05")
        need(obj.blur_px >= 0, "blur_px must be >= 0")
        need(0 <= obj.vignetting < 1, "vignetting must be in [0, 1)")
    elif isinstance(obj, SensorParams):
        need(-8 <= obj.exposure_ev <= 8, f"exposure error {obj.exposure_ev} EV must be within +-8 stops")
        need(obj.full_well_e >= 0 and obj.read_noise_e >= 0, "full_well_e and read_noise_e must be >= 0")
        need(obj.read_noise_e == 0 or obj.full_well_e > 0, "read noise needs a full well (full_well_e > 0)")
        need(obj.glare >= 0, "glare must be >= 0")
        need(obj.bit_depth in (8, 16), f"bit_depth must be 8 or 16, got {obj.bit_depth}")
    elif isinstance(obj, Degradation):
        need(0 < obj.regolith_albedo <= 1, "regolith_albedo must be in (0, 1]")
        need(0 <= obj.albedo_variation <= 1, "albedo_variation must be in [0, 1]")


_SENSOR = SensorParams(full_well_e=12_000.0, read_noise_e=15.0)
#: sunlight at each body relative to Mars (inverse square of the distance to the Sun: 1.52 AU for Mars,
#: 1 AU for the Earth and the Moon, 5.2 AU for Europa)
_SUN_REL_MARS = {"mars": 1.0, "earth": 1.52 ** 2, "moon": 1.52 ** 2, "europa": (1.52 / 5.2) ** 2}

#: The report's noise levels and the clean look (``--preset``); "realistic" is the Mars look, and each
#: body has its own: "realistic-earth" (clear sky, brighter sun), "realistic-moon" (no atmosphere, dark
#: regolith, albedo 0.12), "realistic-europa" (no atmosphere, bright ice, albedo 0.6, sunlight 1/12 of Mars').
#: The airless looks use the clear sky of the dressing (no dust), not a black one (kept so that the lunar
#: figures of sessions 15-31 stay comparable); "realistic-moon-black" is the Moon's look under its real black
#: sky (no sky light: shaded slopes as dark as the sky, sunlit ones the brightest thing in view).
PRESETS: dict[str, Degradation] = {
    "binary": Degradation(name="binary", binary=True, sky=SkyParams(clear=True, dust_tau=0.0)),
    "clean": Degradation(name="clean", sky=SkyParams(clear=True, dust_tau=0.0)),
    "realistic-earth": Degradation(
        name="realistic-earth", body="earth", regolith_albedo=0.25,
        sun=SunParams(strength=_SUN_REL_MARS["earth"]), sky=SkyParams(clear=True, dust_tau=0.0),
        rocks=RockParams(density_per_m2=0.3, d_min_m=0.04, d_max_m=1.0, exponent=2.5, radius_m=35.0),
        sensor=_SENSOR),
    "realistic-moon": Degradation(
        name="realistic-moon", body="moon", regolith_albedo=0.12, albedo_variation=0.25,
        sun=SunParams(strength=_SUN_REL_MARS["moon"]), sky=SkyParams(clear=True, dust_tau=0.0),
        rocks=RockParams(density_per_m2=0.6, d_min_m=0.04, d_max_m=1.2, exponent=2.5, radius_m=35.0),
        sensor=_SENSOR),
    "realistic-moon-black": Degradation(
        name="realistic-moon-black", body="moon", regolith_albedo=0.12, albedo_variation=0.25,
        sun=SunParams(strength=_SUN_REL_MARS["moon"]), sky=SkyParams(clear=True, dust_tau=0.0, black=True),
        rocks=RockParams(density_per_m2=0.6, d_min_m=0.04, d_max_m=1.2, exponent=2.5, radius_m=35.0),
        sensor=_SENSOR),
    "realistic-europa": Degradation(
        name="realistic-europa", body="europa", regolith_albedo=0.6, albedo_variation=0.2,
        sun=SunParams(strength=_SUN_REL_MARS["europa"]), sky=SkyParams(clear=True, dust_tau=0.0),
        rocks=RockParams(density_per_m2=0.2, d_min_m=0.04, d_max_m=1.0, exponent=2.5, radius_m=35.0),
        sensor=_SENSOR),
    "realistic": Degradation(
        name="realistic", body="mars",
        sky=SkyParams(dust_tau=0.6),
        rocks=RockParams(density_per_m2=0.6, d_min_m=0.04, d_max_m=1.2, exponent=2.5, radius_m=35.0),
        sensor=SensorParams(full_well_e=12_000.0, read_noise_e=15.0),
    ),
    "distorted": Degradation(
        name="distorted", body="mars",
        sky=SkyParams(dust_tau=0.6),
        rocks=RockParams(density_per_m2=0.6, d_min_m=0.04, d_max_m=1.2, exponent=2.5, radius_m=35.0),
        lens=LensParams(k1=-0.12, k2=0.02, p1=4e-4, p2=-3e-4, k3=0.0, dispersion=0.0025, blur_px=0.6,
                        vignetting=0.15),
        sensor=SensorParams(full_well_e=12_000.0, read_noise_e=15.0),
    ),
}


#: the scene the camera's exposure is set for: Mars regolith (albedo 0.22) in Mars sunlight (strength 1)
AUTO_EXPOSURE_REFERENCE = 0.22


def auto_exposure_gain(deg: Degradation) -> float:
    """Linear gain of a camera that sets its exposure for the scene (1 for the Mars looks).

    ``AUTO_EXPOSURE_REFERENCE / (regolith_albedo x sun strength)``: the sunlit ground is exposed as
    Mars regolith in Mars sunlight is, whatever the body (Earth: 0.38, 1.2 stops down; Moon: 0.79;
    Europa's bright ice in 1/12 of the sunlight: 4.3).  1 without ``sensor.auto_exposure`` and for
    binary looks.  Applied to the scene's light (sun and sky) before the render, so nothing clips
    that a real exposure would not clip.
    """
    if deg.binary or not deg.sensor.auto_exposure:
        return 1.0
    return AUTO_EXPOSURE_REFERENCE / max(deg.regolith_albedo * deg.sun.strength, 1e-6)


def get_degradation(name: str) -> Degradation:
    """A preset by name (see :data:`PRESETS`)."""
    key = str(name).strip().lower()
    if key not in PRESETS:
        raise InvalidInputError(f"unknown degradation preset {name!r}: use one of {', '.join(PRESETS)}")
    return PRESETS[key]


def look_for_body(body: str) -> str | None:
    """The name of the realistic look made for ``body`` (a body name), or None when there is none."""
    b = str(body).strip().lower()
    for name, d in PRESETS.items():
        if d.body == b and name.startswith("realistic"):
            return name
    return None


def look_on_body(name: str, body: str) -> Degradation:
    """The look ``name`` as it is on ``body`` (a body name): what a campaign on that body renders.

    "realistic" is the Mars look; on another body it is that body's realistic look
    (:func:`look_for_body`: sky, sunlight, regolith).  "distorted" is the realistic look seen through
    the distorted lens: on another body, that body's look with the same lens.  Every other look
    (binary, clean, a body's own look) is returned as it is.  Raises InvalidInputError for an unknown
    name (as :func:`get_degradation`).
    """
    deg = get_degradation(name)
    b = str(body).strip().lower()
    key = str(name).strip().lower()
    if key not in ("realistic", "distorted") or b == deg.body:
        return deg
    own = look_for_body(b)
    if own is None:  # no look for this body: keep the Mars look (check_look_body warns)
        return deg
    base = PRESETS[own]
    if key == "realistic":
        return base
    return replace(base, name=f"distorted-{b}", lens=deg.lens)


def check_look_body(deg: Degradation, body: str) -> str | None:
    """A warning (logged, and returned) when ``deg`` is made for another body than ``body``; None when it fits."""
    if deg.body is None or deg.body == str(body).strip().lower():
        return None
    other = look_for_body(body)
    msg = (f"the look {deg.name!r} is made for {deg.body.capitalize()} (sky, sunlight, regolith) but the terrain "
           f"is on {str(body).capitalize()}: " + (f"use the look {other!r}" if other else
                                                  "use 'clean' or 'binary', or a look of your own"))
    log.warning("%s", msg)
    return msg


# --------------------------------------------------------------------------------------------
# pinhole render geometry
# --------------------------------------------------------------------------------------------
def dispersion_scales(dispersion: float, channels: int = 3) -> np.ndarray:
    """Magnification of each channel relative to green: (1 + d, 1, 1 - d) for RGB; ones for grey."""
    if channels == 3:
        return np.array([1.0 + dispersion, 1.0, 1.0 - dispersion])
    return np.ones(channels)


def render_camera_for(camera: CameraModel, *, dispersion: float = 0.0, margin_px: int = 3) -> CameraModel:
    """The undistorted, centred pinhole to render so that ``camera``'s image can be remapped from it.

    Same focal length (the larger of fx, fy) and square pixels; just large enough to hold every
    ray the distorted camera sees (for every dispersion scale) plus ``margin_px`` for
    interpolation and blur.  Raises InvalidInputError when the distortion is not invertible
    over the image (coefficients beyond the model's one-to-one range).
    """
    f = max(camera.fx, camera.fy)
    # border pixels (and a coarse interior grid) of the distorted image
    n = 64
    us = np.concatenate([np.linspace(-0.5, camera.width - 0.5, n), np.full(n, -0.5), np.full(n, camera.width - 0.5),
                         np.linspace(-0.5, camera.width - 0.5, n)])
    vs = np.concatenate([np.full(n, -0.5), np.linspace(-0.5, camera.height - 0.5, n),
                         np.linspace(-0.5, camera.height - 0.5, n), np.full(n, camera.height - 0.5)])
    gu, gv = np.meshgrid(np.linspace(-0.5, camera.width - 0.5, 9), np.linspace(-0.5, camera.height - 0.5, 9))
    us = np.concatenate([us, gu.ravel()])
    vs = np.concatenate([vs, gv.ravel()])
    x, y = camera.undistort((us - camera.cx) / camera.fx, (vs - camera.cy) / camera.fy)
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise InvalidInputError("the lens distortion is not invertible over the whole image: reduce |k1|, |k2|, |k3| "
                                "(the Brown-Conrady model folds back beyond its one-to-one radius)")
    s = 1.0 + abs(dispersion)
    half_w = float(np.max(np.abs(x))) * f * s + margin_px
    half_h = float(np.max(np.abs(y))) * f * s + margin_px
    w = 2 * math.ceil(half_w + 0.5)
    h = 2 * math.ceil(half_h + 0.5)
    return CameraModel(w, h, f, f, (w - 1) / 2.0, (h - 1) / 2.0)


def remap_maps(camera: CameraModel, pinhole: CameraModel, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole pixel coordinates (u_p, v_p) sampled by every pixel of ``camera``, each (height, width).

    ``scale`` magnifies the ideal normalised coordinates (lateral colour of one channel).
    """
    u, v = camera.pixel_grid()
    x, y = camera.undistort((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy)
    return pinhole.fx * x * scale + pinhole.cx, pinhole.fy * y * scale + pinhole.cy


def bilinear(image: np.ndarray, up: np.ndarray, vp: np.ndarray) -> np.ndarray:
    """Sample a (H, W) or (H, W, C) image at float pixel coordinates (pixel centres at integers).

    Coordinates are clamped to the image (edge pixels repeat); NaN coordinates give 0.
    Returns float32, channel by channel (bounded memory on 20-megapixel frames).
    """
    h, w = image.shape[:2]
    bad = ~(np.isfinite(up) & np.isfinite(vp))
    uc = np.clip(np.where(bad, 0.0, up), 0.0, w - 1.0)
    vc = np.clip(np.where(bad, 0.0, vp), 0.0, h - 1.0)
    u0 = np.minimum(np.floor(uc).astype(np.intp), max(w - 2, 0))
    v0 = np.minimum(np.floor(vc).astype(np.intp), max(h - 2, 0))
    fu = (uc - u0).astype(np.float32)
    fv = (vc - v0).astype(np.float32)
    du = 1 if w > 1 else 0
    dv = w if h > 1 else 0
    i00 = v0 * w + u0
    del uc, vc, u0, v0
    w00 = (1 - fu) * (1 - fv)
    w01 = fu * (1 - fv)
    w10 = (1 - fu) * fv
    w11 = fu * fv
    del fu, fv

    def sample(ch: np.ndarray) -> np.ndarray:
        flat = np.ascontiguousarray(ch, dtype=np.float32).ravel()
        out = (flat[i00] * w00 + flat[i00 + du] * w01 + flat[i00 + dv] * w10 + flat[i00 + dv + du] * w11)
        out[bad] = 0.0
        return out

    if image.ndim == 2:
        return sample(image)
    return np.stack([sample(image[..., c]) for c in range(image.shape[2])], axis=-1)


def distort_image(render: np.ndarray, pinhole: CameraModel, camera: CameraModel, *,
                  dispersion: float = 0.0) -> np.ndarray:
    """Remap an ideal pinhole render (H_p, W_p[, C]) into ``camera``'s distorted image (H, W[, C]).

    Pixel (u, v) of the result shows the ray ``camera.unproject(u, v)``; with dispersion the
    red and blue channels see that ray magnified by ``1 +- dispersion``.
    """
    if render.shape[:2] != (pinhole.height, pinhole.width):
        raise InvalidInputError(f"render is {render.shape[1]}x{render.shape[0]} px but the pinhole is "
                                f"{pinhole.width}x{pinhole.height}: render with render_camera_for(camera)")
    img = render.astype(np.float32, copy=False)
    if img.ndim == 2 or dispersion == 0.0:
        up, vp = remap_maps(camera, pinhole)
        return bilinear(img, up, vp).astype(np.float32)
    out = np.empty((camera.height, camera.width, img.shape[2]), dtype=np.float32)
    for c, s in enumerate(dispersion_scales(dispersion, img.shape[2])):
        up, vp = remap_maps(camera, pinhole, s)
        out[..., c] = bilinear(img[..., c], up, vp)
    return out


# --------------------------------------------------------------------------------------------
# photometric effects
# --------------------------------------------------------------------------------------------
def apply_exposure(image: np.ndarray, exposure_ev: float) -> np.ndarray:
    """Linear gain of ``2 ** exposure_ev`` (stops)."""
    return image * np.float32(2.0 ** exposure_ev)


def add_glare(image: np.ndarray, camera: CameraModel, sun_dir_cam: np.ndarray, strength: float, *,
              core_deg: float = 1.5) -> np.ndarray:
    """Add veiling glare around the sun: ``strength / (1 + (angle / core_deg)**2)`` (linear units).

    ``sun_dir_cam`` is the sun's unit direction in the camera frame (x right, y down, z forward);
    the halo depends only on the angle from the sun, so a sun just outside the frame still
    brightens the near edge.  Works on the distorted image (uses ``camera.unproject``).
    """
    if strength <= 0:
        return image
    d = camera.unproject(*camera.pixel_grid())
    s = np.asarray(sun_dir_cam, dtype=np.float64)
    s = s / np.linalg.norm(s)
    ang = np.degrees(np.arccos(np.clip(d @ s, -1.0, 1.0)))
    halo = (strength / (1.0 + (ang / core_deg) ** 2)).astype(np.float32)
    halo = np.nan_to_num(halo)
    return image + (halo[..., None] if image.ndim == 3 else halo)


def apply_vignetting(image: np.ndarray, camera: CameraModel, amount: float) -> np.ndarray:
    """Multiply by ``1 - amount * (r / r_corner)**2`` (r: pixel distance from the principal point)."""
    if amount <= 0:
        return image
    u, v = camera.pixel_grid()
    r2 = (u - camera.cx) ** 2 + (v - camera.cy) ** 2
    r2c = max((camera.width / 2.0) ** 2 + (camera.height / 2.0) ** 2, 1.0)
    g = (1.0 - amount * r2 / r2c).astype(np.float32)
    return image * (g[..., None] if image.ndim == 3 else g)


def gaussian_blur(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """Separable Gaussian blur (sigma in pixels), edges repeated."""
    if sigma_px <= 0:
        return image
    r = max(1, int(math.ceil(3.0 * sigma_px)))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma_px) ** 2)
    k = (k / k.sum()).astype(np.float32)
    out = image.astype(np.float32)
    for axis in (0, 1):
        pad = [(0, 0)] * out.ndim
        pad[axis] = (r, r)
        p = np.pad(out, pad, mode="edge")
        acc = np.zeros_like(out)
        n = out.shape[axis]
        for i, w in enumerate(k):
            sl = [slice(None)] * out.ndim
            sl[axis] = slice(i, i + n)
            acc += w * p[tuple(sl)]
        out = acc
    return out


def add_sensor_noise(image: np.ndarray, rng: np.random.Generator, *, full_well_e: float,
                     read_noise_e: float) -> np.ndarray:
    """Shot and read noise on a linear image (1.0 = full well), clipped to [0, 1].

    Signal ``s`` (electrons ``s * full_well_e``) becomes ``(Poisson(s * fw) + N(0, read_noise_e)) / fw``:
    mean ``s`` and variance ``s / fw + (read_noise_e / fw)**2`` before clipping.
    ``full_well_e = 0`` returns the image clipped, without noise.
    """
    img = np.clip(image, 0.0, None)
    if full_well_e <= 0:
        return np.clip(img, 0.0, 1.0).astype(np.float32)
    electrons = rng.poisson(np.minimum(img, 4.0).astype(np.float64) * full_well_e)
    if read_noise_e > 0:
        electrons = electrons + rng.normal(0.0, read_noise_e, size=img.shape)
    return np.clip(electrons / full_well_e, 0.0, 1.0).astype(np.float32)


def decode_render(image: np.ndarray) -> np.ndarray:
    """Linear full-well units from a render read in [0, 1] (sRGB-encoded, ``-RENDER_HEADROOM_EV`` exposure)."""
    return (srgb_decode(image) * (2.0 ** RENDER_HEADROOM_EV)).astype(np.float32)


def quantise(encoded: np.ndarray, bit_depth: int = 8) -> np.ndarray:
    """Round [0, 1] values to uint8 or uint16."""
    top = (1 << bit_depth) - 1
    dtype = np.uint8 if bit_depth == 8 else np.uint16
    return np.round(np.clip(encoded, 0.0, 1.0) * top).astype(dtype)


def degrade_frame(render_linear: np.ndarray, pinhole: CameraModel, camera: CameraModel, deg: Degradation,
                  rng: np.random.Generator, *, sun_dir_cam: np.ndarray | None = None) -> np.ndarray:
    """A frame as the NavCam records it, from a linear pinhole render (see the module docstring).

    render_linear : (H_p, W_p, 3) float, linear light, of ``pinhole`` (from :func:`render_camera_for`)
    camera : the calibrated camera (its distortion is applied)
    sun_dir_cam : the sun's unit direction in the camera frame, for glare
    Returns (H, W, 3) uint8 or uint16, sRGB-encoded (binary looks are written linear, 0 or max).
    """
    s = deg.sensor
    img = render_linear.astype(np.float32)
    if deg.binary:
        img = distort_image(img, pinhole, camera)
        return quantise((img > 0.5).astype(np.float32), s.bit_depth)
    img = apply_exposure(img, s.exposure_ev)
    img = distort_image(img, pinhole, camera, dispersion=deg.lens.dispersion)
    if sun_dir_cam is not None:
        img = add_glare(img, camera, sun_dir_cam, s.glare)
    img = apply_vignetting(img, camera, deg.lens.vignetting)
    img = gaussian_blur(img, deg.lens.blur_px)
    img = add_sensor_noise(img, rng, full_well_e=s.full_well_e, read_noise_e=s.read_noise_e)
    return quantise(srgb_encode(img), s.bit_depth)


def degrade_panorama(render_linear: np.ndarray, deg: Degradation, rng: np.random.Generator) -> np.ndarray:
    """An equirectangular render with exposure error, blur and sensor noise (no lens: a panorama
    has no single lens).  Returns uint8/uint16 sRGB-encoded; binary looks stay 0 / max."""
    s = deg.sensor
    img = render_linear.astype(np.float32)
    if deg.binary:
        return quantise((img > 0.5).astype(np.float32), s.bit_depth)
    img = apply_exposure(img, s.exposure_ev)
    img = gaussian_blur(img, deg.lens.blur_px)
    img = add_sensor_noise(img, rng, full_well_e=s.full_well_e, read_noise_e=s.read_noise_e)
    return quantise(srgb_encode(img), s.bit_depth)
