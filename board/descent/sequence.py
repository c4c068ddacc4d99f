"""The descent sequence: one trial of a lander's descent (format ``skyloc-descent-sequence``, version 1).

Folder per trial::

    trial/
      sequence.json        body, terrain reference and hash, both cameras, lights, trajectory, seed, frames
      visible/000000.png   8- or 16-bit grey frames of the visible camera
      thermal/000000.png   16-bit radiometric counts of the thermal camera (value = offset + scale * count)
      imu.csv              t,gx,gy,gz,ax,ay,az
      altimeter.csv        t,range_m,valid
      groundtruth.tum      t x y z qx qy qz qw

Frames
------
World
    The terrain's local metric frame: x east, y north, z up, metres (the DEM's grid, heights in
    metres; no curvature over the few hundred metres of a descent).
Body
    x forward, y left, z up (:mod:`board.conventions`).  Both cameras look down the body's -z.
Camera
    OpenCV (x right, y down, z forward), :class:`board.camera.CameraModel` intrinsics.
    ``R_body_cam`` (3, 3) rotates camera-frame vectors into the body frame and ``t_body_cam`` (3,)
    is the camera centre in the body frame (metres): ``p_body = R_body_cam @ p_cam + t_body_cam``.
Time
    ``t`` in seconds from the start of the sequence.

Files
-----
``imu.csv``
    gyro ``gx, gy, gz``: body angular rate in the body frame, rad/s; accel ``ax, ay, az``: specific
    force in the body frame, m/s2, ``R_wb^T (a_w - g_w)`` with ``g_w = (0, 0, -g)``.
``altimeter.csv``
    slant range (m) along the body's -z axis from the body origin to the terrain; ``valid`` is 1 or 0
    (a dropout, range NaN).
``groundtruth.tum``
    TUM lines ``t x y z qx qy qz qw``: body origin in the world frame (m) and the unit quaternion
    (Hamilton, scalar last) of ``R_world_body``.

The JSON Schema is ``board/schemas/descent_sequence.schema.json``; docs/descent.md describes the
format.  :func:`read_sequence` refuses an unknown format or version, a schema violation or a
missing file with the reason (:class:`board.errors.FormatError`); :func:`write_sequence` writes the
whole folder into a temporary sibling and renames it into place, so a trial folder is either
complete or absent.
"""
from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Iterable

import numpy as np

from board.camera import CameraModel
from board.errors import FormatError, InvalidInputError
from board.atomic import atomic_dir

log = logging.getLogger(__name__)

SEQUENCE_FORMAT = "skyloc-descent-sequence"
SEQUENCE_VERSION = 1
SUPPORTED_SEQUENCE_VERSIONS = (1,)
SEQUENCE_MANIFEST = "sequence.json"
MODES = ("visible", "thermal")
IMU_FILE = "imu.csv"
ALTIMETER_FILE = "altimeter.csv"
GROUNDTRUTH_FILE = "groundtruth.tum"
IMU_HEADER = "t,gx,gy,gz,ax,ay,az"
ALTIMETER_HEADER = "t,range_m,valid"
SCHEMA_PATH = Path(__file__).resolve().parents[1] / "schemas" / "descent_sequence.schema.json"


def png_write_params() -> list[int]:
    """PNG writer settings: zlib level 1, Huffman coding only (faster and smaller on these frames than the default)."""
    import cv2

    return [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]


def frame_name(mode: str, index: int) -> str:
    """Relative path of frame ``index`` of camera ``mode`` ("visible" or "thermal"), e.g. ``visible/000000.png``."""
    if mode not in MODES:
        raise InvalidInputError(f"camera mode {mode!r}: use one of {', '.join(MODES)}")
    return f"{mode}/{int(index):06d}.png"


