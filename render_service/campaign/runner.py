"""The campaign's stages, from the DEM to results.csv, summary.json and report.html.

1. the DEM (a file, or ``procedural:PRESET:SEED`` synthesised at the profile's size) and the site,
   drawn from the seed;
2. on Dask: the ray-marcher's terrains (database and truth), the lost-in-space database tile by
   tile (a tile is never rendered twice), and the exact horizon at candidate poses; candidates
   whose horizon has less than ``min_relief_deg`` of relief are rejected and listed;
3. on Dask: every case (render, extract, locate), each writing its row when it finishes;
4. the database floor: each pose's true horizon located against the database (:mod:`.floor`), written
   beside every case located against it, so that a miss says whether the site and the database or the
   image chain caused it;
5. the rows gathered into results.csv, aggregated into summary.json, drawn into report.html.

Killed at any point and run again with the same arguments, a campaign recomputes nothing that
finished: the database resumes, rows on disk are kept, the poses are the same (drawn from the
seed), and the outputs are rebuilt from the rows.  Only time columns differ from an uninterrupted run.
Run again with more poses or acquisitions, it grows: the first poses and their finished cases are
kept and only the new ones run (``GROWABLE_FIELDS``).
"""
from __future__ import annotations

import csv
import json
import logging
import math
import os
import platform
import resource
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from board.atomic import atomic_path, write_text_atomic
from board.errors import InvalidInputError, SkylocError
from board.skydb import LEGACY_ELEVATION_SCALE_DEG
from render_service.campaign import planning, scoring
from render_service.campaign import summary as summ
from render_service.campaign.floor import floor_summary
from render_service.campaign.profiles import Profile, get_profile
from render_service.campaign.tasks import TRUTH_N_AZIMUTH, CampaignContext

log = logging.getLogger(__name__)

CAMPAIGN_VERSION = 1
#: Candidates whose truth is ray-marched per task.
TRUTH_BATCH = 8
#: Candidates tried per accepted pose before the campaign gives up on a site.
MAX_CANDIDATES_PER_POSE = 10


class HarnessError(SkylocError):
    """The harness itself failed (not a bad fix: that is a result)."""


@dataclass
class CampaignOptions:
    """Arguments of ``skyloc campaign`` (metres, degrees).

    dem : a DEM file or ``procedural:PRESET:SEED`` (sized by the profile)
    scheduler : Dask scheduler address; None starts a LocalCluster of ``workers`` processes
    overrides : profile fields to change (e.g. ``{"n_poses": 10}``)
    """

    out: Path
    dem: str = "procedural:mars:7"
    profile: str = "ci"
    seed: int = 0
    scheduler: str | None = None
    workers: int = 2
    body: str | None = None
    min_relief_deg: float | None = None
    overrides: dict = field(default_factory=dict)
    progress: bool = True
    say: object = None  # callable(str) for the terminal lines; None: print to stdout
    security: object = None  # distributed.security.Security for --scheduler (None: generated / Dask config)
    #: case-id globs (``fnmatch``, e.g. ``t6-*-pitch-*``): run only the matching cases (and the unfinished cases
    #: whose skyline they reuse); the others stay unfinished for a later run.  Empty: every case.
    only: tuple[str, ...] = ()


def _say_default(msg: str) -> None:
    sys.stdout.write(msg + "\n")
    sys.stdout.flush()


def _dem_spec(dem: str, profile: Profile) -> str:
    """A procedural spec sized by the profile (``procedural:mars:7`` -> ``procedural:mars:7:SIZE:RES``)."""
    s = str(dem)
    if s.startswith("procedural:") and len(s.split(":")) == 3:
        return f"{s}:{profile.procedural_size_m:g}:{profile.procedural_res_m:g}"
    return s


def _write_json(path: Path, doc) -> None:
    write_text_atomic(path, json.dumps(doc, indent=2, sort_keys=True, default=_json_default))


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(type(o).__name__)


#: what a campaign started before a profile field existed ran with, where that is not the field's default:
#: its databases were stored in the legacy 0.01-degree units, with point samples
LEGACY_PROFILE_VALUES = {"db_elevation_unit_deg": LEGACY_ELEVATION_SCALE_DEG, "db_azimuth_subsamples": 1}


