"""Scene and test-set definitions: ``scenes/*.toml`` -> validated dataclasses.

A scene file names sites (a DEM and a centre), cameras, pan-tilt plans, degradations and
the sets of acquisitions to render.  See docs/simulator.md for the full reference; in short::

    [dataset]
    name = "robustness"
    seed = 2024                 # same seed, same images
    samples = 16                # Cycles samples per pixel

    [sites.crater]
    dem = "procedural:mars:7"   # or a raster path (relative to this file)
    center = [0.0, 0.0]         # metres, the DEM's metric CRS
    pose_half_m = 300           # poses are drawn in center +- pose_half_m
    z_scale = 1.0               # < 1 flattens the terrain (a flat-horizon site)

    [cameras.navcam]
    preset = "exomars"          # exomars | mars2020 | magellium | custom (+ width, height, hfov_deg, mast_height_m)

    [plans.pan360]
    frames = 13                 # or: overlap = 0.5
    arc_deg = 360
    tilt_deg = 0

    [degradations.dusty]
    base = "realistic"          # a preset (binary, clean, realistic, distorted) or another degradation here
    sky = { dust_tau = 2.0 }

    [[sets]]
    name = "CLUT"
    site = "crater"; camera = "navcam"; plan = "pan360"
    degradations = ["dusty"]    # cycled over the acquisitions
    count = 10
    heading_deg = [0, 360]      # a number or a [min, max] range drawn uniformly
    pitch_deg = 0
    roll_deg = 0
    poses_from = "REF"          # optional: reuse another set's poses

Every error names the file, the table and the fix.
"""
from __future__ import annotations

import logging
import math
import tomllib
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from blender_addon.core.acquire import AcquisitionJob, Pose
from blender_addon.core.cameras import CameraPreset, get_preset
from blender_addon.core.degrade import PRESETS as DEGRADATION_PRESETS, Degradation
from blender_addon.core.plans import PanTiltPlan, plan_frames, plan_overlap
from board.errors import InvalidInputError

log = logging.getLogger(__name__)

#: Range or fixed value: (lo, hi) with lo == hi for a fixed value.
Range = tuple[float, float]


@dataclass(frozen=True)
class SiteSpec:
    """A site: DEM spec (path resolved against the scene file, or procedural:...) and a centre (metres)."""

    name: str
    dem: str
    center: tuple[float, float]
    pose_half_m: float = 200.0
    z_scale: float = 1.0
    max_radius_m: float | None = None
    body: str | None = None


@dataclass(frozen=True)
class PlanSpec:
    """A pan-tilt plan: ``frames`` or ``overlap`` over ``arc_deg`` at ``tilt_deg``."""

    name: str
    frames: int | None = None
    overlap: float | None = None
    arc_deg: float = 360.0
    tilt_deg: float = 0.0
    center_pan_deg: float = 0.0
    allow_gaps: bool = False

    def plan_for(self, camera: CameraPreset) -> PanTiltPlan:
        """The plan for ``camera``'s horizontal field of view."""
        if self.frames is not None:
            return plan_frames(self.frames, self.arc_deg, camera.hfov_deg, tilt_deg=self.tilt_deg,
                               center_pan_deg=self.center_pan_deg, allow_gaps=self.allow_gaps)
        return plan_overlap(float(self.overlap), self.arc_deg, camera.hfov_deg, tilt_deg=self.tilt_deg,
                            center_pan_deg=self.center_pan_deg)


@dataclass(frozen=True)
class SetSpec:
    """One test set: ``count`` acquisitions at random poses around a site."""

    name: str
    site: str
    camera: str
    plan: str
    degradations: tuple[str, ...]
    count: int
    description: str = ""
    heading_deg: Range = (0.0, 360.0)
    pitch_deg: Range = (0.0, 0.0)
    roll_deg: Range = (0.0, 0.0)
    imu_sigma_deg: float = 0.0
    poses_from: str | None = None
    seed: int | None = None


