"""Acquisition and panorama folders: the on-board input formats (versioned, with JSON Schemas).

Acquisition folder (format ``skyloc-acquisition``, version 1)::

    acq/
      acquisition.json     camera model, mast height, per-frame pan/tilt, optional attitude and truth
      frame_000.png ...    the frames (8/16-bit, grey or BGR)

Panorama folder (format ``skyloc-panorama``, version 1)::

    pano/
      panorama.json        grid geometry (azimuth of column 0, degrees per pixel, elevation of row 0)
      panorama.png         the image (intensity, or binary: terrain white, sky black)
      mask.png (optional)  non-zero where the panorama was seen

The schemas live in ``board/schemas/``; docs/formats.md describes both formats.  Readers
refuse unknown formats and versions with the reason; writers write images first and the
manifest last, each to a temporary file renamed into place, so a folder never holds a
manifest that points at half-written files.
"""
from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Sequence

import numpy as np

from board.camera import CameraModel
from board.errors import FormatError, InvalidInputError
from board.transfer import DEFAULT_TRANSFER, check_transfer

log = logging.getLogger(__name__)

ACQUISITION_FORMAT = "skyloc-acquisition"
PANORAMA_FORMAT = "skyloc-panorama"
ACQUISITION_VERSION = 1
PANORAMA_VERSION = 1
SUPPORTED_ACQUISITION_VERSIONS = (1,)
SUPPORTED_PANORAMA_VERSIONS = (1,)
ACQUISITION_MANIFEST = "acquisition.json"
PANORAMA_MANIFEST = "panorama.json"
SCHEMA_DIR = Path(__file__).resolve().parent / "schemas"


# -- dataclasses ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class FrameInfo:
    """One frame: image file (relative to the folder) and the pan-tilt unit's angles (degrees).

    pan_deg : clockwise seen from above, 0 = body forward; tilt_deg : positive up.
    """

    file: str
    pan_deg: float
    tilt_deg: float
    meta: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = {"file": self.file, "pan_deg": float(self.pan_deg), "tilt_deg": float(self.tilt_deg)}
        if self.meta:
            d["meta"] = self.meta
        return d


@dataclass(frozen=True)
class GroundTruth:
    """True pose of simulated data: position (metres, in ``crs``), heading/pitch/roll (degrees)."""

    x: float
    y: float
    heading_deg: float
    z: float | None = None
    pitch_deg: float = 0.0
    roll_deg: float = 0.0
    crs: str = ""
    dem: str = ""
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = {"x": float(self.x), "y": float(self.y), "z": None if self.z is None else float(self.z),
             "heading_deg": float(self.heading_deg), "pitch_deg": float(self.pitch_deg),
             "roll_deg": float(self.roll_deg)}
        if self.crs:
            d["crs"] = self.crs
        if self.dem:
            d["dem"] = self.dem
        d.update(self.extra)
        return d

    @classmethod
    def from_dict(cls, d: dict | None) -> "GroundTruth | None":
        if d is None:
            return None
        known = {"x", "y", "z", "heading_deg", "pitch_deg", "roll_deg", "crs", "dem"}
        return cls(float(d["x"]), float(d["y"]), float(d["heading_deg"]),
                   None if d.get("z") is None else float(d["z"]), float(d.get("pitch_deg", 0.0)),
                   float(d.get("roll_deg", 0.0)), str(d.get("crs", "")), str(d.get("dem", "")),
                   {k: v for k, v in d.items() if k not in known})


