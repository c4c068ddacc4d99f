"""Label factory for the skyline detector: rendered panoramas with their exact horizon (issue 11).

Every label is one dressed Blender panorama (``clean`` / ``realistic`` / ``distorted`` look) at a
seeded random pose, with the truth computed independently by the ray-marcher
(:func:`render_service.renderers.raymarch.horizon_at`) on the same multi-resolution terrain,
every 0.1 degree of azimuth, turned into the mast's frame by
:func:`board.match.synthetic.observe` (heading, pitch, roll).

Draws (all from one seed per case): position uniform over the DEM's inner half (off any grid),
heading uniform in [0, 360), tilt profile level / pitch 10 deg / roll 10 deg, sun azimuth uniform,
sun elevation uniform in [8, 60] deg (low suns put the sun and its halo near the horizon),
regolith texture seed and the rocks/noise seed.  Renders are cached under ``/tmp/labels`` (one
folder per case, keyed by a hash of the case): never in the repository.

The split is by DEM (:data:`SPLITS`): the detector is tuned on ``tune`` and measured on
``validate``, whose terrains (and seeds) it never saw.

Run ``python -m benchmarks.detector_labels --split tune --per-dem 4`` (``make detector-labels``).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import logging
import math
import os
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass, replace
from functools import lru_cache
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

LABEL_ROOT = Path(os.environ.get("SKYLOC_LABELS", "/tmp/labels"))
REAL_DEMS = Path(os.environ.get("SKYLOC_TEST_DEMS", "/work/shared/data/dems"))
PRESETS = ("clean", "realistic", "distorted")
TILTS = {"level": (0.0, 0.0), "pitch10": (10.0, 0.0), "roll10": (0.0, 10.0)}

#: Tuning and validation terrains (split by DEM, never mixed).
SPLITS: dict[str, tuple[str, ...]] = {
    "tune": ("procedural:mars:101:8000:5", "procedural:mars:102:8000:5",
             str(REAL_DEMS / "earth_oetztal_alps_srtm3.tif")),
    "validate": ("procedural:mars:301:8000:5", "procedural:moon:302:8000:5",
                 str(REAL_DEMS / "moon_gld100_aristoteles_256ppd.tif"),
                 str(REAL_DEMS / "earth_sthelens_1980_usgs30m.dem"),
                 str(REAL_DEMS / "earth_baltoro_karakoram_srtm3.tif")),
}
MAST_HEIGHT_M = 2.0
TRUTH_N_AZIMUTH = 3600
#: Elevation band rendered (mast frame, degrees): every horizon of the split at 10 deg of tilt, the sun
#: up to 50 deg; rows below -40 deg (the most expensive ground) are not rendered.
EL_RANGE_DEG = (-40.0, 50.0)


def label_geometry(width: int):
    """Full-circle geometry of a label, heading in the middle, ``width`` x ``width / 4`` pixels."""
    from board.acquisition import PanoramaGeometry

    return PanoramaGeometry.full_circle(width, width // 4, elevation_top_deg=EL_RANGE_DEG[1],
                                        elevation_bottom_deg=EL_RANGE_DEG[0], azimuth_start_deg=-180.0,
                                        azimuth_reference="heading", kind="intensity")


@lru_cache(maxsize=None)
def body_of_dem(dem: str) -> str:
    """Body name of a DEM file or ``procedural:BODY:...`` spec."""
    if dem.startswith("procedural:"):
        return dem.split(":")[1]
    from blender_addon.terrain.dem import dem_info

    return dem_info(dem).body.name


@dataclass(frozen=True)
class LabelCase:
    """One labelled view: the DEM, the pose (metres in the DEM's metric CRS, degrees), the look."""

    split: str
    dem: str
    x: float
    y: float
    heading_deg: float
    pitch_deg: float
    roll_deg: float
    preset: str
    sun_azimuth_deg: float
    sun_elevation_deg: float
    seed: int
    texture_seed: int
    width: int = 1440
    samples: int = 8
    height_m: float = MAST_HEIGHT_M

    @property
    def look(self) -> str:
        """The look a campaign renders for this preset on this DEM's body (realistic on the Moon: the Moon's)."""
        from blender_addon.core.degrade import look_on_body

        return look_on_body(self.preset, body_of_dem(self.dem)).name

    @property
    def key(self) -> str:
        d = asdict(self)
        if self.look != self.preset:
            # rendered in the body's look since session 6 (before: the Mars look on every body); the Mars
            # labels keep their keys
            d["look"] = self.look
        blob = json.dumps(d, sort_keys=True).encode()
        return hashlib.sha1(blob).hexdigest()[:12]

    @property
    def dem_name(self) -> str:
        return Path(self.dem).stem if not self.dem.startswith("procedural:") else self.dem.split(":", 1)[1]

    @property
    def folder(self) -> Path:
        return LABEL_ROOT / self.key


def _dem_bounds(path: Path) -> tuple[float, float, float, float]:
    from blender_addon.terrain.dem import open_metric_source

    return open_metric_source(path).bounds()


def draw_cases(split: str, *, per_dem: int, seed: int = 11, presets=PRESETS, tilts=tuple(TILTS),
               width: int = 1440, samples: int = 8) -> list[LabelCase]:
    """``per_dem`` random poses per DEM of ``split``, each rendered in every preset; tilt profiles cycle.

    Deterministic for a given (split, per_dem, seed).  DEMs that are missing are skipped with a warning.
    """
    from blender_addon.terrain.dem import resolve_dem

    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}: use one of {', '.join(SPLITS)}")
    per = []
    for d_i, dem in enumerate(SPLITS[split]):
        cases = []
        if not dem.startswith("procedural:") and not Path(dem).is_file():
            log.warning("DEM %s missing: skipped", dem)
            continue
        path = resolve_dem(dem)
        x0, y0, x1, y1 = _dem_bounds(path)
        rng = np.random.default_rng(np.random.SeedSequence([seed, d_i, sum(map(ord, dem))]))
        for k in range(per_dem):
            x = float(x0 + (x1 - x0) * rng.uniform(0.25, 0.75))
            y = float(y0 + (y1 - y0) * rng.uniform(0.25, 0.75))
            tilt = tilts[k % len(tilts)]
            pitch, roll = TILTS[tilt]
            sgn = 1.0 if rng.uniform() < 0.5 else -1.0
            base = dict(split=split, dem=dem, x=round(x, 3), y=round(y, 3),
                        heading_deg=round(float(rng.uniform(0, 360)), 3),
                        pitch_deg=sgn * pitch, roll_deg=sgn * roll,
                        sun_azimuth_deg=round(float(rng.uniform(0, 360)), 2),
                        sun_elevation_deg=round(float(rng.uniform(8, 60)), 2),
                        seed=int(rng.integers(1 << 30)), texture_seed=int(rng.integers(1 << 30)),
                        width=width, samples=samples)
            for preset in presets:
                cases.append(LabelCase(preset=preset, **base))
        per.append(cases)
    # interleaved by DEM (pose 1 of every DEM, then pose 2, ...): a partial run covers every terrain
    n = len(presets)
    return [c for k in range(per_dem) for cases in per for c in cases[k * n:(k + 1) * n]]