@dataclass(frozen=True)
class SceneSpec:
    """A whole scene file."""

    name: str
    seed: int
    samples: int
    denoise: bool
    sites: dict[str, SiteSpec]
    cameras: dict[str, CameraPreset]
    plans: dict[str, PlanSpec]
    degradations: dict[str, Degradation]
    sets: tuple[SetSpec, ...]
    source: str = ""
    description: str = ""
    text: str = field(default="", repr=False)

    def set_by_name(self, name: str) -> SetSpec:
        for s in self.sets:
            if s.name == name:
                return s
        raise InvalidInputError(f"{self.source}: no set named {name!r}; sets: {', '.join(s.name for s in self.sets)}")


# ------------------------------------------------------------------------------------------------
# parsing helpers
# ------------------------------------------------------------------------------------------------
class _Table:
    """A TOML table with a location for error messages; tracks which keys were read."""

    def __init__(self, data, where: str) -> None:
        if not isinstance(data, dict):
            raise InvalidInputError(f"{where}: expected a table, got {type(data).__name__}")
        self.data = data
        self.where = where
        self.used: set[str] = set()

    def get(self, key: str, default=None):
        self.used.add(key)
        return self.data.get(key, default)

    def require(self, key: str):
        self.used.add(key)
        if key not in self.data:
            raise InvalidInputError(f"{self.where}: missing {key!r}")
        return self.data[key]

    def number(self, key: str, default=..., *, lo: float | None = None, hi: float | None = None,
               integer: bool = False):
        """The number at ``key`` (``default`` when absent; required when no default is given)."""
        v = self.require(key) if default is ... else self.get(key, default)
        if v is None:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise InvalidInputError(f"{self.where}.{key}: expected a number, got {v!r}")
        if integer and not float(v).is_integer():
            raise InvalidInputError(f"{self.where}.{key}: expected an integer, got {v!r}")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise InvalidInputError(f"{self.where}.{key} = {v} is out of range [{lo}, {hi}]")
        return int(v) if integer else float(v)

    def range(self, key: str, default: Range, *, lo: float, hi: float) -> Range:
        v = self.get(key)
        if v is None:
            return default
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            r = (float(v), float(v))
        elif isinstance(v, list) and len(v) == 2 and all(isinstance(x, (int, float)) for x in v):
            r = (float(v[0]), float(v[1]))
        else:
            raise InvalidInputError(f"{self.where}.{key}: expected a number or [min, max], got {v!r}")
        if not (lo <= r[0] <= r[1] <= hi):
            raise InvalidInputError(f"{self.where}.{key} = {v}: need {lo} <= min <= max <= {hi}")
        return r

    def string(self, key: str, default: str | None = None) -> str | None:
        v = self.get(key, default)
        if v is not None and not isinstance(v, str):
            raise InvalidInputError(f"{self.where}.{key}: expected a string, got {v!r}")
        return v

    def done(self) -> None:
        extra = sorted(set(self.data) - self.used)
        if extra:
            raise InvalidInputError(f"{self.where}: unknown key(s) {', '.join(map(repr, extra))}; check the spelling "
                                    "against docs/simulator.md")


def _site(name: str, t: _Table, base_dir: Path) -> SiteSpec:
    dem = t.string("dem")
    if not dem:
        raise InvalidInputError(f"{t.where}: missing 'dem' (a raster path or procedural:PRESET:SEED)")
    if not dem.startswith("procedural:"):
        p = Path(dem).expanduser()
        dem = str(p if p.is_absolute() else (base_dir / p).resolve())
    c = t.get("center", [0.0, 0.0])
    if not (isinstance(c, list) and len(c) == 2 and all(isinstance(v, (int, float)) for v in c)):
        raise InvalidInputError(f"{t.where}.center: expected [x, y] in metres, got {c!r}")
    body = t.get("body")
    site = SiteSpec(name, dem, (float(c[0]), float(c[1])), t.number("pose_half_m", 200.0, lo=0.0, hi=1e5),
                    t.number("z_scale", 1.0, lo=0.01, hi=10.0), t.number("max_radius_m", None, lo=10.0),
                    None if body is None else str(body))
    t.done()
    return site


