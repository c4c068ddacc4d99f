"""Skyline detection on rendered panoramas against the ray-marched truth, split by DEM (issue 11).

Reads the labels of :mod:`benchmarks.detector_labels` (rendering the missing ones first) and, for
each detector in the same run (``skyloc``: the extraction chain; ``baseline``: the reference
report's graph, every column kept), prints per split and preset:

* returned : share of panoramas with a skyline (status ok or degraded);
* kept/seen : kept azimuth samples over the samples whose true horizon is in view;
* median |err| : of the kept samples against the truth (degrees);
* > 1 deg : share of kept samples more than 1 degree off (a wrong kept column is worse than a masked one);
* p95 |err| and the worst case.

Speed and memory of the detector on a 3600 x 1800 panorama (wall, CPU, peak RSS of a child
process that only loads the image and extracts).  ``--upsample 2.5`` measures on the labels resampled
finer (3600 x 900 px), where the chain detects coarse to fine, against the detector at full resolution.

``python -m benchmarks.bench_detector --split validate --per-dem 3`` (``make bench-detector``).
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from benchmarks.detector_labels import PRESETS, SPLITS, draw_cases, load_label, make_labels

log = logging.getLogger(__name__)

SKYLINE_N = 360
ERR_BAD_DEG = 1.0


@dataclass
class Tally:
    """Per (split, preset, detector) counts."""

    n: int = 0
    returned: int = 0
    seen: int = 0
    kept: int = 0
    errors: list = field(default_factory=list)
    worst: list = field(default_factory=list)

    def row(self) -> dict:
        e = np.concatenate(self.errors) if self.errors else np.zeros(0)
        return {"n": self.n, "returned": self.returned / max(self.n, 1),
                "kept_over_seen": self.kept / max(self.seen, 1),
                "median_err_deg": float(np.median(e)) if e.size else float("nan"),
                "p95_err_deg": float(np.percentile(e, 95)) if e.size else float("nan"),
                "bad_share": float(np.mean(e > ERR_BAD_DEG)) if e.size else float("nan"),
                "max_err_deg": float(e.max()) if e.size else float("nan")}


def truth_on_grid(el_fine: np.ndarray, n: int = SKYLINE_N) -> np.ndarray:
    """Truth (every 0.1 deg from the heading) at the skyline's ``n`` point samples."""
    k = el_fine.size // n
    return el_fine[::k][:n]


def in_view(truth: np.ndarray, geom) -> np.ndarray:
    """Samples whose true horizon lies inside the panorama's elevation band (1 px inside)."""
    top = geom.elevation_row0_deg + 0.5 * geom.elevation_step_deg
    bot = top - geom.height * geom.elevation_step_deg
    return (truth < top - geom.elevation_step_deg) & (truth > bot + geom.elevation_step_deg)


def run_skyloc(pano):
    from board.extraction import extract_from_panorama

    res = extract_from_panorama(pano)
    if res.skyline is None:
        return None, res.reason
    return res.skyline.elevation_deg, res.status


def run_baseline(pano):
    from board.detect import detect_baseline
    from board.extraction import panorama_line_to_skyline

    rows = detect_baseline(pano.image, wrap=True).astype(float) - 0.5
    sky = panorama_line_to_skyline(rows, pano.geometry, n_azimuth=SKYLINE_N)
    return sky.elevation_deg, "ok"


def run_direct(pano):
    """The extraction chain with the detector at full resolution whatever the size (no coarse to fine)."""
    from dataclasses import replace

    from board.detect import DetectorParams
    from board.extraction import ExtractionOptions, extract_from_panorama

    res = extract_from_panorama(pano, options=ExtractionOptions(detector=replace(DetectorParams(),
                                                                                  max_direct_pixels=0)))
    if res.skyline is None:
        return None, res.reason
    return res.skyline.elevation_deg, res.status


DETECTORS = {"skyloc": run_skyloc, "baseline": run_baseline}


def upsampled(pano, factor: float):
    """The panorama resampled ``factor`` times finer (bilinear), same field of view: a stand-in for a finer
    render of the same scene (e.g. 1440 x 360 -> 3600 x 900 px at 0.1 deg/px, as the speed panorama)."""
    import cv2

    from board.acquisition import Panorama, PanoramaGeometry

    g = pano.geometry
    W, H = int(round(g.width * factor)), int(round(g.height * factor))
    sa, se = g.azimuth_step_deg * g.width / W, g.elevation_step_deg * g.height / H
    g2 = PanoramaGeometry(W, H, g.azimuth_col0_deg - g.azimuth_step_deg / 2 + sa / 2, sa,
                          g.elevation_row0_deg + g.elevation_step_deg / 2 - se / 2, se, g.azimuth_reference, g.kind)
    img = cv2.resize(pano.image, (W, H), interpolation=cv2.INTER_LINEAR)
    seen = (None if pano.seen is None
            else cv2.resize(pano.seen.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST) > 0)
    return Panorama(img, g2, seen, pano.mast_height_m, pano.truth, pano.meta, pano.root)