@dataclass
class Acquisition:
    """A set of frames from a calibrated camera on a pan-tilt unit.

    camera : intrinsics and distortion; mast_height_m : optical centre above the ground (metres);
    frames : per-frame file and pan/tilt; attitude : measured body (pitch, roll) in degrees used
    to level the panorama, or None (assume level); truth : ground truth of simulated data;
    root : the folder it was loaded from (None before it is written); transfer : how the frames' values
    relate to the light (:mod:`board.transfer`, ``"srgb"`` unless the manifest says ``"linear"``).
    """

    camera: CameraModel
    mast_height_m: float
    frames: list[FrameInfo]
    attitude: tuple[float, float] | None = None
    truth: GroundTruth | None = None
    meta: dict = field(default_factory=dict)
    root: Path | None = None
    transfer: str = DEFAULT_TRANSFER

    def to_dict(self) -> dict:
        d: dict = {"format": ACQUISITION_FORMAT, "version": ACQUISITION_VERSION, "camera": self.camera.to_dict(),
                   "mast_height_m": float(self.mast_height_m), "frames": [f.to_dict() for f in self.frames],
                   "transfer": check_transfer(self.transfer)}
        if self.attitude is not None:
            d["attitude"] = {"pitch_deg": float(self.attitude[0]), "roll_deg": float(self.attitude[1])}
        if self.truth is not None:
            d["truth"] = self.truth.to_dict()
        if self.meta:
            d["meta"] = self.meta
        return d

    def frame_path(self, i: int) -> Path:
        if self.root is None:
            raise InvalidInputError("this acquisition has no folder yet: write it or load it from a folder first")
        return self.root / self.frames[i].file

    def read_frame(self, i: int) -> np.ndarray:
        """Frame ``i`` as stored (uint8/uint16, (H, W) or (H, W, 3) BGR); checked against the camera size."""
        img = read_image(self.frame_path(i))
        if img.shape[:2] != (self.camera.height, self.camera.width):
            raise FormatError(f"frame {self.frames[i].file} is {img.shape[1]}x{img.shape[0]} px but the camera model "
                              f"says {self.camera.width}x{self.camera.height}: fix the manifest's camera or the image")
        return img


@dataclass(frozen=True)
class PanoramaGeometry:
    """Regular azimuth/elevation grid of an equirectangular panorama (degrees).

    Column ``c`` is centred on azimuth ``azimuth_col0_deg + c * azimuth_step_deg`` (growing to the
    right, clockwise); row ``r`` on elevation ``elevation_row0_deg - r * elevation_step_deg`` (row 0
    on top).  ``azimuth_reference`` is "heading" (0 = the rover's heading, pan 0) or "north"
    (grid north).  ``kind`` is "intensity" or "binary" (terrain non-zero, sky 0).
    """

    width: int
    height: int
    azimuth_col0_deg: float
    azimuth_step_deg: float
    elevation_row0_deg: float
    elevation_step_deg: float
    azimuth_reference: str = "heading"
    kind: str = "intensity"

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise InvalidInputError(f"panorama size {self.width}x{self.height} must be positive")
        if not (self.azimuth_step_deg > 0 and self.elevation_step_deg > 0):
            raise InvalidInputError("panorama steps must be positive degrees per pixel "
                                    "(azimuth grows to the right, elevation falls downwards)")
        if self.width * self.azimuth_step_deg > 360.0 + 1e-6:
            raise InvalidInputError(f"{self.width} columns of {self.azimuth_step_deg} deg exceed 360 deg")
        if self.azimuth_reference not in ("heading", "north"):
            raise InvalidInputError(f"azimuth_reference {self.azimuth_reference!r}: use 'heading' or 'north'")
        if self.kind not in ("intensity", "binary"):
            raise InvalidInputError(f"panorama kind {self.kind!r}: use 'intensity' or 'binary'")

    @classmethod
    def full_circle(cls, width: int, height: int, *, elevation_top_deg: float, elevation_bottom_deg: float,
                    azimuth_start_deg: float = 0.0, azimuth_reference: str = "heading",
                    kind: str = "intensity") -> "PanoramaGeometry":
        """360-degree grid of ``width`` columns whose pixel edges span the given elevations (degrees).

        Column 0's left edge is at ``azimuth_start_deg`` (so its centre is half a step further).
        """
        step_az = 360.0 / width
        step_el = (elevation_top_deg - elevation_bottom_deg) / height
        return cls(width, height, azimuth_start_deg + step_az / 2.0, step_az, elevation_top_deg - step_el / 2.0,
                   step_el, azimuth_reference, kind)

    @property
    def is_full_circle(self) -> bool:
        return math.isclose(self.width * self.azimuth_step_deg, 360.0, abs_tol=1e-6)

    def azimuths_deg(self) -> np.ndarray:
        """(W,) azimuth of every column centre (not wrapped)."""
        return self.azimuth_col0_deg + np.arange(self.width) * self.azimuth_step_deg

    def elevations_deg(self) -> np.ndarray:
        """(H,) elevation of every row centre."""
        return self.elevation_row0_deg - np.arange(self.height) * self.elevation_step_deg

    def col_of_az(self, az_deg) -> np.ndarray:
        """Fractional column of azimuth(s); wrapped into [0, width) for a full circle."""
        c = (np.asarray(az_deg, dtype=np.float64) - self.azimuth_col0_deg) / self.azimuth_step_deg
        if self.is_full_circle:
            c = np.mod(c, self.width)
        else:
            # take the branch of the wrap that lands nearest the panorama
            period = 360.0 / self.azimuth_step_deg
            c = np.mod(c + (period - self.width) / 2.0, period) - (period - self.width) / 2.0
        return c

    def row_of_el(self, el_deg) -> np.ndarray:
        """Fractional row of elevation(s)."""
        return (self.elevation_row0_deg - np.asarray(el_deg, dtype=np.float64)) / self.elevation_step_deg

    def el_of_row(self, row) -> np.ndarray:
        """Elevation (degrees) of fractional row(s)."""
        return self.elevation_row0_deg - np.asarray(row, dtype=np.float64) * self.elevation_step_deg

    def to_dict(self) -> dict:
        return {"width": int(self.width), "height": int(self.height),
                "azimuth_col0_deg": float(self.azimuth_col0_deg), "azimuth_step_deg": float(self.azimuth_step_deg),
                "elevation_row0_deg": float(self.elevation_row0_deg),
                "elevation_step_deg": float(self.elevation_step_deg),
                "azimuth_reference": self.azimuth_reference, "kind": self.kind}