def true_skyline(terrain, case: LabelCase, *, n: int = TRUTH_N_AZIMUTH) -> tuple[np.ndarray, np.ndarray]:
    """The exact horizon in the mast frame, ``n`` samples from the heading (deg), and the ray-marched
    distance of every world azimuth sample (m, for near-horizon statistics)."""
    from board.match.synthetic import observe
    from render_service.renderers.base import RenderSpec
    from render_service.renderers.raymarch import horizon_at

    spec = RenderSpec(camera_height_m=case.height_m, n_azimuth=TRUTH_N_AZIMUTH,
                      body_radius_m=float(terrain.body.radius_m))
    az, el, dist = horizon_at(terrain, case.x, case.y, spec)
    rel = observe(np.asarray(az), np.asarray(el), heading_deg=case.heading_deg, pitch_deg=case.pitch_deg,
                  roll_deg=case.roll_deg, n=n)
    return rel, np.asarray(dist)


def _render_dressed(terrain, case: LabelCase, path: Path, *, degradation=None, dark_sky: bool = False
                    ) -> tuple[np.ndarray, dict]:
    """Dressed equirectangular render of ``case`` (the steps of ``make_panorama``'s dressed look, with
    the case's sun and texture seed instead of the preset's).

    degradation : replaces the case's preset (its sun is still the case's); dark_sky : a black,
    airless sky (lunar look) instead of the dressing's sky.
    """
    from blender_addon.core import degrade
    from blender_addon.core.degrade import SunParams
    from blender_addon.core.terrain_mesh import sample_height
    from blender_addon.scene import dressing
    from blender_addon.scene import render as R
    from blender_addon.scene.camera import place_camera

    deg = degradation if degradation is not None else degrade.look_on_body(case.preset, terrain.body.name)
    # the case's sun direction; the look's sunlight (a body's look has its own strength) is kept
    deg = replace(deg, sun=replace(deg.sun, azimuth_deg=case.sun_azimuth_deg, elevation_deg=case.sun_elevation_deg,
                                   relative=False))
    info = dressing.dress_scene(terrain, deg, center_xy=(case.x, case.y), heading_deg=case.heading_deg,
                                seed=case.seed, texture_seed=case.texture_seed, samples=case.samples)
    if dark_sky:
        import bpy

        world = bpy.data.worlds.get("SkylocDarkSky") or bpy.data.worlds.new("SkylocDarkSky")
        world.use_nodes = True
        world.node_tree.nodes["Background"].inputs[0].default_value = (0.0, 0.0, 0.0, 1.0)
        bpy.context.scene.world = world
    z = sample_height(terrain, case.x, case.y) + case.height_m
    place_camera(case.x, case.y, z, case.heading_deg, case.pitch_deg, case.roll_deg)
    p = R.render_equirect(path, width=case.width, height=case.width // 4, el_range_deg=EL_RANGE_DEG,
                         color_mode="RGB", color_depth="16")
    lin = degrade.decode_render(R.read_image(p))
    rng = np.random.default_rng(np.random.SeedSequence([case.seed & 0xFFFFFFFF, 0x9A40]))
    if deg.lens.dispersion == 0 and deg.lens.vignetting == 0:
        img = degrade.degrade_panorama(lin, deg, rng)
    else:
        img = _distorted(lin, deg, rng)
    img = np.ascontiguousarray(img[..., ::-1])          # BGR, as board.acquisition writes with OpenCV
    meta = {"preset": case.preset, "sun_azimuth_deg": info.sun_azimuth_deg,
            "sun_elevation_deg": info.sun_elevation_deg, "n_rocks": info.n_rocks, "label_key": case.key}
    return img, meta


