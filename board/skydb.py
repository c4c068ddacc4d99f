"""The skyline database: one Zarr v3 store per search grid.

Layout (format ``skyloc-skydb``, version 1)::

    db.zarr/
      zarr.json                 group; attrs hold the metadata below
      elevation/                int16 (ny, nx, n_az), units of ``elevation_scale_deg`` (0.005 degree;
                                0.01 in stores written before it was a choice), chunks (tile, tile, n_az)
      distance/    (optional)   uint16 (ny, nx, n_az), horizon distance in 10 m units
      ground/      (optional)   float32 (ny, nx), chunks (tile, tile): the ground height under each
                                position, metres (the terrain's finest level, bilinear; the eye is
                                ``camera_height_m`` above it), NaN = unknown
      tile_done/                uint8 (n_tiles_y, n_tiles_x), chunks (1, 1): 1 once a tile is written

Row ``i`` / column ``j`` of the grid is the position
``x = gt[0] + (j + 0.5) * gt[1]``, ``y = gt[3] + (i + 0.5) * gt[5]`` (GDAL pixel centres,
row 0 north).  Skyline sample ``k`` is the elevation at azimuth ``start + k * step``
(degrees clockwise from grid north), see :mod:`board.conventions`: with ``azimuth_subsamples`` K > 1
(new stores: ``AZIMUTH_SUBSAMPLES``) the mean of K rays spread evenly over the step centred there
(the horizon averaged over the step, as an extracted sample measures it); K = 1 (stores written before
the attribute existed) a point sample.

A tile is written whole, then marked done; a writer reopening an existing store resumes and
never rewrites a finished tile.  Readers refuse unknown versions and corrupt stores.
"""
from __future__ import annotations

import datetime as _dt
import json
import logging
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from board.conventions import BODIES
from board.errors import FormatError, InvalidInputError

log = logging.getLogger(__name__)

FORMAT_NAME = "skyloc-skydb"
FORMAT_VERSION = 1
SUPPORTED_VERSIONS = (1,)
#: one int16 unit of a new store's elevations, degrees: a flat lunar floor's horizon, 25-40 km away, moves
#: 0.2-0.3 millidegree per metre, so a 0.01-degree unit (0.0029 deg RMS of rounding) swamped what
#: neighbouring 5 m nodes differ by; 0.005 still spans +-163 deg in int16 and keeps the 2 GB flash budget
ELEVATION_SCALE_DEG = 0.005
#: the scale of stores written before ``elevation_scale_deg`` was a choice (their attrs say it too)
LEGACY_ELEVATION_SCALE_DEG = 0.01
#: the elevation units a reader accepts (int16 must span +-90 deg: 0.00275 deg at the finest)
SUPPORTED_ELEVATION_SCALES_DEG = (0.01, 0.005)
#: rays averaged per sample in a new store (a box of one step centred on the sample's azimuth).  An extracted
#: skyline's sample is a line fitted over the camera columns within half a step, i.e. the horizon averaged
#: over the step; a point sample differs from that by 0.0046 deg RMS on a lunar floor's far rims (76 m
#: cells 25-40 km away), as much as the whole extraction error there.  Four rays are within 0.0006 deg RMS
#: of the box average on those rims (docs/renderer.md, "Point or box samples")
AZIMUTH_SUBSAMPLES = 4
#: the most rays a sample may average (beyond, the exact box mean changes by less than 1e-4 deg on any DEM cell)
MAX_AZIMUTH_SUBSAMPLES = 64


def box_offsets_deg(k: int, step_deg: float) -> np.ndarray:
    """Azimuth offsets (degrees) of the ``k`` rays a box sample averages, relative to the sample's azimuth:
    evenly across the step centred there, ``((i + 0.5) / k - 0.5) * step_deg``; ``[0.0]`` for a point sample."""
    return ((np.arange(int(k)) + 0.5) / int(k) - 0.5) * float(step_deg)
MISSING = np.int16(-32768)          # sentinel: not rendered / not seen
DISTANCE_SCALE_M = 10.0             # one uint16 unit of the distance array, metres
DISTANCE_MISSING = np.uint16(65535)
DEFAULT_TILE = 64
#: default bound (MB) of a reader's in-memory copy of the int16 elevations: a database whose whole
#: elevation array is larger (a 7 x 7 km grid at 5 m is 1.4 GB) is streamed and never cached
DEFAULT_CACHE_MB = 64.0