@dataclass
class Panorama:
    """An equirectangular image with its geometry.

    image : (H, W) or (H, W, 3) array; seen : (H, W) bool, False where nothing was observed;
    mast_height_m, truth, meta : carried through from the acquisition or the simulator; transfer : how the
    image's values relate to the light (:mod:`board.transfer`).
    """

    image: np.ndarray
    geometry: PanoramaGeometry
    seen: np.ndarray | None = None
    mast_height_m: float | None = None
    truth: GroundTruth | None = None
    meta: dict = field(default_factory=dict)
    root: Path | None = None
    transfer: str = DEFAULT_TRANSFER


# -- schema and image helpers ----------------------------------------------------------------------
@lru_cache(maxsize=None)
def load_schema(name: str) -> dict:
    """The JSON Schema ``board/schemas/<name>.schema.json`` ("acquisition" or "panorama")."""
    return json.loads((SCHEMA_DIR / f"{name}.schema.json").read_text())


def _validate(doc: dict, schema_name: str, where: str) -> None:
    import jsonschema

    validator = jsonschema.Draft202012Validator(load_schema(schema_name))
    errors = sorted(validator.iter_errors(doc), key=lambda e: list(e.absolute_path))
    if errors:
        e = errors[0]
        loc = "/".join(str(p) for p in e.absolute_path) or "(top level)"
        raise FormatError(f"{where}: {loc}: {e.message} (see board/schemas/{schema_name}.schema.json)")