def _distorted(lin: np.ndarray, deg, rng: np.random.Generator) -> np.ndarray:
    """The ``distorted`` look on an equirectangular product: exposure, dispersion (colour channels
    magnified about the heading by the preset's amount), vignetting along azimuth, blur, noise.

    A panorama has no single lens; this applies the preset's optical defects the way a panorama
    stitched from distorted frames keeps them (channel misregistration, periodic light fall-off).
    """
    import cv2

    from blender_addon.core import degrade

    s = deg.sensor
    img = degrade.apply_exposure(lin.astype(np.float32), s.exposure_ev)
    H, W = img.shape[:2]
    # dispersion: each channel rescaled about the centre of every frame-sized (45 deg) tile
    tile = W // 8
    u = np.arange(W, dtype=np.float32)
    v = np.arange(H, dtype=np.float32)
    cu = (np.floor(u / tile) + 0.5) * tile
    out = np.empty_like(img)
    for ch, scale in enumerate(degrade.dispersion_scales(deg.lens.dispersion, img.shape[2])):
        mx = np.broadcast_to(cu + (u - cu) / scale, (H, W)).astype(np.float32)
        my = np.broadcast_to((H / 2 + (v - H / 2) / scale)[:, None], (H, W)).astype(np.float32)
        out[..., ch] = cv2.remap(img[..., ch], mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    # vignetting: light loss growing to ``vignetting`` at the tile edges
    r = np.abs(u - cu) / (tile / 2)
    out *= (1.0 - deg.lens.vignetting * r ** 2)[None, :, None].astype(np.float32)
    out = degrade.gaussian_blur(out, deg.lens.blur_px)
    out = degrade.add_sensor_noise(out, rng, full_well_e=s.full_well_e, read_noise_e=s.read_noise_e)
    return degrade.quantise(degrade.srgb_encode(out), s.bit_depth)


def make_label(case: LabelCase, *, terrain=None, out: Path | None = None, degradation=None,
               dark_sky: bool = False, build: bool = True) -> Path:
    """Render (or reuse) the label folder of ``case``: ``pano/`` (a panorama folder) + ``truth.npz``.

    out : the folder (default ``case.folder`` under :data:`LABEL_ROOT`); degradation / dark_sky : see
    :func:`_render_dressed`; build : build the terrain in the scene first (False: it is already there).
    """
    from blender_addon.scene import build_terrain, reset_scene
    from blender_addon.terrain.dem import resolve_dem
    from blender_addon.terrain.multires import build_multires
    from board.acquisition import GroundTruth, write_panorama

    out = Path(out) if out is not None else case.folder
    if (out / "truth.npz").is_file():
        return out
    t0 = time.perf_counter()
    if terrain is None:
        terrain = build_multires(resolve_dem(case.dem), (case.x, case.y), grid_half_m=50.0)
    if build:
        reset_scene()
        build_terrain(terrain)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        img, meta = _render_dressed(terrain, case, tmp / "render.png", degradation=degradation, dark_sky=dark_sky)
        (tmp / "render.png").unlink(missing_ok=True)
        truth = GroundTruth(x=case.x, y=case.y, heading_deg=case.heading_deg, pitch_deg=case.pitch_deg,
                            roll_deg=case.roll_deg, crs=terrain.crs_wkt, dem=case.dem)
        write_panorama(tmp / "pano", img, label_geometry(case.width),
                       mast_height_m=case.height_m, truth=truth, meta=meta)
        rel, dist = true_skyline(terrain, case)
        np.savez_compressed(tmp / "truth.npz", el_deg=rel, dist_m=dist)
        (tmp / "case.json").write_text(json.dumps(asdict(case) | {"key": case.key,
                                                                  "render_s": time.perf_counter() - t0}))
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    log.info("label %s (%s %s) in %.1f s", case.key, case.dem_name, case.preset, time.perf_counter() - t0)
    return out


def make_labels(cases: list[LabelCase]) -> list[Path]:
    """Render every case (terrain built once per pose, shared by the presets of that pose)."""
    from blender_addon.terrain.dem import resolve_dem
    from blender_addon.terrain.multires import build_multires

    out, cache = [], {}
    for c in cases:
        if (c.folder / "truth.npz").is_file():
            out.append(c.folder)
            continue
        k = (c.dem, c.x, c.y)
        if k not in cache:
            cache.clear()
            cache[k] = build_multires(resolve_dem(c.dem), (c.x, c.y), grid_half_m=50.0)
        out.append(make_label(c, terrain=cache[k]))
    return out


def load_label(folder: Path) -> tuple[LabelCase, np.ndarray, np.ndarray]:
    """(case, true elevation in the mast frame every 0.1 deg from the heading, distances)."""
    d = json.loads((folder / "case.json").read_text())
    d.pop("key", None), d.pop("render_s", None)
    t = np.load(folder / "truth.npz")
    return LabelCase(**d), t["el_deg"], t["dist_m"]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--split", choices=sorted(SPLITS), default="tune")
    p.add_argument("--per-dem", type=int, default=3, help="poses per DEM (each rendered in every preset)")
    p.add_argument("--seed", type=int, default=11)
    p.add_argument("--width", type=int, default=1440)
    p.add_argument("--samples", type=int, default=8)
    p.add_argument("--presets", default=",".join(PRESETS))
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    cases = draw_cases(a.split, per_dem=a.per_dem, seed=a.seed, width=a.width, samples=a.samples,
                       presets=tuple(a.presets.split(",")))
    t = time.perf_counter()
    make_labels(cases)
    log.info("%d labels of split %s in %s (%.0f s)", len(cases), a.split, LABEL_ROOT, time.perf_counter() - t)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