def detector_from_file(path: str):
    """An extraction run with the ``detect_skyline`` of another version of ``board/detect/sky_regions.py``
    (e.g. ``git show c39f888:board/detect/sky_regions.py > /tmp/issue6.py``), same extraction chain."""
    import importlib.util

    import board.extraction as extraction

    spec = importlib.util.spec_from_file_location("skyloc_other_detector", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod                 # dataclasses look their module up
    spec.loader.exec_module(mod)

    def run(pano):
        current = extraction.detect_skyline
        extraction.detect_skyline = lambda img, **kw: mod.detect_skyline(img, seen=kw.get("seen"),
                                                                       wrap=kw.get("wrap", False))
        try:
            return run_skyloc(pano)
        finally:
            extraction.detect_skyline = current
    return run


def evaluate(folders, detectors=DETECTORS, *, verbose: bool = False, upsample: float = 1.0) -> dict:
    from board.acquisition import load_panorama

    out: dict = {}
    for f in folders:
        case, fine, _ = load_label(f)
        pano = load_panorama(f / "pano")
        if upsample != 1.0:
            pano = upsampled(pano, upsample)
        truth = truth_on_grid(fine)
        view = in_view(truth, pano.geometry)
        for name, fn in detectors.items():
            el, status = fn(pano)
            tilt = "level" if case.pitch_deg == 0 and case.roll_deg == 0 else "tilt10"
            keys = [(case.split, case.preset, name), (case.split, f"{case.dem_name} (all presets)", name),
                    (case.split, f"{case.preset} {tilt}", name)]
            ts = [out.setdefault(k, Tally()) for k in keys]
            err = np.zeros(0)
            kept = np.zeros(view.shape, bool)
            if el is not None:
                kept = view & np.isfinite(el)
                err = np.abs(el[kept] - truth[kept])
            for t in ts:
                t.n += 1
                t.seen += int(view.sum())
                if el is not None:
                    t.returned += 1
                    t.kept += int(kept.sum())
                    t.errors.append(err)
            if el is None:
                if verbose:
                    log.info("%s %s %-9s %-8s refused: %s", case.key, case.dem_name, case.preset, name, status)
                continue
            if verbose:
                log.info("%s %-22s %-9s %-8s p%+.0f r%+.0f %-8s kept %.2f med %.3f bad %.4f max %.2f", case.key,
                         case.dem_name, case.preset, name, case.pitch_deg, case.roll_deg, status,
                         kept.sum() / max(view.sum(), 1), np.median(err) if err.size else np.nan,
                         np.mean(err > ERR_BAD_DEG) if err.size else np.nan, err.max() if err.size else np.nan)
    return out


def print_table(res: dict) -> None:
    print("| split | preset | detector | panoramas | returned | kept / seen | median abs err (deg) | "
          "p95 (deg) | kept > 1 deg | worst (deg) |")
    print("| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for (split, preset, name), t in sorted(res.items()):
        r = t.row()
        print(f"| {split} | {preset} | {name} | {r['n']} | {100 * r['returned']:.0f} % | "
              f"{100 * r['kept_over_seen']:.1f} % | {r['median_err_deg']:.3f} | {r['p95_err_deg']:.2f} | "
              f"{100 * r['bad_share']:.2f} % | {r['max_err_deg']:.1f} |")


_SPEED_CHILD = r"""
import resource, sys, time, json
def peak_mb():
    # VmHWM: the peak resident size of this process's own address space.  Not ru_maxrss: a child
    # started by vfork + exec (subprocess) inherits its parent's peak there (the bench's own hundreds of MB)
    try:
        with open("/proc/self/status") as fh:
            return next(int(x.split()[1]) for x in fh if x.startswith("VmHWM:")) / 1024
    except (OSError, StopIteration):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
from board.acquisition import load_panorama
from board.extraction import extract_from_panorama
imports_mb = peak_mb()
pano = load_panorama(sys.argv[1])
img, g = pano.image, pano.geometry
from board.acquisition import Panorama
import tracemalloc
base = peak_mb()
best = (1e9, 1e9)
for _ in range(3):
    t, c = time.perf_counter(), time.process_time()
    r = extract_from_panorama(Panorama(img, g))
    best = min(best, (time.perf_counter() - t, time.process_time() - c))
del r
tracemalloc.start()
r = extract_from_panorama(Panorama(img, g))
traced = tracemalloc.get_traced_memory()[1]
tracemalloc.stop()
print(json.dumps({"wall_s": best[0], "cpu_s": best[1], "status": r.status, "extraction_peak_mb": traced / 2**20,
                  "second_pass": r.diagnostics.get("colour_second_pass", "not run"),
                  "detections_run": r.diagnostics.get("detections_run", 1),
                  "peak_rss_mb": peak_mb(), "rss_before_mb": base, "imports_mb": imports_mb}))
"""


def _slope_scene(g, rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) uint8 BGR: a bluish sky over reddish ground at a random skyline, and a near slope of the
    ground's colour filling the view to its top over a third of the azimuths (the NavCam case that makes
    the detector run its colour second pass)."""
    from board.synthetic import SkylineFunction

    az, el = g.azimuths_deg(), g.elevations_deg()
    horizon = SkylineFunction.random(2027)(az)
    horizon = np.where((az % 360.0) < 120.0, 91.0, horizon)           # the slope: ground up to the zenith
    ground = el[:, None] < horizon[None, :]
    img = np.empty((g.height, g.width, 3), np.float32)
    sky_bgr, ground_bgr = np.array([0.80, 0.62, 0.50]), np.array([0.30, 0.42, 0.58])
    img[:] = sky_bgr
    img[ground] = ground_bgr
    img += rng.normal(0.0, 0.03, img.shape).astype(np.float32)
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def _blind_slope_scene(g, rng: np.random.Generator) -> np.ndarray:
    """:func:`_slope_scene` with a 60-degree sector whose ground has the sky's colour (no boundary to find): the
    first pass masks it, the colour second pass runs (the slope) and still masks it, so the detector runs a third
    time (the second pass's colour classes without their re-fit): the most work one view can ask for."""
    img = _slope_scene(g, rng)
    az, el = g.azimuths_deg() % 360.0, g.elevations_deg()
    blind = (az >= 200.0) & (az < 260.0)
    sky = img[0, blind].mean(axis=0)
    img[:, blind] = np.clip(sky + rng.normal(0.0, 0.03 * 255, img[:, blind].shape), 0, 255).astype(np.uint8)
    del el
    return img


def _clipped_scene(g, rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) uint8 grey: a sky brightening towards a random skyline past the sensor's full scale (the Moon's
    realistic look under a high sun), the edge blurred by the optics (Gaussian, 0.8 px) before the sensor clips
    it, over darker ground: the detector's clipped-sky count (:mod:`board.detect.clipped_edge`) runs on every
    column."""
    import cv2

    from board.synthetic import SkylineFunction

    az, el = g.azimuths_deg(), g.elevations_deg()
    horizon = SkylineFunction.random(2028)(az)
    above = el[:, None] - horizon[None, :]                              # degrees above the skyline
    radiance = np.where(above > 0.0, 0.75 + 0.6 * np.exp(-np.maximum(above, 0.0) / 8.0), 0.35).astype(np.float32)
    radiance = cv2.GaussianBlur(radiance, (0, 0), 0.8)
    radiance += rng.normal(0.0, 0.02, radiance.shape).astype(np.float32)
    grey = (np.clip(radiance, 0.0, 1.0) * 255 + 0.5).astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=2)


#: the speed scenes, in the order measured
SPEED_SCENES = ("plain", "slope", "blind", "clipped")


def speed_scene_image(scene: str, g) -> np.ndarray:
    """(H, W, 3) uint8 BGR image of speed scene ``scene`` (one of :data:`SPEED_SCENES`) on geometry ``g``."""
    from board.synthetic import SkylineFunction, synth_panorama

    if scene not in SPEED_SCENES:
        raise ValueError(f"unknown speed scene {scene!r}: choose from {', '.join(SPEED_SCENES)}")
    if scene == "slope":
        return _slope_scene(g, np.random.default_rng(1))
    if scene == "blind":
        return _blind_slope_scene(g, np.random.default_rng(1))
    if scene == "clipped":
        return _clipped_scene(g, np.random.default_rng(1))
    grey = synth_panorama(g, SkylineFunction.random(2026), noise_sigma=0.02, seed=1)
    return np.repeat((np.clip(grey, 0, 1) * 255 + 0.5).astype(np.uint8)[..., None], 3, axis=2)


def speed(scene: str = "plain") -> dict:
    """Detector speed and peak memory on a 3600 x 1800 colour panorama read from disk, in a fresh
    child process (peak RSS, VmHWM: the interpreter, numpy/OpenCV, the image and the extraction).
    CPU and wall: the best of 3 extractions (loading not included).  ``scene``: "plain" (a grey
    skyline: one pass), "slope" (:func:`_slope_scene`: the colour second pass runs too) or "blind" (:func:`
    _blind_slope_scene`: three detections) or "clipped" (:func:`_clipped_scene`: a sky clipped at the line)."""
    import tempfile

    from board.acquisition import PanoramaGeometry, write_panorama

    g = PanoramaGeometry.full_circle(3600, 1800, elevation_top_deg=90.0, elevation_bottom_deg=-90.0)
    img = speed_scene_image(scene, g)
    with tempfile.TemporaryDirectory() as tmp:
        write_panorama(tmp, img, g)
        del img
        p = subprocess.run([sys.executable, "-c", _SPEED_CHILD, tmp], capture_output=True, text=True,
                           check=True, env=os.environ | {"OMP_NUM_THREADS": "2"})
    return json.loads(p.stdout.strip().splitlines()[-1])


def print_speed(scenes: tuple[str, ...] = SPEED_SCENES) -> None:
    """Measure and print :func:`speed` for each scene."""
    for scene in scenes:
        s = speed(scene)
        print(f"\nspeed 3600 x 1800 colour panorama, {scene} scene (colour second pass: {s['second_pass']}, "
              f"detections run: {s.get('detections_run', 1)}): "
              f"wall {s['wall_s']:.2f} s, CPU {s['cpu_s']:.2f} s, "
              f"peak RSS {s['peak_rss_mb']:.0f} MB (after the imports: {s['imports_mb']:.0f} MB, after loading "
              f"the panorama folder: {s['rss_before_mb']:.0f} MB), "
              f"peak of the extraction's own allocations (tracemalloc) {s['extraction_peak_mb']:.0f} MB, "
              f"status {s['status']}", flush=True)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--split", default="tune,validate", help="comma-separated splits")
    p.add_argument("--per-dem", type=int, default=3)
    p.add_argument("--seed", type=int, default=11)
    p.add_argument("--presets", default=",".join(PRESETS))
    p.add_argument("--no-speed", action="store_true")
    p.add_argument("--speed-only", action="store_true", help="only the speed scenes (no labels)")
    p.add_argument("--scenes", default=",".join(SPEED_SCENES),
                   help=f"comma-separated speed scenes to time (default: all of {', '.join(SPEED_SCENES)})")
    p.add_argument("--cached-only", action="store_true", help="measure the labels already rendered, render none")
    p.add_argument("--other-detector", help="also run this version of board/detect/sky_regions.py (a file)")
    p.add_argument("--upsample", type=float, default=1.0,
                   help="measure on the labels resampled this many times finer (bilinear), with the detector at "
                        "full resolution ('direct') as well as the chain's coarse to fine ('skyloc')")
    p.add_argument("--no-baseline", action="store_true", help="leave the report's baseline out")
    p.add_argument("-v", "--verbose", action="store_true")
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for noisy in ("blender_addon", "board", "render_service"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    scenes = tuple(x for x in a.scenes.split(",") if x)
    bad = [x for x in scenes if x not in SPEED_SCENES]
    if bad:
        p.error(f"--scenes: unknown speed scene(s) {', '.join(bad)}; choose from {', '.join(SPEED_SCENES)}")
    if a.speed_only:
        print_speed(scenes)
        return 0
    folders = []
    for split in a.split.split(","):
        if split not in SPLITS:
            raise SystemExit(f"unknown split {split!r}")
        cases = draw_cases(split, per_dem=a.per_dem, seed=a.seed, presets=tuple(a.presets.split(",")))
        if a.cached_only:
            folders += [c.folder for c in cases if (c.folder / "truth.npz").is_file()]
        else:
            folders += make_labels(cases)
    print(f"# bench_detector: {len(folders)} labelled panoramas, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
          f"load {os.getloadavg()[0]:.2f}")
    dets = dict(DETECTORS)
    if a.no_baseline:
        del dets["baseline"]
    if a.upsample != 1.0:
        dets["direct"] = run_direct
        print(f"# labels resampled {a.upsample:g} times finer")
    if a.other_detector:
        dets["other"] = detector_from_file(a.other_detector)
    print_table(evaluate(folders, dets, verbose=a.verbose, upsample=a.upsample))
    if not a.no_speed:
        print_speed(scenes)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