def _read_manifest(path: Path, fmt: str, supported: Sequence[int], schema_name: str) -> dict:
    if not path.is_file():
        raise FormatError(f"{path} does not exist: a {fmt} folder holds {path.name} (see docs/formats.md)")
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FormatError(f"{path} is not valid JSON ({exc})") from exc
    if not isinstance(doc, dict) or doc.get("format") != fmt:
        got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise FormatError(f"{path}: format {got!r} is not {fmt!r}; is this the right folder?")
    if doc.get("version") not in supported:
        raise FormatError(f"{path}: {fmt} version {doc.get('version')!r} is not supported "
                          f"(this skyloc reads version(s) {', '.join(map(str, supported))}); "
                          "upgrade skyloc or rewrite the folder with this version")
    _validate(doc, schema_name, str(path))
    return doc


def read_image(path: Path) -> np.ndarray:
    """Read an image file unchanged (8/16 bit, grey or BGR); FormatError when it cannot be read."""
    import cv2

    if not Path(path).is_file():
        raise FormatError(f"image {path} does not exist: the manifest names a file missing from the folder")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FormatError(f"image {path} could not be decoded: use PNG or TIFF, 8 or 16 bit")
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    return img


def _write_image_atomic(path: Path, image: np.ndarray) -> None:
    import cv2

    image = np.asarray(image)
    if image.dtype == bool:
        image = image.astype(np.uint8) * 255
    if image.dtype not in (np.uint8, np.uint16):
        raise InvalidInputError(f"images are written as 8 or 16-bit integers, got {image.dtype}: convert first")
    tmp = path.with_name(path.stem + ".part" + path.suffix)
    if not cv2.imwrite(str(tmp), image):
        raise FormatError(f"could not write image {path}: use a .png or .tif name")
    os.replace(tmp, path)


def _write_json_atomic(path: Path, doc: dict) -> None:
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(json.dumps(doc, indent=1))
    os.replace(tmp, path)


# -- acquisitions ---------------------------------------------------------------------------------
def load_acquisition(folder: str | os.PathLike) -> Acquisition:
    """Read and validate ``folder/acquisition.json``; FormatError (with the reason) when it is not readable."""
    root = Path(folder)
    doc = _read_manifest(root / ACQUISITION_MANIFEST, ACQUISITION_FORMAT, SUPPORTED_ACQUISITION_VERSIONS,
                         "acquisition")
    camera = CameraModel.from_dict(doc["camera"], where=str(root / ACQUISITION_MANIFEST))
    frames = [FrameInfo(f["file"], float(f["pan_deg"]), float(f["tilt_deg"]), dict(f.get("meta", {})))
              for f in doc["frames"]]
    for f in frames:
        if not (root / f.file).is_file():
            raise FormatError(f"{root / ACQUISITION_MANIFEST}: frame {f.file} is missing from the folder")
    att = doc.get("attitude")
    return Acquisition(camera, float(doc["mast_height_m"]), frames,
                       None if att is None else (float(att["pitch_deg"]), float(att["roll_deg"])),
                       GroundTruth.from_dict(doc.get("truth")), dict(doc.get("meta", {})), root,
                       doc.get("transfer", DEFAULT_TRANSFER))


def write_acquisition(folder: str | os.PathLike, acq: Acquisition, *,
                      images: Sequence[np.ndarray] | None = None) -> Path:
    """Write ``acq`` into ``folder`` (created if needed): the images (when given) then the manifest, atomically.

    ``images`` are written under each frame's ``file`` name; without them the files must already
    be in the folder.  Returns the manifest path.
    """
    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    if images is not None:
        if len(images) != len(acq.frames):
            raise InvalidInputError(f"{len(images)} images for {len(acq.frames)} frames: give one image per frame")
        for f, img in zip(acq.frames, images):
            if np.asarray(img).shape[:2] != (acq.camera.height, acq.camera.width):
                raise InvalidInputError(f"image for {f.file} has shape {np.asarray(img).shape}, the camera is "
                                        f"{acq.camera.width}x{acq.camera.height}")
            _write_image_atomic(root / f.file, img)
    missing = [f.file for f in acq.frames if not (root / f.file).is_file()]
    if missing:
        raise InvalidInputError(f"frames missing from {root}: {', '.join(missing[:5])}; "
                                "pass images= or write them first")
    doc = acq.to_dict()
    _validate(doc, "acquisition", "acquisition to write")
    path = root / ACQUISITION_MANIFEST
    _write_json_atomic(path, doc)
    acq.root = root
    return path