@dataclass(frozen=True)
class GridSpec:
    """A regular grid of camera positions in the DEM's projected CRS (metres).

    ``geotransform`` follows GDAL; positions are pixel centres, row 0 is the northern row.
    """

    geotransform: tuple[float, float, float, float, float, float]
    nx: int
    ny: int
    crs_wkt: str = ""

    @classmethod
    def from_center(cls, center_xy: tuple[float, float], size_m: float, step_m: float, crs_wkt: str = "") -> "GridSpec":
        """Square grid of ``size_m / step_m + 1`` positions a side centred on ``center_xy``.

        A 1000 m grid at 5 m has 201 x 201 = 40,401 positions, both edges included.
        """
        if not (step_m > 0 and math.isfinite(step_m)):
            raise InvalidInputError(f"grid step must be a positive number of metres, got {step_m}")
        if not (size_m >= 0 and math.isfinite(size_m)):
            raise InvalidInputError(f"grid size must be a non-negative number of metres, got {size_m}")
        n = int(round(size_m / step_m)) + 1
        half = (n - 1) * step_m / 2.0
        cx, cy = float(center_xy[0]), float(center_xy[1])
        gt = (cx - half - step_m / 2.0, step_m, 0.0, cy + half + step_m / 2.0, 0.0, -step_m)
        return cls(gt, n, n, crs_wkt)

    @property
    def n_positions(self) -> int:
        return self.nx * self.ny

    def xy(self, i, j):
        """Projected coordinates (metres) of row ``i``, column ``j`` (scalars or arrays)."""
        gt = self.geotransform
        x = gt[0] + (np.asarray(j) + 0.5) * gt[1] + (np.asarray(i) + 0.5) * gt[2]
        y = gt[3] + (np.asarray(j) + 0.5) * gt[4] + (np.asarray(i) + 0.5) * gt[5]
        return x, y

    def ij(self, x: float, y: float) -> tuple[float, float]:
        """Fractional (row, column) of point (x, y); inverse of :meth:`xy` for north-up grids."""
        gt = self.geotransform
        return (y - gt[3]) / gt[5] - 0.5, (x - gt[0]) / gt[1] - 0.5

    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the position centres, metres."""
        x0, y0 = self.xy(0, 0)
        x1, y1 = self.xy(self.ny - 1, self.nx - 1)
        return float(min(x0, x1)), float(min(y0, y1)), float(max(x0, x1)), float(max(y0, y1))


@dataclass(frozen=True)
class Tile:
    """A block of grid positions: rows ``row0:row0+nrows``, columns ``col0:col0+ncols``."""

    ti: int
    tj: int
    row0: int
    col0: int
    nrows: int
    ncols: int

    @property
    def key(self) -> str:
        return f"{self.ti}_{self.tj}"


def plan_tiles(grid: GridSpec, tile: int) -> list[Tile]:
    """Tiles of ``tile x tile`` positions covering the grid (edge tiles smaller), row-major."""
    out = []
    for ti, r0 in enumerate(range(0, grid.ny, tile)):
        for tj, c0 in enumerate(range(0, grid.nx, tile)):
            out.append(Tile(ti, tj, r0, c0, min(tile, grid.ny - r0), min(tile, grid.nx - c0)))
    return out


@dataclass
class SkyDBMeta:
    """Metadata of a skyline database (the store's group attributes)."""

    grid: GridSpec
    camera_height_m: float
    n_azimuth: int = 360
    azimuth_start_deg: float = 0.0
    body: str = "custom"
    body_radius_m: float = BODIES["mars"].radius_m
    refraction_k: float = 0.0
    renderer: str = "raymarch"
    renderer_version: str = "0"
    dem_sha256: str = ""
    tile_size: int = DEFAULT_TILE
    has_distance: bool = False
    #: the store holds each position's ground height (``ground`` array): the parallax interpolation moves the eye
    #: by the true height differences between nodes instead of estimating them from the skylines
    has_ground: bool = False
    #: one int16 unit of the elevations, degrees (one of SUPPORTED_ELEVATION_SCALES_DEG)
    elevation_scale_deg: float = ELEVATION_SCALE_DEG
    #: rays averaged per sample (1: point samples, the only kind before this attribute existed)
    azimuth_subsamples: int = 1
    created_utc: str = field(default_factory=lambda: _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"))
    extra: dict = field(default_factory=dict)

    @property
    def azimuth_step_deg(self) -> float:
        return 360.0 / self.n_azimuth

    def azimuths_deg(self) -> np.ndarray:
        return self.azimuth_start_deg + np.arange(self.n_azimuth) * self.azimuth_step_deg

    def to_attrs(self) -> dict:
        d = asdict(self)
        g = d.pop("grid")
        return {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "crs_wkt": g["crs_wkt"],
            "geotransform": list(g["geotransform"]),
            "nx": g["nx"],
            "ny": g["ny"],
            "azimuth_step_deg": self.azimuth_step_deg,
            "missing": int(MISSING),
            **d,
        }

    @classmethod
    def from_attrs(cls, attrs: dict, where: str = "store") -> "SkyDBMeta":
        fmt = attrs.get("format")
        if fmt != FORMAT_NAME:
            raise FormatError(f"{where} is not a skyloc skyline database (format={fmt!r}); "
                              "render one with `skyloc db render`")
        version = attrs.get("version")
        if version not in SUPPORTED_VERSIONS:
            raise FormatError(f"{where} has skyline-database version {version!r}; this skyloc reads "
                              f"versions {SUPPORTED_VERSIONS}: upgrade skyloc or re-render the database")
        try:
            grid = GridSpec(tuple(float(v) for v in attrs["geotransform"]), int(attrs["nx"]), int(attrs["ny"]),
                            str(attrs.get("crs_wkt", "")))
            names = {f for f in cls.__dataclass_fields__} - {"grid"}
            kw = {k: attrs[k] for k in names if k in attrs}
            kw.setdefault("elevation_scale_deg", LEGACY_ELEVATION_SCALE_DEG)
            meta = cls(grid=grid, **kw)
            meta.elevation_scale_deg = float(meta.elevation_scale_deg)
            meta.azimuth_subsamples = int(meta.azimuth_subsamples)
            if meta.azimuth_subsamples < 1:
                raise ValueError(f"azimuth_subsamples {meta.azimuth_subsamples} < 1")
        except (KeyError, TypeError, ValueError) as exc:
            raise FormatError(f"{where} has corrupt metadata ({exc}); re-render the database") from exc
        try:
            meta.elevation_scale_deg = checked_elevation_scale(meta.elevation_scale_deg)
        except InvalidInputError as exc:
            raise FormatError(f"{where}: {exc}; this skyloc cannot read it: upgrade skyloc or re-render "
                              "the database") from exc
        return meta


def checked_elevation_scale(scale_deg: float) -> float:
    """``scale_deg`` if it is one of SUPPORTED_ELEVATION_SCALES_DEG, else InvalidInputError naming them."""
    for s in SUPPORTED_ELEVATION_SCALES_DEG:
        if math.isclose(float(scale_deg), s, rel_tol=1e-9):
            return s
    raise InvalidInputError(f"elevation unit {scale_deg!r} deg is not one of "
                            f"{', '.join(str(s) for s in SUPPORTED_ELEVATION_SCALES_DEG)} deg")


def quantize_elevation(el_deg: np.ndarray, scale_deg: float = ELEVATION_SCALE_DEG) -> np.ndarray:
    """Degrees (NaN = missing) -> int16 in ``scale_deg`` units (rounded: at most half a unit off) with the
    MISSING sentinel; values beyond the int16 range saturate."""
    el = np.asarray(el_deg, dtype=np.float64)
    q = np.round(el / scale_deg)
    q = np.clip(q, -32767, 32767)
    out = np.where(np.isfinite(el), q, MISSING).astype(np.int16)
    return out


def dequantize_elevation(q: np.ndarray, dtype=np.float32, scale_deg: float = ELEVATION_SCALE_DEG) -> np.ndarray:
    """int16 ``scale_deg`` units -> degrees (``dtype``), NaN where MISSING."""
    out = q.astype(dtype) * dtype(scale_deg)
    out[q == MISSING] = np.nan
    return out


def _zarr():
    try:
        import zarr  # noqa: PLC0415
    except ImportError as exc:  # pragma: no cover - zarr is a hard dependency of the package
        raise FormatError("reading a skyline database needs the 'zarr' package: pip install zarr") from exc
    return zarr


class SkyDBWriter:
    """Creates or resumes a skyline database and writes whole tiles.

    Use :meth:`create` (new store, or resume a compatible existing one).  Each
    :meth:`write_tile` writes the tile's chunk(s) then marks it done, so an interrupted
    render loses at most the tile in progress and never rewrites a finished one.
    """

    def __init__(self, path: Path, meta: SkyDBMeta, group) -> None:
        self.path = Path(path)
        self.meta = meta
        self._group = group
        self.tiles = plan_tiles(meta.grid, meta.tile_size)

    @staticmethod
    def check_resumable(path: str | os.PathLike, meta: SkyDBMeta, *, warn: bool = False) -> "SkyDB":
        """The existing store at ``path`` if rendering ``meta`` there may resume it; InvalidInputError if not.

        A different database (grid, DEM, height, sampling, renderer...) is refused, and so is a partial
        store started by another renderer version or with(out) ground heights (its tiles would mix); a
        complete store of another renderer version, or one without ground heights, is accepted (with a
        warning if ``warn``).
        """
        path = Path(path)
        existing = SkyDB.open(path)
        mine, theirs = meta.to_attrs(), existing.meta.to_attrs()
        keys = ("geotransform", "nx", "ny", "n_azimuth", "azimuth_start_deg", "camera_height_m",
                "body_radius_m", "refraction_k", "renderer", "dem_sha256", "tile_size", "crs_wkt",
                "has_distance", "elevation_scale_deg", "azimuth_subsamples")
        diff = [k for k in keys if mine.get(k) != theirs.get(k)]
        if diff:
            raise InvalidInputError(
                f"{path} already holds a different skyline database (differs in {', '.join(diff)}); "
                "choose another --out or delete it")
        if bool(theirs.get("has_ground", False)) != bool(mine.get("has_ground", False)):
            if not existing.complete:
                raise InvalidInputError(
                    f"{path} was partly rendered {'with' if theirs.get('has_ground') else 'without'} ground heights "
                    f"and this render {'stores' if mine.get('has_ground') else 'does not store'} them (differs in "
                    "has_ground): delete it (or choose another --out) to render it again from scratch")
            if warn:
                log.warning("%s is complete but holds no ground heights (rendered before skyloc stored them): kept "
                            "as it is, its eye heights between nodes are estimated from the skylines; render it "
                            "again into a new --out for the stored heights", path)
        old_v, new_v = theirs.get("renderer_version"), mine.get("renderer_version")
        if old_v != new_v:
            if not existing.complete:
                raise InvalidInputError(
                    f"{path} was partly rendered by {theirs.get('renderer')} version {old_v}; this is version "
                    f"{new_v}: resuming would mix tiles of two renderer versions. Delete it (or choose another "
                    "--out) to render it again from scratch, or finish it with the version that started it")
            if warn:
                log.warning("%s is complete but was rendered by %s version %s (this is version %s): kept as it "
                            "is; delete it and render again for the current renderer", path, theirs.get("renderer"),
                            old_v, new_v)
        return existing

    @classmethod
    def create(cls, path: str | os.PathLike, meta: SkyDBMeta, *, overwrite: bool = False) -> "SkyDBWriter":
        """Create a new store, or reopen ``path`` to resume if it holds the same render.

        Raises InvalidInputError when ``path`` holds a different database (other grid, DEM,
        height or sampling) unless ``overwrite``.
        """
        zarr = _zarr()
        path = Path(path)
        if meta.n_azimuth <= 0 or meta.tile_size <= 0:
            raise InvalidInputError("n_azimuth and tile_size must be positive")
        meta.elevation_scale_deg = checked_elevation_scale(meta.elevation_scale_deg)
        if path.exists() and not overwrite:
            existing = cls.check_resumable(path, meta, warn=True)
            log.info("resuming %s: %d of %d tiles done", path, existing.n_tiles_done(), len(existing.tiles))
            return cls(path, existing.meta, zarr.open_group(str(path), mode="r+"))
        if path.exists() and overwrite:
            import shutil  # noqa: PLC0415
            shutil.rmtree(path)
        g = meta.grid
        group = zarr.open_group(str(path), mode="w")
        t = meta.tile_size
        group.create_array("elevation", shape=(g.ny, g.nx, meta.n_azimuth), chunks=(t, t, meta.n_azimuth),
                           dtype="int16", fill_value=int(MISSING), dimension_names=("y", "x", "azimuth"))
        if meta.has_distance:
            group.create_array("distance", shape=(g.ny, g.nx, meta.n_azimuth), chunks=(t, t, meta.n_azimuth),
                               dtype="uint16", fill_value=int(DISTANCE_MISSING),
                               dimension_names=("y", "x", "azimuth"))
        if meta.has_ground:
            group.create_array("ground", shape=(g.ny, g.nx), chunks=(t, t), dtype="float32", fill_value=float("nan"),
                               dimension_names=("y", "x"))
        nty, ntx = math.ceil(g.ny / t), math.ceil(g.nx / t)
        group.create_array("tile_done", shape=(nty, ntx), chunks=(1, 1), dtype="uint8", fill_value=0)
        group.attrs.update(meta.to_attrs())
        return cls(path, meta, group)

    def done_mask(self) -> np.ndarray:
        """(n_tiles_y, n_tiles_x) bool: tiles already written."""
        return np.asarray(self._group["tile_done"][...]).astype(bool)

    def pending_tiles(self) -> list[Tile]:
        """Tiles not yet written, in row-major order."""
        done = self.done_mask()
        return [t for t in self.tiles if not done[t.ti, t.tj]]

    def write_tile(self, tile: Tile, elevation_deg: np.ndarray, distance_m: np.ndarray | None = None,
                   ground_m: np.ndarray | None = None) -> None:
        """Write one whole tile: ``elevation_deg`` (nrows, ncols, n_az) degrees, NaN = missing; with
        :attr:`SkyDBMeta.has_distance` the horizon distances (same shape, metres), with
        :attr:`SkyDBMeta.has_ground` the ground heights under the positions (nrows, ncols, metres)."""
        shape = (tile.nrows, tile.ncols, self.meta.n_azimuth)
        if elevation_deg.shape != shape:
            raise InvalidInputError(f"tile {tile.key} expects elevations of shape {shape}, got {elevation_deg.shape}")
        if self._group["tile_done"][tile.ti, tile.tj]:  # this tile's flag only, not the whole mask
            raise InvalidInputError(f"tile {tile.key} of {self.path} is already written; tiles are written once")
        if self.meta.has_ground and (ground_m is None or np.shape(ground_m) != shape[:2]):
            raise InvalidInputError(f"this database stores ground heights: pass ground_m of shape {shape[:2]}, "
                                    f"got {None if ground_m is None else np.shape(ground_m)}")
        if self.meta.has_distance and distance_m is None:
            raise InvalidInputError("this database stores horizon distances: pass distance_m")
        # every check above, before anything is written
        sl = (slice(tile.row0, tile.row0 + tile.nrows), slice(tile.col0, tile.col0 + tile.ncols))
        self._group["elevation"][sl] = quantize_elevation(elevation_deg, self.meta.elevation_scale_deg)
        if self.meta.has_distance:
            d = np.asarray(distance_m, dtype=np.float64) / DISTANCE_SCALE_M
            dq = np.where(np.isfinite(d), np.clip(np.round(d), 0, 65534), DISTANCE_MISSING).astype(np.uint16)
            self._group["distance"][sl] = dq
        if self.meta.has_ground:
            self._group["ground"][sl] = np.asarray(ground_m, dtype=np.float32)
        self._group["tile_done"][tile.ti, tile.tj] = 1

    def finalize(self) -> "SkyDB":
        """Mark the database complete (all tiles done) and return a reader."""
        pending = self.pending_tiles()
        if pending:
            raise InvalidInputError(f"{len(pending)} tiles of {self.path} are not written yet")
        self._group.attrs["complete"] = True
        return SkyDB.open(self.path)


def _paste_chunks(tile: Tile, ch: int, cw: int, out: np.ndarray, chunk_at) -> np.ndarray:
    """Fill ``out`` (tile.nrows, tile.ncols, ...) from the chunks of ``ch`` x ``cw`` positions the tile overlaps;
    ``chunk_at(ci, cj)`` returns chunk (ci, cj) (positions on its first two axes).  Returns ``out``."""
    r1, c1 = tile.row0 + tile.nrows, tile.col0 + tile.ncols
    for ci in range(tile.row0 // ch, (r1 - 1) // ch + 1):
        for cj in range(tile.col0 // cw, (c1 - 1) // cw + 1):
            chunk = chunk_at(ci, cj)
            a0, a1 = max(tile.row0, ci * ch), min(r1, (ci + 1) * ch)
            b0, b1 = max(tile.col0, cj * cw), min(c1, (cj + 1) * cw)
            out[a0 - tile.row0:a1 - tile.row0, b0 - tile.col0:b1 - tile.col0] = \
                chunk[a0 - ci * ch:a1 - ci * ch, b0 - cj * cw:b1 - cj * cw]
    return out


class _ChunkReader:
    """Reads whole chunks of one array of the store straight from their files (bytes + zstd codecs).

    A board localising repeatedly reads every chunk of the same store; going through zarr's
    asynchronous machinery costs about as much as the decompression itself.  Only the layout this
    module writes is read this way (regular chunks, default "/" chunk keys, little-endian bytes,
    optional zstd, no storage transformers); :meth:`for_array` returns None for anything else and
    the caller uses zarr.  A missing chunk file is the fill value (zarr semantics).
    """

    def __init__(self, root: Path, name: str, shape: tuple[int, ...], chunks: tuple[int, ...], dtype: np.dtype,
                 fill_value, zstd: bool) -> None:
        self.root, self.name = root, name
        self.shape, self.chunks, self.dtype = shape, chunks, dtype
        self.fill_value = fill_value
        self.nbytes = int(np.prod(chunks)) * dtype.itemsize
        self._zstd = None
        if zstd:
            from numcodecs import Zstd  # noqa: PLC0415 - the codec zarr itself uses

            self._zstd = Zstd()

    @classmethod
    def for_array(cls, root: Path, name: str) -> "_ChunkReader | None":
        """A reader for array ``name`` of the store at ``root``, or None if its layout is not the plain one."""
        try:
            doc = json.loads((root / name / "zarr.json").read_text())
            grid, key = doc["chunk_grid"], doc["chunk_key_encoding"]
            codecs = [c["name"] for c in doc["codecs"]]
            endian = doc["codecs"][0].get("configuration", {}).get("endian", "little")
            dtype = np.dtype(doc["data_type"])
            plain = (doc.get("zarr_format") == 3 and doc.get("node_type") == "array"
                     and not doc.get("storage_transformers") and grid["name"] == "regular"
                     and key["name"] == "default" and key.get("configuration", {}).get("separator", "/") == "/"
                     and codecs in (["bytes"], ["bytes", "zstd"]) and (endian == "little" or dtype.itemsize == 1)
                     and dtype.kind in "iu" and isinstance(doc["fill_value"], int))
            if not plain:
                return None
            return cls(root, name, tuple(doc["shape"]), tuple(grid["configuration"]["chunk_shape"]),
                       dtype.newbyteorder("<"), doc["fill_value"], zstd=codecs[-1] == "zstd")
        except (OSError, ValueError, KeyError, TypeError, IndexError, AttributeError, ImportError):
            return None

    def chunk(self, idx: tuple[int, ...]) -> np.ndarray:
        """The whole chunk at chunk-grid index ``idx`` (chunk shape, also at the array's edges)."""
        f = self.root / self.name / "c" / "/".join(str(i) for i in idx)
        try:
            buf = f.read_bytes()
        except FileNotFoundError:
            return np.full(self.chunks, self.fill_value, dtype=self.dtype)
        except OSError as exc:
            raise FormatError(f"{self.root}: cannot read chunk {f.relative_to(self.root)} ({exc}); "
                              "the store is truncated or corrupt: re-render it") from exc
        if self._zstd is not None:
            try:
                buf = self._zstd.decode(buf)
            except Exception as exc:  # numcodecs raises RuntimeError on a damaged frame
                raise FormatError(f"{self.root}: chunk {f.relative_to(self.root)} does not decompress "
                                  f"({type(exc).__name__}: {exc}); the store is truncated or corrupt: "
                                  "re-render it") from exc
        if len(buf) != self.nbytes:
            raise FormatError(f"{self.root}: chunk {f.relative_to(self.root)} holds {len(buf)} bytes, "
                              f"{self.nbytes} expected; the store is truncated or corrupt: re-render it")
        return np.frombuffer(buf, dtype=self.dtype).reshape(self.chunks)


class SkyDB:
    """Read-only access to a skyline database, streamed tile by tile (bounded memory).

    Chunks are read straight from their files (zarr for any layout this module does not write).
    A complete database whose whole elevation array (plus the distance array, if stored) fits in
    ``cache_mb`` is kept in memory as int16/uint16 chunks as they are read, so repeated queries on
    one site skip the disk and the decompression; a larger one is streamed on every query and never
    cached (a 7 x 7 km grid at 5 m holds 1.4 GB of elevations).
    """

    def __init__(self, path: Path, meta: SkyDBMeta, group, complete: bool, *,
                 cache_mb: float = DEFAULT_CACHE_MB) -> None:
        self.path = path
        self.meta = meta
        self._group = group
        self.complete = complete
        self.tiles = plan_tiles(meta.grid, meta.tile_size)
        self._readers = {name: _ChunkReader.for_array(Path(path), name) for name in ("elevation", "distance")}
        g = meta.grid
        array_mb = g.ny * g.nx * meta.n_azimuth * 2 / 1e6  # int16 elevations (and as much for uint16 distances)
        total_mb = array_mb * (2 if meta.has_distance else 1)
        #: chunks kept in memory ((array name, chunk row, chunk col) -> int16/uint16 array), or None
        self._cache: dict | None = {} if complete and 0 < total_mb <= cache_mb else None
        #: ground-height chunks read so far ((chunk row, chunk col) -> float32 array, 16 KB each at 64 x 64)
        self._ground: dict[tuple[int, int], np.ndarray] = {}

    @classmethod
    def open(cls, path: str | os.PathLike, *, cache_mb: float = DEFAULT_CACHE_MB) -> "SkyDB":
        """Open and validate a store; FormatError with the reason if it cannot be read.

        cache_mb : keep the elevations (and distances) in memory when the whole arrays fit in this many MB;
            0 never caches
        """
        zarr = _zarr()
        path = Path(path)
        if not path.exists():
            raise FormatError(f"no skyline database at {path}: render one with `skyloc db render`")
        meta_file = path / "zarr.json"
        if not meta_file.is_file():
            raise FormatError(f"{path} is not a Zarr v3 store (no zarr.json): not a skyline database")
        try:
            json.loads(meta_file.read_text())
            group = zarr.open_group(str(path), mode="r")
            attrs = dict(group.attrs)
        except Exception as exc:  # zarr raises a variety of errors on damaged stores
            raise FormatError(f"{path} is corrupt ({type(exc).__name__}: {exc}); re-render it") from exc
        meta = SkyDBMeta.from_attrs(attrs, where=str(path))
        try:
            arr = group["elevation"]
            done = group["tile_done"]
        except KeyError as exc:
            raise FormatError(f"{path} is corrupt: missing array {exc}; re-render it") from exc
        except Exception as exc:  # a damaged array zarr.json surfaces as JSON/metadata errors
            raise FormatError(f"{path} is corrupt ({type(exc).__name__}: {exc}); re-render it") from exc
        g = meta.grid
        if tuple(arr.shape) != (g.ny, g.nx, meta.n_azimuth) or str(arr.dtype) != "int16":
            raise FormatError(f"{path} is corrupt: elevation array has shape {arr.shape} / {arr.dtype}, "
                              f"metadata says {(g.ny, g.nx, meta.n_azimuth)} int16")
        if tuple(done.shape) != (math.ceil(g.ny / meta.tile_size), math.ceil(g.nx / meta.tile_size)):
            raise FormatError(f"{path} is corrupt: tile_done has shape {done.shape}")
        if meta.has_ground:
            try:
                ground = group["ground"]
            except Exception as exc:
                raise FormatError(f"{path} is corrupt: its metadata says it holds ground heights but the ground "
                                  f"array cannot be opened ({type(exc).__name__}: {exc}); re-render it") from exc
            if tuple(ground.shape) != (g.ny, g.nx):
                raise FormatError(f"{path} is corrupt: ground array has shape {ground.shape}, metadata says "
                                  f"{(g.ny, g.nx)}")
        return cls(path, meta, group, bool(attrs.get("complete", False)), cache_mb=cache_mb)

    @property
    def grid(self) -> GridSpec:
        return self.meta.grid

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.grid.ny, self.grid.nx, self.meta.n_azimuth)

    def done_mask(self) -> np.ndarray:
        return np.asarray(self._group["tile_done"][...]).astype(bool)

    def n_tiles_done(self) -> int:
        return int(self.done_mask().sum())

    def _read(self, name: str, tile: Tile) -> np.ndarray:
        r1, c1 = tile.row0 + tile.nrows, tile.col0 + tile.ncols
        reader = self._readers.get(name)
        if reader is None or len(reader.chunks) != 3 or reader.chunks[2] != self.meta.n_azimuth:
            sl = (slice(tile.row0, r1), slice(tile.col0, c1))
            try:
                return np.asarray(self._group[name][sl])
            except Exception as exc:
                raise FormatError(f"{self.path}: cannot read tile {tile.key} of {name} "
                                  f"({type(exc).__name__}: {exc}); the store is truncated or corrupt") from exc
        cache = self._cache
        ch, cw = reader.chunks[0], reader.chunks[1]
        out = np.empty((tile.nrows, tile.ncols, reader.chunks[2]), dtype=reader.dtype)
        if out.size == 0:
            return out

        def chunk_at(ci: int, cj: int) -> np.ndarray:
            chunk = None if cache is None else cache.get((name, ci, cj))
            if chunk is None:
                try:
                    chunk = reader.chunk((ci, cj, 0))
                except FormatError as exc:
                    raise FormatError(f"cannot read tile {tile.key} of {name}: {exc}") from exc
                if cache is not None:  # edge chunks trimmed to the array: the cache holds the array's size
                    chunk = np.ascontiguousarray(chunk[:reader.shape[0] - ci * ch, :reader.shape[1] - cj * cw])
                    cache[(name, ci, cj)] = chunk
            return chunk

        return _paste_chunks(tile, ch, cw, out, chunk_at)

    @property
    def cached_mb(self) -> float:
        """MB of elevations (and distances) held in memory by this reader (0 when not caching)."""
        return 0.0 if not self._cache else sum(c.nbytes for c in self._cache.values()) / 1e6

    def read_tile_raw(self, tile: Tile) -> np.ndarray:
        """int16 elevations (``meta.elevation_scale_deg`` units, MISSING sentinel) of one tile."""
        return self._read("elevation", tile)

    def read_tile(self, tile: Tile) -> np.ndarray:
        """float32 elevations in degrees (NaN = missing), shape (nrows, ncols, n_az)."""
        return dequantize_elevation(self.read_tile_raw(tile), scale_deg=self.meta.elevation_scale_deg)

    def read_distance(self, tile: Tile) -> np.ndarray | None:
        """Horizon distances (metres, float32, NaN = missing) of one tile, or None if not stored."""
        if not self.meta.has_distance:
            return None
        q = self._read("distance", tile)
        d = q.astype(np.float32) * np.float32(DISTANCE_SCALE_M)
        d[q == DISTANCE_MISSING] = np.nan
        return d

    def read_ground(self, tile: Tile) -> np.ndarray | None:
        """Ground heights under the positions of ``tile`` (nrows, ncols; metres, float32, NaN = unknown), or None
        if the store does not hold them (stores written before session 26).  Chunks are kept once read (a
        query reads the few around its candidates; the whole array of a 7 x 7 km grid at 5 m is 8 MB)."""
        if not self.meta.has_ground:
            return None
        t = self.meta.tile_size
        out = np.full((tile.nrows, tile.ncols), np.nan, dtype=np.float32)
        if out.size == 0:
            return out

        def chunk_at(ci: int, cj: int) -> np.ndarray:
            chunk = self._ground.get((ci, cj))
            if chunk is None:
                try:
                    chunk = np.asarray(self._group["ground"][ci * t:(ci + 1) * t, cj * t:(cj + 1) * t],
                                       dtype=np.float32)
                except Exception as exc:  # zarr raises a variety of errors on damaged stores
                    raise FormatError(f"{self.path}: cannot read the ground heights of tile {tile.key} "
                                      f"({type(exc).__name__}: {exc}); the store is truncated or corrupt") from exc
                self._ground[(ci, cj)] = chunk
            return chunk

        return _paste_chunks(tile, t, t, out, chunk_at)

    def iter_tiles(self) -> Iterator[tuple[Tile, np.ndarray]]:
        """Yield (tile, float32 elevations in degrees) one tile at a time."""
        for t in self.tiles:
            yield t, self.read_tile(t)

    def skyline(self, i: int, j: int) -> np.ndarray:
        """Elevations (degrees, float32, NaN = missing) at grid row ``i``, column ``j``."""
        g = self.grid
        if not (0 <= i < g.ny and 0 <= j < g.nx):
            raise InvalidInputError(f"grid index ({i}, {j}) is outside the {g.ny} x {g.nx} grid")
        return dequantize_elevation(self._read("elevation", Tile(-1, -1, i, j, 1, 1))[0, 0],
                                    scale_deg=self.meta.elevation_scale_deg)

    def read_all(self) -> np.ndarray:
        """All elevations (degrees, float32). Only for small databases: use iter_tiles otherwise."""
        g = self.grid
        return dequantize_elevation(self._read("elevation", Tile(-1, -1, 0, 0, g.ny, g.nx)),
                                    scale_deg=self.meta.elevation_scale_deg)

    def size_bytes(self) -> int:
        """Bytes on disk of the store."""
        return sum(f.stat().st_size for f in self.path.rglob("*") if f.is_file())

    def summary(self) -> dict:
        """A JSON-able summary (for `skyloc db info`)."""
        m, g = self.meta, self.grid
        return {
            "path": str(self.path),
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "grid": {"nx": g.nx, "ny": g.ny, "step_m": abs(g.geotransform[1]), "geotransform": list(g.geotransform),
                     "bounds": list(g.bounds())},
            "positions": g.n_positions,
            "crs_wkt": g.crs_wkt,
            "camera_height_m": m.camera_height_m,
            "n_azimuth": m.n_azimuth,
            "azimuth_start_deg": m.azimuth_start_deg,
            "azimuth_step_deg": m.azimuth_step_deg,
            "body": m.body,
            "body_radius_m": m.body_radius_m,
            "refraction_k": m.refraction_k,
            "renderer": m.renderer,
            "renderer_version": m.renderer_version,
            "dem_sha256": m.dem_sha256,
            "tile_size": m.tile_size,
            "elevation_scale_deg": m.elevation_scale_deg,
            "azimuth_subsamples": m.azimuth_subsamples,
            "has_distance": m.has_distance,
            "has_ground": m.has_ground,
            "tiles_done": self.n_tiles_done(),
            "tiles_total": len(self.tiles),
            "complete": self.complete,
            "created_utc": m.created_utc,
            "size_bytes": self.size_bytes(),
        }
