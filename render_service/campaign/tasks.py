"""The campaign's Dask tasks (run on workers; arguments picklable, results small).

* :func:`terrain_task` builds a multi-resolution terrain for the ray-marcher (once per campaign);
* :func:`db_tile_task` renders one tile of the lost-in-space database (never twice);
* :func:`truth_task` ray-marches the exact horizon at candidate poses (0.1 degree azimuths);
* :func:`case_task` runs one case end to end -- Blender render of the panorama or the NavCam
  frames at the hidden pose, panorama building, skyline detection, matching -- and writes the
  case's folder and its ``row.json`` last (atomically), so a case with a row is finished.

A worker keeps one Blender :class:`~blender_addon.sim.Simulator` per site (the terrain is
built in Blender once per worker process).  Workers must run one thread each (bpy is not
thread-safe).  Coordinates are metres in the DEM's metric CRS, angles degrees.
"""
from __future__ import annotations

import json
import logging
import os
import shutil
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from board.atomic import atomic_dir, publish_dir
from board.errors import SkylocError

log = logging.getLogger(__name__)

#: Azimuths of the true horizon (0.1 degree).
TRUTH_N_AZIMUTH = 3600


@dataclass(frozen=True)
class CampaignContext:
    """What every case task needs to know about the campaign (all picklable)."""

    out_dir: str
    dem_path: str
    dem_spec: str
    body: str
    site_xy: tuple[float, float]
    sim_half_m: float
    db_path: str
    terrain_dir: str
    profile: dict
    n_azimuth: int
    camera_height_m: float
    large_db_path: str = ""