# -- panoramas ----------------------------------------------------------------------------------
def load_panorama(folder: str | os.PathLike) -> Panorama:
    """Read and validate a panorama folder (``panorama.json`` + image [+ mask])."""
    root = Path(folder)
    doc = _read_manifest(root / PANORAMA_MANIFEST, PANORAMA_FORMAT, SUPPORTED_PANORAMA_VERSIONS, "panorama")
    where = str(root / PANORAMA_MANIFEST)
    try:
        geom = PanoramaGeometry(int(doc["width"]), int(doc["height"]), float(doc["azimuth_col0_deg"]),
                                float(doc["azimuth_step_deg"]), float(doc["elevation_row0_deg"]),
                                float(doc["elevation_step_deg"]), doc.get("azimuth_reference", "heading"),
                                doc.get("kind", "intensity"))
    except InvalidInputError as exc:
        raise FormatError(f"{where}: {exc}") from exc
    image = read_image(root / doc["image"])
    if image.shape[:2] != (geom.height, geom.width):
        raise FormatError(f"{where}: image is {image.shape[1]}x{image.shape[0]} px, the manifest says "
                          f"{geom.width}x{geom.height}")
    seen = None
    if doc.get("mask"):
        m = read_image(root / doc["mask"])
        if m.shape[:2] != image.shape[:2]:
            raise FormatError(f"{where}: mask size {m.shape[:2]} differs from the image {image.shape[:2]}")
        seen = (m if m.ndim == 2 else m[..., 0]) > 0
    return Panorama(image, geom, seen, doc.get("mast_height_m"), GroundTruth.from_dict(doc.get("truth")),
                    dict(doc.get("meta", {})), root, doc.get("transfer", DEFAULT_TRANSFER))


def write_panorama(folder: str | os.PathLike, image: np.ndarray, geometry: PanoramaGeometry, *,
                   seen: np.ndarray | None = None, mast_height_m: float | None = None,
                   truth: GroundTruth | None = None, meta: dict | None = None,
                   image_name: str = "panorama.png", transfer: str = DEFAULT_TRANSFER) -> Path:
    """Write a panorama folder: image (and ``seen`` mask) first, then ``panorama.json``, each atomically.

    image : (H, W) or (H, W, 3) uint8/uint16 (bool is written as 0/255); seen : (H, W) bool or None;
    transfer : how the values relate to the light (:mod:`board.transfer`).  Returns the manifest path.
    """
    root = Path(folder)
    image = np.asarray(image)
    if image.shape[:2] != (geometry.height, geometry.width):
        raise InvalidInputError(f"image shape {image.shape} does not match the geometry "
                                f"{geometry.width}x{geometry.height}")
    root.mkdir(parents=True, exist_ok=True)
    _write_image_atomic(root / image_name, image)
    doc: dict = {"format": PANORAMA_FORMAT, "version": PANORAMA_VERSION, "image": image_name,
                 **geometry.to_dict(), "transfer": check_transfer(transfer)}
    if seen is not None:
        seen = np.asarray(seen, dtype=bool)
        if seen.shape != image.shape[:2]:
            raise InvalidInputError(f"seen mask shape {seen.shape} differs from the image {image.shape[:2]}")
        _write_image_atomic(root / "mask.png", seen)
        doc["mask"] = "mask.png"
    if mast_height_m is not None:
        doc["mast_height_m"] = float(mast_height_m)
    if truth is not None:
        doc["truth"] = truth.to_dict()
    if meta:
        doc["meta"] = meta
    _validate(doc, "panorama", "panorama to write")
    path = root / PANORAMA_MANIFEST
    _write_json_atomic(path, doc)
    return path