def _camera(name: str, t: _Table) -> CameraPreset:
    preset = t.string("preset", "custom")
    kw = {k: t.number(k, None) for k in ("width", "height", "hfov_deg", "mast_height_m")}
    t.done()
    try:
        return get_preset(preset, width=None if kw["width"] is None else int(kw["width"]),
                          height=None if kw["height"] is None else int(kw["height"]), hfov_deg=kw["hfov_deg"],
                          mast_height_m=kw["mast_height_m"])
    except InvalidInputError as exc:
        raise InvalidInputError(f"{t.where}: {exc}") from None


def _plan(name: str, t: _Table) -> PlanSpec:
    frames = t.number("frames", None, lo=1, hi=1000, integer=True)
    overlap = t.number("overlap", None, lo=0.0, hi=0.95)
    if (frames is None) == (overlap is None):
        raise InvalidInputError(f"{t.where}: give exactly one of 'frames' (a count) or 'overlap' (a fraction)")
    allow = t.get("allow_gaps", False)
    if not isinstance(allow, bool):
        raise InvalidInputError(f"{t.where}.allow_gaps: expected true or false")
    spec = PlanSpec(name, frames, overlap, t.number("arc_deg", 360.0, lo=1.0, hi=360.0),
                    t.number("tilt_deg", 0.0, lo=-90.0, hi=90.0), t.number("center_pan_deg", 0.0), allow)
    t.done()
    return spec


def _degradations(tables: dict, source: str) -> dict[str, Degradation]:
    out: dict[str, Degradation] = {}
    pending = dict(tables)

    def build(name: str, stack: tuple[str, ...]) -> Degradation:
        if name in out:
            return out[name]
        if name in stack:
            chain = " -> ".join(stack + (name,))
            raise InvalidInputError(f"{source}: degradations form a cycle through 'base': {chain}")
        if name not in pending:
            if name in DEGRADATION_PRESETS:
                return DEGRADATION_PRESETS[name]
            raise InvalidInputError(f"{source}: unknown degradation {name!r}; define [degradations.{name}] or use a "
                                    f"preset ({', '.join(DEGRADATION_PRESETS)})")
        d = dict(pending[name])
        if not isinstance(d, dict):
            raise InvalidInputError(f"{source}: [degradations.{name}] must be a table")
        base_name = d.pop("base", "clean")
        base = build(str(base_name), stack + (name,))
        deg = Degradation.from_dict({**d, "name": name}, base=base, where=f"{source}: [degradations.{name}]")
        out[name] = deg
        return deg

    for n in tables:
        build(n, ())
    return out