def _with_profile_defaults(args: dict) -> dict:
    """``args`` of an earlier campaign.json with the profile fields added since at what it ran with (the
    field's default, or LEGACY_PROFILE_VALUES): a campaign started before a field existed resumes when
    run as it was, and is refused with the field named when the new default would change it."""
    from dataclasses import MISSING, fields  # noqa: PLC0415

    from render_service.campaign.profiles import Profile  # noqa: PLC0415

    prof = args.get("profile")
    if not isinstance(prof, dict):
        return args
    defaults = {f.name: LEGACY_PROFILE_VALUES.get(f.name, f.default) for f in fields(Profile)
                if f.default is not MISSING and f.name not in prof}
    return {**args, "profile": {**prof, **json.loads(json.dumps(defaults, default=_json_default))}}


#: profile fields a resumed campaign may raise: its first poses, acquisitions and window / heading poses are
#: drawn and planned the same whatever the counts, so their finished rows are kept and only the new ones run
GROWABLE_FIELDS = ("n_poses", "n_acquisitions", "n_window_poses", "n_heading_poses")


def _growth(prev: dict, args: dict) -> dict[str, tuple[int, int]] | None:
    """``{field: (before, now)}`` when ``args`` differ from ``prev`` only by growable counts (any of them may be
    lower: the caller refuses that), else None."""
    a, b = prev.get("profile"), args.get("profile")
    if not (isinstance(a, dict) and isinstance(b, dict)):
        return None
    if {k: v for k, v in prev.items() if k != "profile"} != {k: v for k, v in args.items() if k != "profile"}:
        return None
    diff = {k for k in set(a) | set(b) if a.get(k) != b.get(k)}
    if not diff or not diff <= set(GROWABLE_FIELDS) or not all(isinstance(a.get(k), int) and isinstance(b.get(k), int)
                                                                 for k in diff):
        return None
    return {k: (a[k], b[k]) for k in sorted(diff)}


def _check_arguments(out: Path, args: dict) -> dict[str, tuple[int, int]]:
    """Refuse to resume a campaign of other arguments into the same folder.

    Returns the counts a resume raises (``{field: (before, now)}``, empty when the arguments are the same):
    a campaign grows by more poses or acquisitions (``--poses 30`` on a folder of 10), and campaign.json
    takes the new counts once the new poses are drawn (``_record_growth``).  Lower counts are refused."""
    p = out / "campaign.json"
    if p.is_file():
        old = json.loads(p.read_text())
        prev = _with_profile_defaults(old.get("arguments", {}))
        if prev != args:
            grown = _growth(prev, args)
            if grown is not None:
                fewer = {k: v for k, v in grown.items() if v[1] < v[0]}
                if not fewer:
                    return grown
                raise InvalidInputError(
                    f"{out} holds a campaign of more cases than asked ("
                    + ", ".join(f"{k} {b} < {a}" for k, (a, b) in fewer.items())
                    + "): a resume can add poses and acquisitions but not drop them; give at least the counts it "
                      "ran with, or use another --out")
            diff = sorted(k for k in set(prev) | set(args) if prev.get(k) != args.get(k))
            if "profile" in diff and isinstance(prev.get("profile"), dict) and isinstance(args.get("profile"), dict):
                a, b = prev["profile"], args["profile"]
                diff[diff.index("profile")] = "profile: " + ", ".join(sorted(k for k in set(a) | set(b)
                                                                              if a.get(k) != b.get(k)))
            raise InvalidInputError(f"{out} holds a campaign run with other arguments ({', '.join(diff)} differ): "
                                    "use another --out, or the same arguments to resume it (more poses or "
                                    "acquisitions grow it)")
    else:
        out.mkdir(parents=True, exist_ok=True)
        _write_json(p, {"format": "skyloc-campaign", "version": CAMPAIGN_VERSION, "arguments": args})
    return {}