# -- dataclasses ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Radiometric:
    """Conversion of stored counts to a physical value: ``value = offset + scale * count``.

    unit : "K" (brightness temperature, kelvin) or "W/m2/sr" (band radiance);
    band_um : (lo, hi) spectral band, micrometres.
    """

    unit: str
    scale: float
    offset: float
    band_um: tuple[float, float]

    def __post_init__(self) -> None:
        if self.unit not in ("K", "W/m2/sr"):
            raise InvalidInputError(f"radiometric unit {self.unit!r}: use 'K' or 'W/m2/sr'")
        if not (np.isfinite(self.scale) and self.scale > 0 and np.isfinite(self.offset)):
            raise InvalidInputError(f"radiometric scale {self.scale} must be positive and offset {self.offset} finite")
        lo, hi = self.band_um
        if not (0 < lo < hi):
            raise InvalidInputError(f"band {self.band_um} um: give (lo, hi) micrometres with 0 < lo < hi")

    def to_physical(self, counts) -> np.ndarray:
        """Physical value (``unit``) of stored counts, float64."""
        return self.offset + self.scale * np.asarray(counts, dtype=np.float64)

    def to_counts(self, value, bit_depth: int) -> np.ndarray:
        """Counts (rounded, clipped to ``bit_depth`` bits) of physical values; uint16."""
        c = np.rint((np.asarray(value, dtype=np.float64) - self.offset) / self.scale)
        return np.clip(c, 0, 2 ** int(bit_depth) - 1).astype(np.uint16)

    def to_dict(self) -> dict:
        return {"unit": self.unit, "scale": float(self.scale), "offset": float(self.offset),
                "band_um": [float(self.band_um[0]), float(self.band_um[1])]}

    @classmethod
    def from_dict(cls, d: dict | None) -> "Radiometric | None":
        if d is None:
            return None
        return cls(str(d["unit"]), float(d["scale"]), float(d["offset"]),
                   (float(d["band_um"][0]), float(d["band_um"][1])))


@dataclass(frozen=True)
class DescentCamera:
    """One downward camera of the lander.

    model : intrinsics (pixels); R_body_cam : (3, 3) camera-frame -> body-frame rotation;
    t_body_cam : (3,) camera centre in the body frame, metres; bit_depth : bits per stored pixel
    (8..16); radiometric : counts -> physical value, or None (visible counts are relative).
    """

    model: CameraModel
    R_body_cam: np.ndarray
    t_body_cam: np.ndarray
    bit_depth: int
    radiometric: Radiometric | None = None

    def __post_init__(self) -> None:
        R = np.asarray(self.R_body_cam, dtype=np.float64)
        t = np.asarray(self.t_body_cam, dtype=np.float64)
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise InvalidInputError(f"R_body_cam must be a (3, 3) rotation matrix, got {R.tolist()}")
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise InvalidInputError(f"t_body_cam must be 3 finite metres, got {t.tolist()}")
        if not (1 <= int(self.bit_depth) <= 16):
            raise InvalidInputError(f"bit depth {self.bit_depth}: frames are stored with 1 to 16 bits")
        object.__setattr__(self, "R_body_cam", R)
        object.__setattr__(self, "t_body_cam", t)
        object.__setattr__(self, "bit_depth", int(self.bit_depth))

    def to_dict(self) -> dict:
        return {"model": self.model.to_dict(), "R_body_cam": self.R_body_cam.tolist(),
                "t_body_cam": self.t_body_cam.tolist(), "bit_depth": self.bit_depth,
                "radiometric": None if self.radiometric is None else self.radiometric.to_dict()}

    @classmethod
    def from_dict(cls, d: dict, where: str = "camera") -> "DescentCamera":
        try:
            return cls(CameraModel.from_dict(d["model"], where=where), np.array(d["R_body_cam"], dtype=np.float64),
                       np.array(d["t_body_cam"], dtype=np.float64), int(d["bit_depth"]),
                       Radiometric.from_dict(d.get("radiometric")))
        except (KeyError, TypeError, ValueError) as exc:
            raise FormatError(f"{where}: malformed descent camera ({exc})") from exc


# -- schema ----------------------------------------------------------------------------------------
def load_schema() -> dict:
    """The JSON Schema of ``sequence.json``."""
    return json.loads(SCHEMA_PATH.read_text())


def validate_meta(doc: dict, where: str) -> None:
    """Raise FormatError naming the first schema violation of a ``sequence.json`` document."""
    import jsonschema

    validator = jsonschema.Draft202012Validator(load_schema())
    errors = sorted(validator.iter_errors(doc), key=lambda e: list(e.absolute_path))
    if errors:
        e = errors[0]
        loc = "/".join(str(p) for p in e.absolute_path) or "(top level)"
        raise FormatError(f"{where}: {loc}: {e.message} (see board/schemas/descent_sequence.schema.json)")