def _set(i: int, t: _Table, names: dict[str, set[str]]) -> SetSpec:
    name = t.string("name")
    if not name or not name.replace("_", "").replace("-", "").isalnum():
        raise InvalidInputError(f"{t.where}: 'name' must be a short identifier (letters, digits, _ or -), "
                                f"got {name!r}")
    t.where = f"{t.where} ({name})"
    refs = {}
    for key in ("site", "camera", "plan"):
        v = t.string(key)
        if v is None and len(names[key]) == 1:
            v = next(iter(names[key]))
        if v not in names[key]:
            raise InvalidInputError(f"{t.where}.{key} = {v!r}: define it under [{key}s.NAME] "
                                    f"(known: {', '.join(sorted(names[key])) or 'none'})")
        refs[key] = v
    degs = t.get("degradations", t.get("degradation", "clean"))
    degs = [degs] if isinstance(degs, str) else degs
    if not (isinstance(degs, list) and degs and all(isinstance(d, str) for d in degs)):
        raise InvalidInputError(f"{t.where}.degradations: expected a name or a list of names")
    for d in degs:
        if d not in names["degradation"] and d not in DEGRADATION_PRESETS:
            raise InvalidInputError(f"{t.where}: unknown degradation {d!r}; define [degradations.{d}] or use a preset "
                                    f"({', '.join(DEGRADATION_PRESETS)})")
    seed = t.number("seed", None, lo=0, integer=True)
    spec = SetSpec(name, refs["site"], refs["camera"], refs["plan"], tuple(degs),
                   t.number("count", 1, lo=1, hi=100_000, integer=True), t.string("description", "") or "",
                   t.range("heading_deg", (0.0, 360.0), lo=-360.0, hi=720.0),
                   t.range("pitch_deg", (0.0, 0.0), lo=-45.0, hi=45.0),
                   t.range("roll_deg", (0.0, 0.0), lo=-45.0, hi=45.0),
                   t.number("imu_sigma_deg", 0.0, lo=0.0, hi=10.0), t.string("poses_from"), seed)
    t.done()
    return spec


def parse_scene(text: str, *, source: str = "<scene>", base_dir: str | Path = ".") -> SceneSpec:
    """Parse and validate a scene file's text (InvalidInputError with the location on any problem)."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InvalidInputError(f"{source}: not valid TOML ({exc})") from None
    base = Path(base_dir)
    top = _Table(doc, source)
    ds = _Table(top.get("dataset", {}), f"{source}: [dataset]")
    name = ds.string("name", Path(source).stem) or "dataset"
    seed = ds.number("seed", 0, lo=0, hi=2 ** 63 - 1, integer=True)
    samples = ds.number("samples", 16, lo=1, hi=4096, integer=True)
    denoise = ds.get("denoise", False)
    description = ds.string("description", "") or ""
    if not isinstance(denoise, bool):
        raise InvalidInputError(f"{ds.where}.denoise: expected true or false")
    ds.done()

    def tables(key: str) -> dict:
        v = top.get(key, {})
        if not isinstance(v, dict):
            raise InvalidInputError(f"{source}: [{key}] must be tables like [{key}.NAME]")
        return v

    sites = {n: _site(n, _Table(v, f"{source}: [sites.{n}]"), base) for n, v in tables("sites").items()}
    cameras = {n: _camera(n, _Table(v, f"{source}: [cameras.{n}]")) for n, v in tables("cameras").items()}
    plans = {n: _plan(n, _Table(v, f"{source}: [plans.{n}]")) for n, v in tables("plans").items()}
    degs = _degradations(tables("degradations"), source)
    raw_sets = top.get("sets", [])
    top.done()
    if not isinstance(raw_sets, list) or not raw_sets:
        raise InvalidInputError(f"{source}: no [[sets]]: define at least one set of acquisitions")
    for key, d in (("sites", sites), ("cameras", cameras), ("plans", plans)):
        if not d:
            raise InvalidInputError(f"{source}: no [{key}.NAME] table: define at least one")
    names = {"site": set(sites), "camera": set(cameras), "plan": set(plans), "degradation": set(degs)}
    sets = tuple(_set(i, _Table(s, f"{source}: [[sets]] #{i + 1}"), names) for i, s in enumerate(raw_sets))
    seen: set[str] = set()
    for s in sets:
        if s.name in seen:
            raise InvalidInputError(f"{source}: two sets are named {s.name!r}: set names must be unique")
        seen.add(s.name)
    by_name = {s.name: s for s in sets}
    for s in sets:
        if s.poses_from is not None:
            src = by_name.get(s.poses_from)
            if src is None:
                raise InvalidInputError(f"{source}: set {s.name}: poses_from = {s.poses_from!r} names no set")
            if src.poses_from is not None:
                raise InvalidInputError(f"{source}: set {s.name}: poses_from {s.poses_from!r} itself borrows poses; "
                                        "point at the original set")
            if src.site != s.site or src.count < s.count:
                raise InvalidInputError(f"{source}: set {s.name} borrows poses from {src.name}: it needs the same site "
                                        f"and at most {src.count} acquisitions")
    for s in sets:  # build every plan now so geometry errors surface at load time
        try:
            plans[s.plan].plan_for(cameras[s.camera])
        except InvalidInputError as exc:
            raise InvalidInputError(f"{source}: set {s.name}: plan {s.plan!r} with camera {s.camera!r}: {exc}") \
                from None
        site = sites[s.site]
        if site.pose_half_m < 0:
            raise InvalidInputError(f"{source}: site {site.name}: pose_half_m must be >= 0")
    return SceneSpec(name, int(seed), int(samples), denoise, sites, cameras, plans, degs, sets, source, description,
                     text)


def load_scene(path: str | Path) -> SceneSpec:
    """Read a scene file (see the module docstring)."""
    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(f"scene file {p} does not exist: give a .toml file such as scenes/robustness.toml")
    return parse_scene(p.read_text(), source=str(p), base_dir=p.parent)


# ------------------------------------------------------------------------------------------------
# expansion into acquisition jobs
# ------------------------------------------------------------------------------------------------
def set_seed(scene: SceneSpec, s: SetSpec) -> int:
    """The set's seed: its own, or derived from the scene seed and the set name (stable across edits)."""
    if s.seed is not None:
        return int(s.seed)
    return int(np.random.SeedSequence([scene.seed & 0xFFFFFFFF, zlib.crc32(s.name.encode())]).generate_state(1)[0])