def terrain_task(dem_path: str, center_xy: tuple[float, float], size_m: float, step_m: float,
                 n_azimuth: int, camera_height_m: float, out_dir: str) -> str:
    """Build (once) the ray-marcher's terrain for a grid of ``size_m`` around ``center_xy``."""
    from render_service.dbrender import load_terrain, prepare_job  # noqa: PLC0415
    from render_service.renderers.base import RenderSpec  # noqa: PLC0415

    out = Path(out_dir)
    if (out / "terrain.json").is_file():
        return str(out)
    spec = RenderSpec(camera_height_m=camera_height_m, n_azimuth=int(n_azimuth))
    job = prepare_job(dem_path, center_xy=center_xy, size_m=size_m, step_m=step_m, spec=spec)
    tmp = out.with_name(out.name + f".tmp-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    load_terrain(job, terrain_dir=tmp)
    publish_dir(tmp, out)
    return str(out)


def db_tile_task(db_path: str, terrain_dir: str, tile, spec) -> bool:
    """Render one database tile unless it is written already; True if rendered here."""
    from render_service.dbrender import render_and_write_tile  # noqa: PLC0415
    from render_service.workers import worker_terrain  # noqa: PLC0415

    return render_and_write_tile(db_path, worker_terrain(terrain_dir), tile, spec)


def truth_task(terrain_dir: str, xy: list[tuple[float, float]], camera_height_m: float,
               body_radius_m: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """The exact horizon (elevation, distance; ``TRUTH_N_AZIMUTH`` azimuths from north) at each (x, y)."""
    from render_service.renderers.base import RenderSpec  # noqa: PLC0415
    from render_service.renderers.raymarch import horizon_at  # noqa: PLC0415
    from render_service.workers import worker_terrain  # noqa: PLC0415

    terrain = worker_terrain(terrain_dir)
    spec = RenderSpec(camera_height_m=camera_height_m, n_azimuth=TRUTH_N_AZIMUTH, body_radius_m=body_radius_m)
    out = []
    for x, y in xy:
        _, el, dist = horizon_at(terrain, float(x), float(y), spec)
        out.append((el.astype(np.float32), dist.astype(np.float32)))
    return out


# --------------------------------------------------------------------------------------------
# Blender side (one Simulator per worker and site)
# --------------------------------------------------------------------------------------------
_SIMULATORS: dict[tuple, object] = {}


def _simulator(ctx: CampaignContext):
    from blender_addon.sim import Simulator  # noqa: PLC0415

    key = (ctx.dem_path, ctx.site_xy, ctx.sim_half_m)
    sim = _SIMULATORS.get(key)
    if sim is None:
        _SIMULATORS.clear()
        sim = Simulator(ctx.dem_path, ctx.site_xy, grid_half_m=ctx.sim_half_m, body=ctx.body)
        _SIMULATORS[key] = sim
    return sim


def _degradation(preset: str, cand: dict, body: str):
    """The preset's look on ``body`` (realistic and distorted take the body's sky, sunlight and regolith:
    :func:`blender_addon.core.degrade.look_on_body`) with this pose's sun (absolute azimuth, degrees)."""
    from blender_addon.core.degrade import look_on_body  # noqa: PLC0415

    deg = look_on_body(preset, body)
    if deg.binary:
        return deg
    return replace(deg, sun=replace(deg.sun, azimuth_deg=float(cand["sun_azimuth_deg"]),
                                    elevation_deg=float(cand["sun_elevation_deg"]), relative=False))


def render_panorama_case(ctx: CampaignContext, case: dict, cand: dict, pitch: float, roll: float,
                         out: Path) -> float:
    """Render the case's equirectangular panorama into ``out``; returns the render time (s)."""
    from blender_addon.core.acquire import Pose  # noqa: PLC0415
    from blender_addon.scene.panorama import make_panorama  # noqa: PLC0415

    sim = _simulator(ctx)
    sim.ensure_scene()
    p = ctx.profile
    deg = _degradation(case["preset"], cand, ctx.body)
    t0 = time.perf_counter()
    make_panorama(sim.terrain, Pose(cand["x"], cand["y"], cand["heading_deg"], pitch, roll), out,
                  height_m=ctx.camera_height_m, width=int(p["pano_width"]), binary=deg.binary,
                  preset=None if deg.binary else deg, seed=int(cand["texture_seed"]), samples=int(p["samples"]),
                  dem=ctx.dem_spec, build=False,
                  elevation_range_deg=tuple(p["pano_band_deg"]))
    return time.perf_counter() - t0


def render_acquisition_case(ctx: CampaignContext, case: dict, cand: dict, pitch: float, roll: float,
                            out: Path) -> float:
    """Render the case's NavCam pan-tilt acquisition into ``out``; returns the render time (s)."""
    from blender_addon.core.acquire import AcquisitionJob, Pose  # noqa: PLC0415
    from blender_addon.core.cameras import get_preset  # noqa: PLC0415
    from blender_addon.core.plans import plan_frames  # noqa: PLC0415

    sim = _simulator(ctx)
    p = ctx.profile
    cam = get_preset(p["camera"], width=int(p["camera_width"]), mast_height_m=ctx.camera_height_m)
    plan = plan_frames(int(p["frames"]), 360.0, cam.hfov_deg)
    job = AcquisitionJob(Pose(cand["x"], cand["y"], cand["heading_deg"], pitch, roll), cam, plan,
                         _degradation(case["preset"], cand, ctx.body), seed=int(cand["texture_seed"]),
                         samples=int(p["samples"]))
    t0 = time.perf_counter()
    sim.acquire(job, out)
    return time.perf_counter() - t0


# --------------------------------------------------------------------------------------------
# the case task
# --------------------------------------------------------------------------------------------
def case_dir(ctx: CampaignContext, case_id: str) -> Path:
    return Path(ctx.out_dir) / "cases" / case_id


def read_row(ctx: CampaignContext, case_id: str) -> dict | None:
    """The finished row of a case, or None when the case has not finished."""
    p = case_dir(ctx, case_id) / "row.json"
    if not p.is_file():
        return None
    try:
        return json.loads(p.read_text())
    except (OSError, ValueError):
        return None


def _write_json_atomic(path: Path, doc) -> None:
    from board.atomic import write_text_atomic  # noqa: PLC0415

    write_text_atomic(path, json.dumps(doc, indent=1, sort_keys=True, default=float))


def case_task(ctx: CampaignContext, case: dict, cand: dict, truth_el: np.ndarray, source_ready=None) -> dict:
    """Run one case end to end and record its row; returns the row (also in ``cases/<id>/row.json``).

    ``source_ready`` is the future of the case whose skyline this one reuses (an ordering
    dependency only).  A stage that fails leaves its reason in the row; only an error of the
    harness itself (a bug, a full disk) raises.
    """
    from render_service.campaign import scoring  # noqa: PLC0415

    done = read_row(ctx, case["case_id"])
    if done is not None:
        return done
    folder = case_dir(ctx, case["case_id"])
    folder.mkdir(parents=True, exist_ok=True)
    t_case = time.perf_counter()
    stage = scoring.CaseOutcome(case=case, cand=cand)
    try:
        _run_case(ctx, case, cand, folder, stage)
    except SkylocError as exc:  # a stage refused its input: a result, not a harness error
        stage.reason = stage.reason or f"{stage.stage}: {exc}"
        log.info("case %s: %s", case["case_id"], stage.reason)
    row = scoring.make_row(ctx, stage, np.asarray(truth_el, dtype=np.float64))
    row["case_s"] = round(time.perf_counter() - t_case, 3)
    scoring.save_case_arrays(folder, stage)
    _write_json_atomic(folder / "row.json", row)
    return row


def _run_case(ctx: CampaignContext, case: dict, cand: dict, folder: Path, st) -> None:
    from board.extraction import extract_from_acquisition, extract_from_panorama  # noqa: PLC0415
    from board.skyline import Skyline  # noqa: PLC0415
    from render_service.campaign import scoring  # noqa: PLC0415
    from render_service.campaign.planning import Candidate, Case, prior_of, tilt_of  # noqa: PLC0415
    from render_service.campaign.profiles import Profile  # noqa: PLC0415

    c = Case(**case)
    cd = Candidate(**cand)
    prof = Profile(**{k: tuple(v) if isinstance(v, list) else v for k, v in ctx.profile.items()})
    pitch, roll = tilt_of(c, cd, prof)
    st.pitch_deg, st.roll_deg = pitch, roll
    kind = c.kind
    if kind in ("panorama", "acquisition"):
        st.stage = "render"
        product = folder / ("panorama" if kind == "panorama" else "acquisition")
        if not (product / ("panorama.json" if kind == "panorama" else "acquisition.json")).is_file():
            render = render_panorama_case if kind == "panorama" else render_acquisition_case
            st.render_s = render(ctx, case, cand, pitch, roll, product)
        st.stage = "extract"
        if kind == "panorama":
            res = extract_from_panorama(product, azimuth_step_deg=360.0 / ctx.n_azimuth, azimuth_start_deg=0.0)
        else:
            res = extract_from_acquisition(product, azimuth_step_deg=360.0 / ctx.n_azimuth, azimuth_start_deg=0.0)
        st.extract_status, st.extract_s = res.status, res.elapsed_s
        st.levelled = kind == "acquisition"
        if res.panorama is not None:
            st.view = scoring.view_limits(res.panorama, ctx.n_azimuth)
        if res.skyline is None:
            st.reason = f"extract: {res.reason}"
            return
        res.skyline.save(folder / "skyline.json")
        st.skyline = res.skyline
        st.stage = "locate"
        _locate(ctx, c, cd, prof, st, folder)
    else:
        src = Path(ctx.out_dir) / "cases" / c.source
        src_row = json.loads((src / "row.json").read_text()) if (src / "row.json").is_file() else None
        st.extract_status = src_row.get("extract_status", "") if src_row else ""
        st.extract_s = float(src_row.get("extract_s") or 0.0) if src_row else 0.0
        if not (src / "skyline.json").is_file():
            st.reason = f"extract: no skyline from {c.source}" + (f" ({src_row.get('reason')})" if src_row else "")
            return
        st.skyline = Skyline.load(src / "skyline.json")
        st.stage = "window database" if kind == "window" else "locate"
        st.prior = prior_of(c, cd, prof)
        _locate(ctx, c, cd, prof, st, folder)


def _locate(ctx: CampaignContext, c, cd, prof, st, folder: Path) -> None:
    from board.locate import locate  # noqa: PLC0415

    t0 = time.perf_counter()
    if c.kind == "window":
        db = _window_db(ctx, folder, st.prior[:2], prof)
        t0 = time.perf_counter()
        fix = locate(db, st.skyline, mode="lost")
        fix.mode = "window"
    elif c.kind == "lost_large":
        fix = locate(ctx.large_db_path, st.skyline, mode="lost")
    elif c.kind == "heading":
        hp = cd.heading_deg + cd.heading_prior_offset_deg * prof.heading_window_deg
        st.heading_prior_deg = hp
        fix = locate(ctx.db_path, st.skyline, mode="heading", prior_xy=st.prior[:2], heading_prior_deg=hp,
                     heading_window_deg=prof.heading_window_deg)
    else:
        fix = locate(ctx.db_path, st.skyline, mode="lost")
    st.locate_s = time.perf_counter() - t0
    st.fix = fix
    if fix_pictures(fix, "score_map") is not None:
        try:
            from board.plots import plot_fix  # noqa: PLC0415

            plot_fix(fix, folder / "locate.png", truth=(cd.x, cd.y))
        except ImportError:  # matplotlib missing: no picture, same numbers
            pass
        except Exception as exc:  # a picture must not lose the case's numbers: say it in the row
            log.warning("case %s: score-map picture failed: %s", c.case_id, exc)
            st.picture_error = f"{type(exc).__name__}: {exc}"


def _window_db(ctx: CampaignContext, folder: Path, prior_xy, prof):
    """The table-7 window database (``window_m`` at ``window_step_m``) centred on the prior."""
    from board.skydb import SkyDB, SkyDBWriter  # noqa: PLC0415
    from render_service.dbrender import prepare_job, render_and_write_tile  # noqa: PLC0415
    from render_service.renderers.base import RenderSpec  # noqa: PLC0415
    from render_service.workers import worker_terrain  # noqa: PLC0415

    path = folder / "window.zarr"
    if path.exists():
        try:
            db = SkyDB.open(path)
            if db.complete:
                return db
        except SkylocError:
            pass
        shutil.rmtree(path, ignore_errors=True)
    spec = RenderSpec(camera_height_m=ctx.camera_height_m, n_azimuth=ctx.n_azimuth,
                      azimuth_subsamples=int(prof.db_azimuth_subsamples))
    job = prepare_job(ctx.dem_path, center_xy=(float(prior_xy[0]), float(prior_xy[1])), size_m=prof.window_m,
                      step_m=prof.window_step_m, spec=spec, tile_size=64, body=ctx.body, what="the window",
                      elevation_unit_deg=prof.db_elevation_unit_deg)
    terrain = worker_terrain(ctx.terrain_dir)
    with atomic_dir(path, suffix=".zarr") as tmp:
        w = SkyDBWriter.create(tmp, job.meta, overwrite=True)   # the new, empty folder
        for tile in w.pending_tiles():
            render_and_write_tile(tmp, terrain, tile, job.spec, writer=w)
        w.finalize()
    return SkyDB.open(path)


def fix_pictures(fix, name: str):
    """A picture payload of a Fix (``fix.pictures.<name>``; older Fix objects held them directly)."""
    pics = getattr(fix, "pictures", None)
    return getattr(pics if pics is not None else fix, name, None)