# -- reading ---------------------------------------------------------------------------------------
def _read_table(path: Path, header: str, ncols: int) -> np.ndarray:
    if not path.is_file():
        raise FormatError(f"{path} does not exist: a descent sequence holds {path.name} (see docs/descent.md)")
    with open(path) as f:
        first = f.readline().strip()
    if first.replace(" ", "") != header:
        raise FormatError(f"{path}: header {first!r} is not {header!r}")
    try:
        a = np.loadtxt(path, delimiter=",", skiprows=1, dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise FormatError(f"{path}: not a numeric CSV with columns {header} ({exc})") from exc
    if a.size == 0:
        a = a.reshape(0, ncols)
    if a.shape[1] != ncols:
        raise FormatError(f"{path}: {a.shape[1]} columns, expected {ncols} ({header})")
    return a


def _read_tum(path: Path) -> np.ndarray:
    if not path.is_file():
        raise FormatError(f"{path} does not exist: a descent sequence holds {path.name} (see docs/descent.md)")
    try:
        a = np.loadtxt(path, comments="#", dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise FormatError(f"{path}: not TUM lines 't x y z qx qy qz qw' ({exc})") from exc
    if a.shape[1] != 8:
        raise FormatError(f"{path}: {a.shape[1]} columns, TUM lines have 8 (t x y z qx qy qz qw)")
    return a


class DescentSequence:
    """A descent-sequence folder opened by :func:`read_sequence` (tables are read on first use).

    path : the folder; meta : the parsed ``sequence.json``; cameras : {"visible", "thermal"} ->
    DescentCamera (only the cameras whose frames the folder holds); modes : their names.
    """

    def __init__(self, path: Path, meta: dict) -> None:
        self.path = path
        self.meta = meta
        where = str(path / SEQUENCE_MANIFEST)
        self.cameras: dict[str, DescentCamera] = {
            m: DescentCamera.from_dict(meta["cameras"][m], where=f"{where}: cameras/{m}")
            for m in MODES if m in meta["cameras"]}
        self.modes: tuple[str, ...] = tuple(self.cameras)
        self.frame_times = np.array([float(f["t"]) for f in meta["frames"]], dtype=np.float64)
        if np.any(np.diff(self.frame_times) <= 0):
            raise FormatError(f"{where}: frame times must increase strictly")
        for i, f in enumerate(meta["frames"]):
            if int(f["index"]) != i:
                raise FormatError(f"{where}: frame {i} has index {f['index']}; frames are listed in order from 0")
            for m in self.modes:
                if not f.get(m):
                    raise FormatError(f"{where}: frame {i} names no {m} image but the sequence has a {m} camera")
                if not (path / f[m]).is_file():
                    raise FormatError(f"{where}: frame {f[m]} is missing from the folder")

    def __repr__(self) -> str:
        return (f"DescentSequence({str(self.path)!r}, trajectory={self.meta['trajectory']['id']}, "
                f"trial={self.meta['trial']}, frames={self.n_frames}, modes={self.modes})")

    @property
    def n_frames(self) -> int:
        return int(self.frame_times.size)

    @property
    def body_radius_m(self) -> float:
        return float(self.meta["body"]["radius_m"])

    @property
    def gravity_w(self) -> np.ndarray:
        """(3,) gravity in the world frame, m/s2: (0, 0, -g)."""
        return np.array([0.0, 0.0, -float(self.meta["body"]["gravity_mps2"])])

    def frame_path(self, mode: str, i: int) -> Path:
        """Path of frame ``i`` (0-based) of camera ``mode``."""
        if mode not in self.cameras:
            raise InvalidInputError(f"this sequence has no {mode!r} camera (it has {', '.join(self.modes)})")
        if not (0 <= int(i) < self.n_frames):
            raise InvalidInputError(f"frame {i} out of range: the sequence has {self.n_frames} frames")
        return self.path / self.meta["frames"][int(i)][mode]

    def load_frame(self, mode: str, i: int) -> np.ndarray:
        """Frame ``i`` of camera ``mode`` as stored: (H, W) uint8 or uint16 (see ``cameras[mode].radiometric``)."""
        import cv2

        p = self.frame_path(mode, i)
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise FormatError(f"frame {p} could not be decoded as PNG")
        cam = self.cameras[mode].model
        if img.ndim != 2 or img.shape != (cam.height, cam.width):
            raise FormatError(f"frame {p} has shape {img.shape}, the {mode} camera is a {cam.width}x{cam.height} "
                              "grey camera: fix the manifest or the image")
        return img

    @cached_property
    def imu(self) -> np.ndarray:
        """(n, 7) float64: t (s), gyro xyz (rad/s, body), specific force xyz (m/s2, body)."""
        return _read_table(self.path / self.meta["imu"]["file"], IMU_HEADER, 7)

    @cached_property
    def altimeter(self) -> np.ndarray:
        """(n, 3) float64: t (s), slant range along body -z (m; NaN when invalid), valid (1/0)."""
        return _read_table(self.path / self.meta["altimeter"]["file"], ALTIMETER_HEADER, 3)

    @cached_property
    def groundtruth(self) -> np.ndarray:
        """(n, 8) float64 TUM rows: t, body origin x y z (m, world), quaternion qx qy qz qw of R_world_body."""
        return _read_tum(self.path / self.meta["groundtruth"])


def read_sequence(path: str | os.PathLike) -> DescentSequence:
    """Open a descent-sequence folder (or its ``sequence.json``); FormatError with the reason when unreadable."""
    root = Path(path)
    if root.name == SEQUENCE_MANIFEST:
        root = root.parent
    mpath = root / SEQUENCE_MANIFEST
    if not mpath.is_file():
        raise FormatError(f"{mpath} does not exist: a descent-sequence folder holds {SEQUENCE_MANIFEST} "
                          "(see docs/descent.md)")
    try:
        doc = json.loads(mpath.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FormatError(f"{mpath} is not valid JSON ({exc})") from exc
    if not isinstance(doc, dict) or doc.get("format") != SEQUENCE_FORMAT:
        got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise FormatError(f"{mpath}: format {got!r} is not {SEQUENCE_FORMAT!r}; is this a descent-sequence folder?")
    if doc.get("version") not in SUPPORTED_SEQUENCE_VERSIONS:
        raise FormatError(f"{mpath}: {SEQUENCE_FORMAT} version {doc.get('version')!r} is not supported (this "
                          f"skyloc reads version(s) {', '.join(map(str, SUPPORTED_SEQUENCE_VERSIONS))}); "
                          "upgrade skyloc or regenerate the sequence")
    validate_meta(doc, str(mpath))
    for key in ("imu", "altimeter"):
        if not (root / doc[key]["file"]).is_file():
            raise FormatError(f"{mpath}: {doc[key]['file']} is missing from the folder")
    if not (root / doc["groundtruth"]).is_file():
        raise FormatError(f"{mpath}: {doc['groundtruth']} is missing from the folder")
    return DescentSequence(root, doc)


# -- writing ---------------------------------------------------------------------------------------
def _check_table(name: str, a, ncols: int) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != ncols or a.shape[0] == 0:
        raise InvalidInputError(f"{name} must be a non-empty (n, {ncols}) array, got shape {a.shape}")
    if np.any(np.diff(a[:, 0]) <= 0):
        raise InvalidInputError(f"{name}: times (column 0) must increase strictly")
    return a


def _write_frames(root: Path, modes: list[str], frames: list[Iterable[np.ndarray]], n: int, cams: dict) -> None:
    """Write the frames of every mode in lockstep (frame i of each mode, then frame i + 1...)."""
    import cv2

    for m in modes:
        (root / m).mkdir()
    iters = [iter(f) for f in frames]
    count = 0
    while True:
        imgs = []
        for m, it in zip(modes, iters):
            try:
                imgs.append(next(it))
            except StopIteration:
                imgs.append(None)
        if all(img is None for img in imgs):
            break
        i = count
        for m, img in zip(modes, imgs):
            if img is None:
                raise InvalidInputError(f"{i} {m} frames for {n} frame times: give one image per frame")
            if i >= n:
                raise InvalidInputError(f"more {m} frames than the {n} frame times: give one image per frame")
            cam = cams[m]
            w, h = int(cam["model"]["width"]), int(cam["model"]["height"])
            bits = int(cam["bit_depth"])
            img = np.asarray(img)
            if img.shape != (h, w):
                raise InvalidInputError(f"{m} frame {i} has shape {img.shape}; the camera is {w}x{h} grey")
            want = np.uint8 if bits <= 8 else np.uint16
            if img.dtype != want:
                raise InvalidInputError(f"{m} frame {i} is {img.dtype}; a {bits}-bit camera stores {np.dtype(want)}")
            if bits not in (8, 16) and int(img.max(initial=0)) >= 2 ** bits:
                raise InvalidInputError(f"{m} frame {i} holds counts above {2 ** bits - 1} ({bits}-bit camera)")
            if not cv2.imwrite(str(root / frame_name(m, i)), img, png_write_params()):
                raise FormatError(f"could not write {root / frame_name(m, i)}")
        count += 1
    if count != n:
        raise InvalidInputError(f"{count} {modes[0]} frames for {n} frame times: give one image per frame")


def write_sequence(folder: str | os.PathLike, meta: dict, visible_frames: Iterable[np.ndarray] | None,
                   thermal_frames: Iterable[np.ndarray] | None, imu, altimeter, groundtruth, *,
                   frame_times=None, overwrite: bool = False) -> Path:
    """Write a descent-sequence folder atomically (a temporary sibling renamed into place); returns it.

    meta : the ``sequence.json`` content without (or with) the file lists: ``frames``, ``imu.file``,
        ``altimeter.file`` and ``groundtruth`` are filled in here; ``cameras`` names both cameras and
        the frames written are those of the cameras whose frames are given (a camera without frames
        is dropped from ``cameras``).
    visible_frames, thermal_frames : iterables (lists or generators) of (H, W) uint8/uint16 images,
        one per frame time, or None; both are consumed in lockstep (frame i of each, then i + 1),
        so two generators fed by one renderer (``itertools.tee``) hold at most one frame.
    imu : (n, 7) t, gyro (rad/s), accel (m/s2); altimeter : (n, 3) t, range (m), valid;
    groundtruth : (n, 8) TUM rows.  frame_times : (n_frames,) s, or None to take ``meta["frames"]``'s.
    overwrite : replace an existing folder (otherwise InvalidInputError).
    """
    root = Path(folder)
    if root.exists() and not overwrite:
        raise InvalidInputError(f"{root} already exists: remove it or pass overwrite=True")
    if frame_times is None:
        if not meta.get("frames"):
            raise InvalidInputError("no frame times: pass frame_times= or meta['frames'] with a 't' per frame")
        frame_times = [f["t"] for f in meta["frames"]]
    times = np.asarray(frame_times, dtype=np.float64)
    if times.ndim != 1 or times.size == 0 or np.any(np.diff(times) <= 0) or not np.all(np.isfinite(times)):
        raise InvalidInputError("frame times must be a non-empty, strictly increasing 1-D array of seconds")
    imu = _check_table("imu", imu, 7)
    altimeter = _check_table("altimeter", altimeter, 3)
    groundtruth = _check_table("groundtruth", groundtruth, 8)
    qn = np.linalg.norm(groundtruth[:, 4:8], axis=1)
    if not np.allclose(qn, 1.0, atol=1e-6):
        raise InvalidInputError("groundtruth quaternions (columns 4-7) must be unit quaternions")
    given = {"visible": visible_frames, "thermal": thermal_frames}
    modes = [m for m in MODES if given[m] is not None]
    if not modes:
        raise InvalidInputError("no frames: give visible_frames, thermal_frames or both")
    doc = json.loads(json.dumps(meta))     # a deep, JSON-clean copy
    doc["format"] = SEQUENCE_FORMAT
    doc["version"] = SEQUENCE_VERSION
    missing = [m for m in modes if m not in doc.get("cameras", {})]
    if missing:
        raise InvalidInputError(f"meta['cameras'] lacks {', '.join(missing)}: describe every camera whose frames "
                                "are written")
    doc["cameras"] = {m: doc["cameras"][m] for m in modes}
    doc["frames"] = [{"index": i, "t": float(t), **{m: frame_name(m, i) for m in modes}}
                     for i, t in enumerate(times)]
    doc.setdefault("imu", {})["file"] = IMU_FILE
    doc.setdefault("altimeter", {})["file"] = ALTIMETER_FILE
    doc["groundtruth"] = GROUNDTRUTH_FILE
    validate_meta(doc, "sequence to write")
    for m in modes:
        DescentCamera.from_dict(doc["cameras"][m], where=f"cameras/{m}")

    with atomic_dir(root) as tmp:
        _write_frames(tmp, modes, [given[m] for m in modes], times.size, doc["cameras"])
        np.savetxt(tmp / IMU_FILE, imu, delimiter=",", header=IMU_HEADER, comments="", fmt="%.9g")
        alt = altimeter.copy()
        np.savetxt(tmp / ALTIMETER_FILE, alt, delimiter=",", header=ALTIMETER_HEADER, comments="",
                   fmt=("%.9g", "%.6f", "%d"))
        np.savetxt(tmp / GROUNDTRUTH_FILE, groundtruth, delimiter=" ", fmt="%.9f")
        (tmp / SEQUENCE_MANIFEST).write_text(json.dumps(doc, indent=1))
    log.info("wrote descent sequence %s (%d frames, modes %s)", root, times.size, ",".join(modes))
    return root