def _draw(rng: np.random.Generator, r: Range) -> float:
    return float(r[0]) if r[0] == r[1] else float(rng.uniform(r[0], r[1]))


def set_poses(scene: SceneSpec, s: SetSpec) -> list[Pose]:
    """Poses of a set's acquisitions (reproducible from the seeds)."""
    if s.poses_from is not None:
        src = scene.set_by_name(s.poses_from)
        base = set_poses(scene, src)[: s.count]
        if s.pitch_deg == (0.0, 0.0) and s.roll_deg == (0.0, 0.0):
            return base
        rng = np.random.default_rng([set_seed(scene, s), 2])
        return [Pose(p.x, p.y, p.heading_deg, _draw(rng, s.pitch_deg), _draw(rng, s.roll_deg)) for p in base]
    site = scene.sites[s.site]
    rng = np.random.default_rng([set_seed(scene, s), 1])
    out = []
    for _ in range(s.count):
        x = site.center[0] + float(rng.uniform(-site.pose_half_m, site.pose_half_m))
        y = site.center[1] + float(rng.uniform(-site.pose_half_m, site.pose_half_m))
        h = float(np.mod(_draw(rng, s.heading_deg), 360.0))
        out.append(Pose(x, y, h, _draw(rng, s.pitch_deg), _draw(rng, s.roll_deg)))
    return out


def set_jobs(scene: SceneSpec, s: SetSpec) -> list[AcquisitionJob]:
    """The acquisition jobs of a set: poses, camera, plan, the cycled degradations and per-job seeds."""
    cam = scene.cameras[s.camera]
    plan = scene.plans[s.plan].plan_for(cam)
    poses = set_poses(scene, s)
    seeds = np.random.SeedSequence([set_seed(scene, s) & 0xFFFFFFFF, 3]).generate_state(len(poses))
    jobs = []
    for i, pose in enumerate(poses):
        dname = s.degradations[i % len(s.degradations)]
        deg = scene.degradations.get(dname) or DEGRADATION_PRESETS[dname]
        jobs.append(AcquisitionJob(pose, cam, plan, deg, seed=int(seeds[i]), samples=scene.samples,
                                   denoise=scene.denoise, imu_sigma_deg=s.imu_sigma_deg,
                                   meta={"set": s.name, "index": i}))
    return jobs