def _record_growth(out: Path, args: dict, grown: dict[str, tuple[int, int]]) -> None:
    """campaign.json takes the grown counts (the arguments a later resume must give), with its history."""
    p = out / "campaign.json"
    doc = json.loads(p.read_text())
    doc["arguments"] = args
    doc.setdefault("grown", []).append({"utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                                        **{k: {"before": a, "now": b} for k, (a, b) in grown.items()}})
    _write_json(p, doc)


def _forget_refused(out: Path, out_existed: bool, fresh: bool) -> None:
    """Remove what a campaign refused before its first render wrote: the folder if this run made it,
    else the ``campaign.json`` it started (a refused run leaves nothing half-written behind)."""
    if not fresh:
        return
    if not out_existed:
        shutil.rmtree(out, ignore_errors=True)
    else:
        (out / "campaign.json").unlink(missing_ok=True)


def run_campaign(opt: CampaignOptions) -> dict:
    """Run (or resume) a campaign; returns the summary (also written to ``summary.json``).

    Raises InvalidInputError for bad arguments and HarnessError when cases crashed the harness
    (their rows are missing; running again retries them).
    """
    say = opt.say or _say_default
    if logging.getLogger().level > logging.DEBUG:  # Dask's INFO lines would drown the progress bars
        for name in ("distributed", "distributed.scheduler", "distributed.nanny", "distributed.core",
                     "distributed.worker", "distributed.http.proxy"):
            logging.getLogger(name).setLevel(logging.WARNING)
        # closing a cluster whose workers hold Blender logs broken-stream tracebacks and slow-exit warnings:
        # noise for a user (the cases' own failures reach the harness through their futures)
        for name in ("distributed.batched", "distributed.comm", "distributed.nanny"):
            logging.getLogger(name).setLevel(logging.CRITICAL)
    t_wall, cpu0 = time.perf_counter(), time.process_time()
    ov = dict(opt.overrides)
    if opt.min_relief_deg is not None:
        ov["min_relief_deg"] = float(opt.min_relief_deg)
    profile = get_profile(opt.profile, **ov)
    out = Path(opt.out).resolve()
    args = {"dem": str(opt.dem), "profile": profile.to_dict(), "seed": int(opt.seed), "body": opt.body}
    out_existed, fresh = out.exists(), not (out / "campaign.json").exists()
    args = json.loads(json.dumps(args, default=_json_default))
    grown = _check_arguments(out, args)
    try:
        select_cases(planning.plan_cases(profile, profile.n_poses), opt.only)  # a bad --only fails before any work
        from blender_addon.terrain.dem import dem_info, resolve_dem  # noqa: PLC0415

        spec = _dem_spec(opt.dem, profile)
        dem_path = resolve_dem(spec, cache_dir=out / "dem")
        info = dem_info(dem_path, body=opt.body)
        say(f"campaign {profile.name}: DEM {spec} ({info.body.name}, {info.size[0]} x {info.size[1]} cells of "
            f"{info.cell_m:g} m, sha256 {info.sha256[:12]}), seed {opt.seed} -> {out}")
        site = planning.choose_site(profile, info.bounds,
                                    np.random.default_rng(np.random.SeedSequence([int(opt.seed) & 0xFFFFFFFF, 0x5173])),
                                    area_m=max(profile.area_m, profile.large_area_m))
    except Exception:
        _forget_refused(out, out_existed, fresh)
        raise
    site = planning.Site(site.center_x, site.center_y, profile.area_m, site.step_m, site.dem_bounds)
    say(f"  site: {profile.area_m:g} x {profile.area_m:g} m at {profile.step_m:g} m centred on "
        f"({site.center_x:.1f}, {site.center_y:.1f}) (metres, the DEM's metric CRS)")

    from render_service.engine import dask_client  # noqa: PLC0415
    from render_service.workers import TerrainPlugin  # noqa: PLC0415

    harness_errors: list[str] = []
    mem_workers_mb: list[float] = []
    cpu_workers_s = 0.0
    with dask_client(opt.scheduler, n_workers=opt.workers, threads_per_worker=1, security=opt.security) as client:
        n_w = max(1, len(client.scheduler_info(n_workers=-1)["workers"]) if opt.scheduler else opt.workers)
        client.register_plugin(TerrainPlugin(numba_threads=max(1, (os.cpu_count() or 1) // n_w)))
        ctx, db = _prepare(client, opt, profile, out, dem_path, spec, info, site, say)
        poses, truths = _poses(client, opt, profile, out, site, ctx, say)
        if grown:
            _record_growth(out, args, grown)
            say("  grown: " + ", ".join(f"{k} {a} -> {b}" for k, (a, b) in grown.items())
                + " (the finished cases of the first ones are kept)")
        cases = planning.plan_cases(profile, len(poses))
        selected = select_cases(cases, opt.only)
        if len(selected) < len(cases):
            names = ", ".join(c.case_id for c in selected[:12]) + (", ..." if len(selected) > 12 else "")
            say(f"  --only {' '.join(opt.only)}: {len(selected)} of {len(cases)} cases selected ({names}; the others "
                "are left as they are: run again without --only to finish them)")
        harness_errors = _run_cases(client, ctx, selected, poses, truths, opt, say)
        extra_rows: list[dict] = []
        if profile.robustness and _only_may_match_robustness(opt.only):
            from render_service.campaign.robustness import run_robustness  # noqa: PLC0415

            extra_rows, errs = run_robustness(client, ctx, profile, out, opt, say, _render_db)
            harness_errors += errs
        elif profile.robustness:  # --only names no robustness case: its finished rows are still results
            from render_service.campaign.tasks import read_row  # noqa: PLC0415

            extra_rows = [r for r in (read_row(ctx, d.name) for d in sorted((out / "cases").glob("r-*")))
                          if r is not None]
            say(f"  robustness sets not run (--only): {len(extra_rows)} finished rows kept")
        try:
            stats = client.run(_worker_usage)
            mem_workers_mb = [v[0] for v in stats.values()]
            cpu_workers_s = float(sum(v[1] for v in stats.values()))
        except Exception as exc:  # accounting only
            log.debug("worker usage unavailable: %s", exc)

    rows = _gather_rows(ctx, cases) + extra_rows
    floor = _database_floor(out, say)
    scoring.add_floor(rows, floor)
    _write_results(out / "results.csv", rows)
    summary = summ.summarise(rows)
    summary.update({
        "floor": floor_summary(floor),
        "campaign": {"profile": profile.name, "seed": int(opt.seed), "dem": spec, "dem_sha256": info.sha256,
                     "body": info.body.name, "site": site.to_dict(), "poses": len(poses),
                     "rejected_poses": json.loads((out / "poses.json").read_text()).get("rejected", []),
                     "cases": len(cases) + len(extra_rows), "rows": len(rows), "harness_errors": harness_errors,
                     "database": db.summary() if hasattr(db, "summary") else {}},
        "run": {"wall_s": round(time.perf_counter() - t_wall, 1),
                "cpu_s_main": round(time.process_time() - cpu0, 1), "cpu_s_workers": round(cpu_workers_s, 1),
                "peak_rss_mb_main": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
                "peak_rss_mb_workers": [round(v, 1) for v in mem_workers_mb],
                "machine": platform.node(), "cpus": os.cpu_count(), "load_avg": os.getloadavg()[0],
                "versions": _versions(), "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())},
    })
    _write_json(out / "summary.json", summary)
    write_text_atomic(out / "summary.md", summ.markdown(summary))
    try:
        from render_service.campaign.report_html import write_report  # noqa: PLC0415

        write_report(out, rows, summary, ctx, truths)
    except ImportError as exc:  # matplotlib missing: the numbers are still written
        say(f"  report.html skipped ({exc})")
    for line in screen_summary(summary):
        say(line)
    if harness_errors:
        raise HarnessError(f"{len(harness_errors)} case(s) crashed the harness (first: {harness_errors[0]}); "
                           "their rows are missing: fix the cause and run the same command again to finish")
    return summary


def _worker_usage() -> tuple[float, float]:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_maxrss / 1024.0, ru.ru_utime + ru.ru_stime


def _versions() -> dict:
    from importlib.metadata import PackageNotFoundError, version  # noqa: PLC0415

    out = {"python": platform.python_version()}
    for pkg in ("skyloc", "numpy", "bpy", "dask", "distributed", "opencv-python-headless"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            pass
    try:
        from render_service.dbrender import renderer_version  # noqa: PLC0415

        out["raymarch"] = renderer_version("raymarch")
    except Exception:  # informational
        pass
    return out


def _prepare(client, opt, profile: Profile, out: Path, dem_path: Path, spec: str, info, site, say):
    """Terrains (the database's and the 0.1-degree truth's) and the lost-in-space database(s), on Dask."""
    from board.conventions import body_from_name  # noqa: PLC0415
    from board.skydb import SkyDB  # noqa: PLC0415
    from render_service.campaign.tasks import terrain_task  # noqa: PLC0415

    h = profile.camera_height_m
    center = (site.center_x, site.center_y)
    tdir, truth_dir = out / "terrain" / "db", out / "terrain" / "truth"
    (out / "terrain").mkdir(parents=True, exist_ok=True)
    f_tr = client.submit(terrain_task, str(dem_path), center, profile.area_m, profile.step_m, TRUTH_N_AZIMUTH, h,
                         str(truth_dir), pure=False)
    db_path = _render_db(client, opt, out / "db.zarr", tdir, dem_path, spec, center, profile.area_m, profile.step_m,
                         h, say, profile.db_elevation_unit_deg, profile.db_azimuth_subsamples)
    f_tr.result()
    large = ""
    if profile.large_area_m > 0:
        large = str(_render_db(client, opt, out / "db_large.zarr", out / "terrain" / "db_large", dem_path, spec,
                               center, profile.large_area_m, profile.step_m, h, say, profile.db_elevation_unit_deg,
                               profile.db_azimuth_subsamples))
    body = body_from_name(opt.body) if opt.body else info.body
    ctx = CampaignContext(out_dir=str(out), dem_path=str(dem_path), dem_spec=spec, body=body.name,
                          site_xy=center, sim_half_m=profile.area_m / 2, db_path=str(db_path),
                          terrain_dir=str(tdir), profile=profile.to_dict(), n_azimuth=360,
                          camera_height_m=h, large_db_path=large)
    return ctx, SkyDB.open(db_path)


def _render_db(client, opt, db_path: Path, tdir: Path, dem_path: Path, spec: str, center, size_m: float,
               step_m: float, h: float, say, unit_deg: float | None = None, subsamples: int = 1) -> Path:
    """A lost-in-space database of ``size_m`` (terrain and tiles on Dask, resumed tile by tile), its
    elevations in int16 units of ``unit_deg`` degrees (None: board.skydb.ELEVATION_SCALE_DEG), each sample
    the mean of ``subsamples`` rays across its azimuth step (1: point samples)."""
    from board.skydb import SkyDBWriter  # noqa: PLC0415
    from render_service.campaign.tasks import db_tile_task, terrain_task  # noqa: PLC0415
    from render_service.dbrender import prepare_job  # noqa: PLC0415
    from render_service.renderers.base import RenderSpec  # noqa: PLC0415

    t0 = time.perf_counter()
    client.submit(terrain_task, str(dem_path), center, size_m, step_m, 360, h, str(tdir), pure=False).result()
    job = prepare_job(dem_path, center_xy=center, size_m=size_m, step_m=step_m,
                      spec=RenderSpec(camera_height_m=h, n_azimuth=360, azimuth_subsamples=int(subsamples)),
                      body=opt.body,
                      elevation_unit_deg=unit_deg)
    job.meta.extra.pop("dem_path", None)
    job.meta.extra["dem"] = spec
    writer = SkyDBWriter.create(db_path, job.meta)
    pending = writer.pending_tiles()
    if pending:
        futs = client.map(db_tile_task, [str(db_path)] * len(pending), [str(tdir)] * len(pending), pending,
                          [job.spec] * len(pending), pure=False)
        _progress(client, futs, f"{db_path.name} ({len(writer.tiles)} tiles)", opt.progress,
                  initial=len(writer.tiles) - len(pending), total=len(writer.tiles))
        for f in futs:
            f.result()
    writer.finalize()
    say(f"  database {db_path.name}: {job.grid.nx} x {job.grid.ny} positions, {len(pending)} tiles rendered now, "
        f"{time.perf_counter() - t0:.1f} s")
    return db_path


def _database_floor(out: Path, say) -> list[dict]:
    """Each accepted pose's true horizon located against the campaign's database (:mod:`.floor`), in the
    order of ``poses.json``; [] (said) when it cannot be: the rows then keep empty floor cells."""
    from render_service.campaign.floor import floor_rows  # noqa: PLC0415

    t0 = time.perf_counter()
    try:
        rows = floor_rows(out)
    except Exception as exc:  # accounting beside the cases: never worth losing the campaign's outputs
        log.warning("database floor failed", exc_info=True)
        say(f"  database floor not measured ({type(exc).__name__}: {exc})")
        return []
    fs = floor_summary(rows)
    if fs["n"]:
        say(f"  database floor: {fs['n']} true horizon{'s' if fs['n'] != 1 else ''} located against the database in "
            f"{time.perf_counter() - t0:.0f} s: median {fs['error_m_median']:.2f} m, max {fs['error_m_max']:.2f} m, "
            f"{fs['ok']} ok" + (f"; poses limited by the site or the database: {fs['limited_poses']}"
                               if fs["limited_poses"] else ""))
    return rows


def _poses(client, opt, profile: Profile, out: Path, site, ctx, say):
    """Accepted poses (drawn from the seed, horizon relief checked) and their true horizons."""
    from board.conventions import body_from_name  # noqa: PLC0415
    from render_service.campaign.tasks import truth_task  # noqa: PLC0415

    pfile, tfile = out / "poses.json", out / "truth.npz"
    accepted, rejected, truths = [], [], []
    next_i = 0
    if pfile.is_file() and tfile.is_file():
        doc = json.loads(pfile.read_text())
        with np.load(tfile) as z:
            el_before = z["elevation_deg"]
        if doc.get("n_poses") == profile.n_poses:
            return doc["accepted"], el_before
        if doc.get("truth_n_azimuth") == TRUTH_N_AZIMUTH and (
                doc.get("n_poses", 0) < profile.n_poses or len(doc["accepted"]) >= profile.n_poses):
            # grown (or back to the counts it had before a growth was interrupted): candidates are drawn in
            # index order, each independent of the others, so the first poses are kept and the draw goes on
            # after the last one kept, exactly as a campaign of these counts from scratch would draw
            accepted = doc["accepted"][:profile.n_poses]
            truths = list(el_before[:len(accepted)])
            next_i = accepted[-1]["index"] + 1 if accepted else 0
            rejected = [r for r in doc.get("rejected", []) if r["index"] < next_i]
    radius = body_from_name(ctx.body).radius_m
    limit = MAX_CANDIDATES_PER_POSE * profile.n_poses
    while len(accepted) < profile.n_poses and next_i < limit:
        need = profile.n_poses - len(accepted)
        batch = [planning.draw_candidate(opt.seed, i, site, profile)
                 for i in range(next_i, min(next_i + max(need + 2, TRUTH_BATCH), limit))]
        next_i += len(batch)
        chunks = [batch[i:i + TRUTH_BATCH] for i in range(0, len(batch), TRUTH_BATCH)]
        futs = [client.submit(truth_task, str(out / "terrain" / "truth"), [(c.x, c.y) for c in ch],
                              profile.camera_height_m, radius, pure=False) for ch in chunks]
        for ch, f in zip(chunks, futs):
            for cand, (el, _dist) in zip(ch, f.result()):
                relief = planning.horizon_relief_deg(el)
                if len(accepted) < profile.n_poses and relief >= profile.min_relief_deg:
                    accepted.append(cand.to_dict())
                    truths.append(el)
                elif relief < profile.min_relief_deg:
                    rejected.append({"index": cand.index, "x": cand.x, "y": cand.y, "relief_deg": round(relief, 3),
                                     "reason": f"true horizon relief {relief:.2f} deg < --min-relief-deg "
                                               f"{profile.min_relief_deg:g}"})
    if not accepted:
        raise InvalidInputError(f"no pose of the {profile.area_m:g} m area centred on ({site.center_x:.0f}, "
                                f"{site.center_y:.0f}) sees a horizon with {profile.min_relief_deg:g} deg of relief "
                                f"({len(rejected)} tried): lower --min-relief-deg or use a rougher DEM")
    if len(accepted) < profile.n_poses:
        say(f"  only {len(accepted)} of {profile.n_poses} poses have {profile.min_relief_deg:g} deg of horizon "
            f"relief after {next_i} candidates: the campaign runs with {len(accepted)}")
    if rejected:
        say(f"  {len(rejected)} candidate pose(s) rejected for a flat horizon (listed in poses.json and summary.json)")
    el = np.stack(truths).astype(np.float32)
    with atomic_path(tfile, suffix=".part.npz") as tmp:
        np.savez_compressed(tmp, elevation_deg=el)
    _write_json(pfile, {"n_poses": profile.n_poses, "accepted": accepted, "rejected": rejected,
                        "truth_n_azimuth": TRUTH_N_AZIMUTH})
    say(f"  {len(accepted)} hidden poses drawn off the grid (true horizon ray-marched at "
        f"{360 / TRUTH_N_AZIMUTH:g} deg)")
    return accepted, el


def select_cases(cases: list, only) -> list:
    """The cases whose id matches one of the globs ``only`` (``fnmatch``, case-sensitive), with the cases whose
    skyline they reuse (``source``), in plan order; every case when ``only`` is empty.

    Raises InvalidInputError naming the glob and a few case ids when a glob matches no case.
    """
    from fnmatch import fnmatchcase  # noqa: PLC0415

    if not only:
        return list(cases)
    ids = [c.case_id for c in cases]
    for g in only:
        if not any(fnmatchcase(i, g) for i in ids):
            shown = ", ".join(ids[:6]) + (f", ... ({len(ids)} cases)" if len(ids) > 6 else "")
            raise InvalidInputError(f"--only {g!r} matches none of this campaign's cases ({shown}); give a glob "
                                    "over case ids such as 't6-*-pitch-*' or 't4-clean-p0[0-4]'")
    keep = {i for i in ids if matches_only(i, only)}
    by_id = {c.case_id: c for c in cases}
    for i in list(keep):
        src = by_id[i].source
        while src and src not in keep:
            keep.add(src)
            src = by_id[src].source
    return [c for c in cases if c.case_id in keep]


def matches_only(case_id: str, only) -> bool:
    """Whether ``case_id`` is selected by the ``--only`` globs ``only`` (``fnmatch``, case-sensitive); True without."""
    from fnmatch import fnmatchcase  # noqa: PLC0415

    return not only or any(fnmatchcase(case_id, g) for g in only)


def _only_may_match_robustness(only) -> bool:
    """Whether the ``--only`` globs can match a robustness case id (``r-SET-NNN``); True without globs."""
    return not only or any(g[:1] in ("r", "*", "?", "[") for g in only)


def _progress(client, futures, desc: str, show: bool, *, initial: int = 0, total: int | None = None):
    from distributed import as_completed  # noqa: PLC0415
    from tqdm import tqdm  # noqa: PLC0415

    with tqdm(total=total or len(futures), initial=initial, desc=desc, disable=not show, dynamic_ncols=True,
              file=sys.stderr, unit="task") as bar:
        for _ in as_completed(futures):
            bar.update(1)


def _run_cases(client, ctx: CampaignContext, cases, poses, truths, opt, say) -> list[str]:
    """Submit every unfinished case (sources before the cases that reuse them); returns harness errors."""
    from distributed import as_completed  # noqa: PLC0415
    from tqdm import tqdm  # noqa: PLC0415

    from render_service.campaign.tasks import case_task, read_row  # noqa: PLC0415

    todo = [c for c in cases if read_row(ctx, c.case_id) is None]
    say(f"  {len(cases)} cases: {len(cases) - len(todo)} finished before, {len(todo)} to run on "
        f"{len(client.scheduler_info(n_workers=-1)['workers'])} Dask worker(s)")
    futures: dict[str, object] = {}
    order = sorted(todo, key=lambda c: (c.source != "", c.table, c.pose))
    for c in order:
        dep = futures.get(c.source) if c.source else None
        # heavy renders first (acquisitions), then panoramas, then the quick window / heading cases
        prio = {"acquisition": 30, "panorama": 20, "window": 10, "lost_large": 5, "heading": 0}[c.kind]
        futures[c.case_id] = client.submit(case_task, ctx, c.to_dict(), poses[c.pose], truths[c.pose], dep,
                                           key=f"case-{c.case_id}-{os.getpid()}", priority=prio, pure=False)
    errors: list[str] = []
    t0 = time.perf_counter()
    by_future = {f: cid for cid, f in futures.items()}
    with tqdm(total=len(cases), initial=len(cases) - len(todo), desc="cases", disable=not opt.progress,
              dynamic_ncols=True, file=sys.stderr, unit="case") as bar:
        for f in as_completed(list(futures.values())):
            cid = by_future[f]
            try:
                row = f.result()
                bar.set_postfix_str(f"{cid}: {row.get('status')} {row.get('error_m') or ''}", refresh=False)
            except Exception as exc:
                errors.append(f"{cid}: {type(exc).__name__}: {exc}")
                log.error("case %s crashed the harness: %s", cid, exc)
            bar.update(1)
    log.info("cases ran in %.1f s", time.perf_counter() - t0)
    return errors


def _gather_rows(ctx: CampaignContext, cases) -> list[dict]:
    from render_service.campaign.tasks import read_row  # noqa: PLC0415

    rows = []
    for c in cases:
        r = read_row(ctx, c.case_id)
        if r is not None:
            rows.append(r)
    return rows


def _write_results(path: Path, rows: list[dict]) -> None:
    with atomic_path(path) as tmp, tmp.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(scoring.COLUMNS), extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow(r)


def _fmt(v, spec: str = ".2f") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return format(v, spec)


def screen_summary(summary: dict) -> list[str]:
    """The one-screen summary printed at the end: one line per group, the report's figures beside."""
    ref4 = summary["reference"]["table4"]
    ref5 = summary["reference"]["table5"]
    lines = ["", f"{'group':<24}{'cases':>6}{'sky':>6}{'kept':>6}{'ext err':>8}{'>1deg':>7}{'med m':>8}"
             f"{'p90 m':>8}{'max m':>9}{'med deg':>8}{'ok':>4}{'amb':>4}{'fail':>5}{'wrong':>6}{'wr ok':>6}  report"]
    for key, g in summary["groups"].items():
        st = g["status"]
        t, preset = key.split("/")[0], key.split("/")[1]
        ref = ""
        if t == "4" and preset in ref4:
            ref = f"median {ref4[preset]['median_m']:.1f} m, max {ref4[preset]['max_m']:.1f} m"
        elif t == "5":
            axis = key.split("/")[2]
            ref = f"binary: median {ref5[axis]['median_m']:.0f} m, max {ref5[axis]['max_heading_deg']:.0f} deg"
        elif t == "6":
            ref = "simulated 0 m, 36.6 s"
        elif t == "7":
            ref = "simulated 0 m, 18.5 s"
        elif t == "8":
            from render_service.campaign.reference import table8_reference  # noqa: PLC0415

            d = float(key.split("/")[2][1:])
            r8 = table8_reference(d)
            ref = "" if r8 is None else f"heading error {r8:.0f} deg"
        lines.append(
            f"{key:<24}{g['cases']:>6}{_fmt(g['skyline_returned'], '.0%'):>6}"
            f"{_fmt(g['kept_fraction']['median'], '.0%'):>6}{_fmt(g['extract_median_abs_err_deg']['median']):>8}"
            f"{_fmt(g['kept_samples_gt1deg_share'], '.1%'):>7}{_fmt(g['error_m']['median']):>8}"
            f"{_fmt(g['error_m']['p90']):>8}{_fmt(g['error_m']['max'], '.1f'):>9}"
            f"{_fmt(g['heading_error_deg']['median']):>8}{st.get('ok', 0):>4}{st.get('ambiguous', 0):>4}"
            f"{st.get('failed', 0):>5}{g['wrong']:>6}{g['wrong_ok']:>6}  {ref}")
    fl = summary.get("floor") or {}
    if fl.get("n"):
        lines.append(f"database floor (true horizons located): median {fl['error_m_median']:.2f} m, max "
                     f"{fl['error_m_max']:.2f} m, {fl['ok']} of {fl['n']} ok"
                     + (f"; limited poses {fl['limited_poses']}" if fl["limited_poses"] else ""))
    c, r = summary["campaign"], summary["run"]
    lines.append(f"{c['rows']} of {c['cases']} cases, {c['poses']} poses ({len(c['rejected_poses'])} rejected), "
                 f"wall {r['wall_s']:.0f} s, CPU {r['cpu_s_main'] + r['cpu_s_workers']:.0f} s; "
                 "sky = skyline returned, kept = kept/seen azimuths, ext err = median |extracted - true| (deg), "
                 "wrong = > 25 m or > 2 deg, wr ok = wrong fixes reported ok")
    return lines
