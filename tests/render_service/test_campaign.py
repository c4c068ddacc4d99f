"""``skyloc campaign``: planning from the seed, scoring against the truth, and the whole chain on Dask + Blender.

The end-to-end tests run a reduced ``ci`` profile on a small procedural site (real Blender renders,
real Dask LocalCluster, real extraction and matching) and check that the rows are consistent with
the manifests the simulator wrote, not that the numbers are good.  The resume test kills a run
with SIGKILL and checks that the resumed run equals an uninterrupted one and recomputed nothing.
"""
from __future__ import annotations

import csv
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from board.errors import InvalidInputError
from render_service.campaign import planning, scoring, summary
from render_service.campaign.profiles import get_profile, parse_setting

# --------------------------------------------------------------------------------------------
# planning (no Dask, no Blender)
# --------------------------------------------------------------------------------------------


def _site(profile, bounds=(0.0, 0.0, 8000.0, 8000.0), seed=3):
    return planning.choose_site(profile, bounds, np.random.default_rng(seed))


def test_poses_are_off_the_grid_inside_the_area_and_seeded():
    prof = get_profile("ci")
    site = _site(prof)
    cands = [planning.draw_candidate(11, i, site, prof) for i in range(400)]
    half = planning.pose_half_m(prof)
    for c in cands:
        # brute force: distance to every node line of the grid, in steps
        nodes = site.center_x + np.arange(-60, 61) * site.step_m
        dx = np.min(np.abs(c.x - nodes)) / site.step_m
        nodes_y = site.center_y + np.arange(-60, 61) * site.step_m
        dy = np.min(np.abs(c.y - nodes_y)) / site.step_m
        assert min(dx, dy) >= planning.OFF_GRID_MARGIN - 1e-9
        assert abs(c.x - site.center_x) <= half + site.step_m and abs(c.y - site.center_y) <= half + site.step_m
        assert 0 <= c.heading_deg < 360 and planning.SUN_ELEVATION_DEG[0] <= c.sun_elevation_deg <= 60
    # the i-th candidate does not depend on the others, and another seed draws other poses
    assert planning.draw_candidate(11, 250, site, prof) == cands[250]
    assert planning.draw_candidate(12, 250, site, prof) != cands[250]
    # headings and positions are spread, not a fixed list
    assert np.std([c.heading_deg for c in cands]) > 80
    assert len({round(c.x, 3) for c in cands}) == len(cands)


def test_every_position_prior_lies_on_the_database_grid():
    """A rover-scale area (100 m at 1 m, window priors 5 m off) with table 8's heading priors 0-20 m off: every
    window and heading case's prior lies inside the area (the matcher refuses one off its grid: session 33's
    Gale campaign lost 9 heading cases so).  The report profile's 1 km area draws its poses where it did."""
    prof = get_profile("report", area_m=100.0, step_m=1.0, site_margin_m=100.0, window_m=10.0,
                       window_prior_max_m=5.0, t4_presets=("realistic",), t5_presets=(),
                       window_presets=("realistic",), heading_presets=("realistic",))
    site = _site(prof, (0.0, 0.0, 348.0, 337.0), seed=5)
    cases = [c for c in planning.plan_cases(prof, 30) if c.mode in ("window", "heading")]
    assert {c.mode for c in cases} == {"window", "heading"} and max(c.prior_offset_m for c in cases) == 20.0
    for i in range(200):
        cand = planning.draw_candidate(131, i, site, prof)
        for c in cases[:: len(cases) // 40]:
            x, y, _ = planning.prior_of(c, cand, prof)
            assert abs(x - site.center_x) <= site.area_m / 2 and abs(y - site.center_y) <= site.area_m / 2
    # without heading cases the margin is the window priors' as before
    assert planning.pose_half_m(replace(prof, heading_presets=())) == 100.0 / 2 - 10.0 / 2 - 5.0 - 1.0
    report = get_profile("report")
    assert planning.pose_half_m(report) == report.area_m / 2 - report.window_m / 2 - report.window_prior_max_m - 5.0


def test_site_inside_the_dem_with_margin_and_refused_when_too_small():
    prof = get_profile("report")
    bounds = (1000.0, -5000.0, 21000.0, 15000.0)
    margin = max(300.0, 0.15 * 20000.0)
    centres = []
    for seed in range(20):
        s = _site(prof, bounds, seed)
        tol = prof.step_m / 2 + 1e-6  # the centre is snapped to the step
        assert bounds[0] + margin + 500 - tol <= s.center_x <= bounds[2] - margin - 500 + tol
        assert bounds[1] + margin + 500 - tol <= s.center_y <= bounds[3] - margin - 500 + tol
        centres.append((s.center_x, s.center_y))
    assert len(set(centres)) > 10  # drawn, not fixed
    with pytest.raises(InvalidInputError, match="too small"):
        _site(prof, (0.0, 0.0, 1200.0, 1200.0))


def test_site_margin_can_be_set_and_the_refusal_says_what_fits():
    """A rover-scale DEM (350 m) fits only with a smaller margin; the message names the setting that fits."""
    bounds = (0.0, 0.0, 348.0, 337.0)
    small = get_profile("report", area_m=100.0, step_m=1.0)
    with pytest.raises(InvalidInputError, match=r"site_margin_m=M, at most 118 m"):
        _site(small, bounds)
    prof = get_profile("report", area_m=100.0, step_m=1.0, site_margin_m=100.0)
    for seed in range(10):
        s = _site(prof, bounds, seed)
        assert 150.0 - 0.5 <= s.center_x <= 348.0 - 150.0 + 0.5 and 150.0 - 0.5 <= s.center_y <= 337.0 - 150.0 + 0.5
    # with the margin fixed, a too large area is refused with the largest that fits
    with pytest.raises(InvalidInputError, match=r"area_m=M, at most 137 m"):
        _site(get_profile("report", area_m=200.0, site_margin_m=100.0), bounds)
    with pytest.raises(InvalidInputError, match="site_margin_m"):
        get_profile("report", site_margin_m=-1.0)


def test_a_refused_campaign_leaves_nothing_behind(tmp_path):
    """Bad input exits 1 with the reason, and neither the output folder nor a campaign.json is left."""
    gdal = pytest.importorskip("osgeo.gdal")
    dem = tmp_path / "small.tif"
    ds = gdal.GetDriverByName("GTiff").Create(str(dem), 60, 60, 1, gdal.GDT_Float32)
    ds.SetGeoTransform((500000.0, 5.0, 0.0, 4000000.0, 0.0, -5.0))
    ds.SetProjection("EPSG:32610")
    ds.GetRasterBand(1).WriteArray(np.random.default_rng(0).normal(0.0, 5.0, (60, 60)).astype(np.float32))
    ds = None
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "skyloc.cli", "campaign", "--dem", str(dem), "--profile", "report",
                        "--out", str(out), "--no-progress"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 1
    assert "too small" in r.stderr + r.stdout and "--set" in r.stderr + r.stdout
    assert not out.exists()
    # a folder that existed stays, without the campaign.json the refused run started
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    r = subprocess.run([sys.executable, "-m", "skyloc.cli", "campaign", "--dem", str(dem), "--profile", "report",
                        "--out", str(out), "--no-progress"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 1 and sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_case_plan_covers_the_tables_and_reuses_existing_sources():
    prof = get_profile("report", n_poses=3, n_window_poses=3, n_heading_poses=2, n_acquisitions=2)
    cases = planning.plan_cases(prof, 3)
    tables = {c.table for c in cases}
    assert tables == {"4", "5", "6", "7", "8"}
    ids = {c.case_id for c in cases}
    assert len(ids) == len(cases)
    assert sum(c.table == "4" for c in cases) == 3 * len(prof.t4_presets)
    assert sum(c.table == "5" for c in cases) == 3 * len(prof.t5_presets) * 2
    assert sum(c.table == "8" for c in cases) == 2 * len(prof.heading_presets) * len(prof.heading_offsets_m)
    assert all(c.source in ids for c in cases if c.source)
    with pytest.raises(InvalidInputError, match="t4_presets"):
        planning.plan_cases(get_profile("ci", t4_presets=("clean",), window_presets=("binary",)), 1)


def test_only_selects_cases_by_glob_with_the_cases_whose_skyline_they_reuse():
    """``--only``: the matching cases and, transitively, their sources, in plan order; a glob matching
    nothing is refused with the case ids it could have matched."""
    from render_service.campaign.runner import select_cases

    prof = get_profile("report", n_poses=3, n_window_poses=3, n_heading_poses=2, n_acquisitions=3)
    cases = planning.plan_cases(prof, 3)
    ids = [c.case_id for c in cases]
    assert select_cases(cases, ()) == cases
    got = [c.case_id for c in select_cases(cases, ("t6-*-pitch-*",))]
    assert got == [i for i in ids if i.startswith("t6-") and "-pitch-" in i] and len(got) == 1
    # a heading case brings its table-4 source along, nothing else of that pose
    head = next(i for i in ids if i.startswith("t8-"))
    src = next(c.source for c in cases if c.case_id == head)
    assert [c.case_id for c in select_cases(cases, (head,))] == [i for i in ids if i in (head, src)]
    # two globs: the union, in plan order
    both = [c.case_id for c in select_cases(cases, ("t6-*-p00", "t6-*-p02"))]
    assert both == [i for i in ids if i.startswith("t6-") and i.endswith(("-p00", "-p02"))] and len(both) == 2
    with pytest.raises(InvalidInputError, match=r"--only 't9-\*'.*t4-"):
        select_cases(cases, ("t9-*",))


def test_a_campaign_with_an_only_glob_that_matches_nothing_is_refused_before_any_work(tmp_path):
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "skyloc.cli", "campaign", "--profile", "ci", "--out", str(out),
                        "--only", "t6-nothing-*", "--no-progress"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 1
    assert "--only 't6-nothing-*' matches none" in r.stderr + r.stdout
    assert not out.exists()


def test_profile_settings_are_typed_and_checked():
    assert parse_setting("t4_presets=binary, clean") == ("t4_presets", ("binary", "clean"))
    assert parse_setting("heading_offsets_m=0,2.5") == ("heading_offsets_m", (0.0, 2.5))
    assert parse_setting("frames=7") == ("frames", 7)
    for bad in ("frames", "nosuch=1", "frames=seven", "robustness=maybe"):
        with pytest.raises(InvalidInputError):
            parse_setting(bad)
    with pytest.raises(InvalidInputError, match="unknown look"):
        get_profile("ci", t5_presets=("sepia",))
    with pytest.raises(InvalidInputError, match="unknown campaign profile"):
        get_profile("huge")
    # the panoramas' elevation band: typed as floats, checked, whole sphere by default
    key, band = parse_setting("pano_band_deg=-45,45")
    assert get_profile("ci", **{key: band}).pano_band_deg == (-45.0, 45.0)
    assert get_profile("ci").pano_band_deg == (-90.0, 90.0)
    # the report's panoramas: 0.1 deg pixels from 45 deg below the horizontal to the zenith (no alpine
    # horizon is cut), the band the simulator renders with square pixels
    from blender_addon.core.band import panorama_band

    rep = get_profile("report")
    height, bottom, top = panorama_band(rep.pano_width, rep.pano_band_deg)
    assert 360.0 / rep.pano_width <= 0.1 and top == 90.0 and -46.0 < bottom <= -45.0
    assert height == pytest.approx((top - bottom) * rep.pano_width / 360.0)
    assert get_profile("full").pano_band_deg == rep.pano_band_deg
    # ... and its NavCam frames at the camera's own resolution (0.063 deg per pixel for the ExoMars NavCam)
    from blender_addon.core.cameras import get_preset

    cam = get_preset(rep.camera)
    assert rep.camera_width == cam.width and cam.hfov_deg / rep.camera_width < 0.07
    assert get_profile("full").camera_width == rep.camera_width
    for bad in ((45.0, -45.0), (-100.0, 10.0), (-10.0,), (0.0, 0.0)):
        with pytest.raises(InvalidInputError, match="pano_band_deg"):
            get_profile("ci", pano_band_deg=bad)


def test_relief_and_off_grid_distance():
    el = np.concatenate([np.zeros(100), np.linspace(0, 10, 100)])
    assert planning.horizon_relief_deg(el) == pytest.approx(np.percentile(el, 98) - np.percentile(el, 2))
    assert planning.horizon_relief_deg(np.full(50, np.nan)) == 0.0
    site = planning.Site(100.0, 200.0, 400.0, 10.0, (0, 0, 1, 1))
    assert planning.off_grid_distance_steps(103.0, 207.5, site) == pytest.approx(0.25)


# --------------------------------------------------------------------------------------------
# scoring against the truth
# --------------------------------------------------------------------------------------------


def test_extraction_errors_against_a_known_truth():
    truth = np.linspace(0, 5, 360)
    ext = truth.copy()
    ext[:40] = np.nan                      # 40 azimuths masked
    ext[100:103] += 2.0                    # 3 wrong kept columns
    ext[200:300] += 0.05
    e = scoring.extraction_errors(ext, truth, 1.0)
    assert e["kept_deg"] == 320 and e["kept_fraction"] == pytest.approx(320 / 360)
    assert e["n_gt1deg"] == 3 and e["extract_frac_gt1deg"] == pytest.approx(3 / 320)
    assert e["extract_median_abs_err_deg"] == pytest.approx(0.0)


def test_a_horizon_out_of_the_picture_is_not_seen_and_a_line_kept_there_is_wrong():
    """A NavCam acquisition's frames end ~32 deg up: where a near slope rises above that, the horizon is not
    in the picture.  Those azimuths are not asked for (kept / seen), and a line kept there counts as wrong."""
    from board.acquisition import Panorama, PanoramaGeometry

    g = PanoramaGeometry.full_circle(720, 100, elevation_top_deg=30.0, elevation_bottom_deg=-20.0)  # 0.5 deg/px
    seen = np.ones((g.height, g.width), bool)
    seen[:10, 360:] = False                          # the top 10 rows unseen on the second half: top 25 deg
    seen[:, 700:] = False                            # a gap between frames: nothing seen
    top, bottom, margin = scoring.view_limits(Panorama(np.zeros((g.height, g.width)), g, seen), 360)
    assert margin == pytest.approx(1.5)
    el = g.elevations_deg()
    assert top[0] == pytest.approx(el[0]) and top[200] == pytest.approx(el[10]) and np.isnan(top[355])
    assert bottom[0] == pytest.approx(el[-1])
    truth = np.full(360, 5.0)
    truth[40:60] = 40.0                              # above the whole view
    truth[200:220] = 27.0                            # below 30 deg but above the half's 25 deg: hidden
    truth[100:105] = 29.0                            # within the margin of the top: neither seen nor hidden
    ext = truth + 0.02
    ext[40:50] = 12.0                                # a line kept where the horizon is out of view (wrong)
    ext[50:60] = np.nan
    ext[200:220] = 20.0                              # ... and there
    ext[300:318] = np.nan                            # 18 seen azimuths masked
    ext[350:] = np.nan                               # nothing seen, nothing kept
    e = scoring.extraction_errors(ext, truth, 1.0, (top, bottom, margin))
    n_seen = 360 - 20 - 20 - 5 - 10                  # the gap (350-359) is hidden too
    assert e["kept_fraction"] == pytest.approx((n_seen - 18) / n_seen)
    assert e["seen_deg"] == n_seen and e["kept_deg"] == n_seen - 18
    assert e["n_kept_hidden"] == 30 and e["kept_hidden_deg"] == 30.0
    assert e["n_gt1deg"] == 30 and e["n_kept"] == n_seen - 18 + 30
    assert e["extract_median_abs_err_deg"] == pytest.approx(0.02)
    plain = scoring.extraction_errors(ext, truth, 1.0)  # without the view: every azimuth seen, as before
    assert plain["n_kept_hidden"] == 0 and plain["kept_fraction"] == pytest.approx((360 - 10 - 18 - 10) / 360)
    assert plain["seen_deg"] == 360.0


def test_true_skyline_of_a_level_mast_is_the_horizon_shifted_by_the_heading():
    az = np.arange(3600) * 0.1
    el = 3 + 2 * np.sin(np.radians(az)) + np.cos(np.radians(3 * az))
    sky = scoring.true_skyline(el, heading_deg=40.0, pitch_deg=0.0, roll_deg=0.0, n_azimuth=360)
    expect = 3 + 2 * np.sin(np.radians(np.arange(360) + 40.0)) + np.cos(np.radians(3 * (np.arange(360) + 40.0)))
    assert np.max(np.abs(sky - expect)) < 2e-3
    tilted = scoring.true_skyline(el, heading_deg=40.0, pitch_deg=10.0, roll_deg=0.0, n_azimuth=360)
    # pitching the mast up by 10 degrees lowers the skyline ahead by about 10 degrees and raises it behind
    assert tilted[0] == pytest.approx(expect[0] - 10.0, abs=0.3)
    assert tilted[180] == pytest.approx(expect[180] + 10.0, abs=0.3)


class _Fix:
    def __init__(self, x, y, h, status="ok"):
        self.x, self.y, self.heading_deg, self.pitch_deg, self.roll_deg = x, y, h, 0.0, 0.0
        self.status, self.reason = status, "" if status == "ok" else "another place fits"
        self.sigma_x_m = self.sigma_y_m = 1.0
        self.sigma_heading_deg = 0.1
        self.ellipse95_m = (2.45, 2.45, 0.0)


class _Ctx:
    dem_spec = "procedural:mars:1"
    site_xy = (0.0, 0.0)
    profile = get_profile("ci").to_dict()
    body = "mars"


def _row(fix, table="4"):
    case = planning.Case("t-x", table, "panorama", "binary", 0).to_dict()
    cand = dict(planning.draw_candidate(0, 0, planning.Site(0, 0, 400, 10, (0, 0, 1, 1)), get_profile("ci")).to_dict())
    st = scoring.CaseOutcome(case=case, cand=cand, fix=fix)
    return scoring.make_row(_Ctx(), st, np.zeros(3600)), cand


def test_rows_score_the_fix_against_the_truth_and_flag_wrong_ok():
    right, cand = _row(_Fix(0, 0, 0))
    fix = _Fix(cand["x"] + 3.0, cand["y"] - 4.0, cand["heading_deg"] + 359.5)
    row, _ = _row(fix)
    assert row["error_m"] == pytest.approx(5.0) and row["heading_error_deg"] == pytest.approx(0.5)
    assert row["wrong"] == 0 and row["wrong_ok"] == 0 and row["right_flagged"] == 0
    far, _ = _row(_Fix(cand["x"] + 30.0, cand["y"], cand["heading_deg"]))
    assert far["wrong"] == 1 and far["wrong_ok"] == 1
    flagged, _ = _row(_Fix(cand["x"] + 30.0, cand["y"], cand["heading_deg"], status="ambiguous"))
    assert flagged["wrong"] == 1 and flagged["wrong_ok"] == 0 and flagged["reason"].startswith("locate:")
    none, _ = _row(None)
    assert none["status"] == "no_fix" and none["error_m"] == ""
    agg = summary.aggregate([row, far, flagged, none])
    assert agg["cases"] == 4 and agg["wrong"] == 2 and agg["wrong_ok"] == 1
    assert agg["wrong_flagged_share"] == 0.5 and agg["status"] == {"ambiguous": 1, "no_fix": 1, "ok": 2}
    assert agg["error_m"]["n"] == 3 and agg["error_m"]["max"] == pytest.approx(30.0)


def test_rows_carry_their_poses_database_floor_and_misses_say_whether_the_floor_explains_them():
    """A case located against the campaign's database gets its pose's floor (the true horizon located alone); a
    miss (beyond 5 m or 1 deg) at a pose whose floor is beyond 2.5 m, or not ``ok``, counts as floor-limited."""
    from render_service.campaign.floor import floor_summary

    _, cand = _row(None)
    near, _ = _row(_Fix(cand["x"] + 1.0, cand["y"], cand["heading_deg"]))
    chain_miss, _ = _row(_Fix(cand["x"] + 8.0, cand["y"], cand["heading_deg"]))
    site_miss, _ = _row(_Fix(cand["x"] + 40.0, cand["y"], cand["heading_deg"], status="ambiguous"))
    large, _ = _row(_Fix(cand["x"] + 40.0, cand["y"], cand["heading_deg"]))
    robust, _ = _row(_Fix(cand["x"] + 40.0, cand["y"], cand["heading_deg"]))
    large["kind"], robust["table"] = "lost_large", "R"          # located against other databases: no floor
    for r, pose in ((near, 0), (chain_miss, 0), (site_miss, 1), (large, 1), (robust, 1)):
        r["pose"] = pose
    floor = [{"index": 3, "status": "ok", "error_m": 0.21}, {"index": 7, "status": "ambiguous", "error_m": 31.0}]
    scoring.add_floor([near, chain_miss, site_miss, large, robust], floor)
    assert (near["floor_error_m"], near["floor_status"]) == (0.21, "ok")
    assert (site_miss["floor_error_m"], site_miss["floor_status"]) == (31.0, "ambiguous")
    assert large["floor_error_m"] == "" and robust["floor_error_m"] == ""
    agg = summary.aggregate([near, chain_miss, site_miss])
    assert agg["beyond_5m_1deg"] == 2 and agg["beyond_5m_1deg_floor_limited"] == 1
    assert agg["floor_error_m"]["max"] == pytest.approx(31.0)
    fs = floor_summary(floor)
    assert fs["limited_poses"] == [1] and fs["ok"] == 1 and fs["error_m_max"] == pytest.approx(31.0)
    assert {"floor_error_m", "floor_status"} <= set(scoring.COLUMNS)


def test_rows_name_the_look_rendered_on_the_terrains_body():
    assert scoring._look_name("realistic", "moon") == "realistic-moon"
    assert scoring._look_name("distorted", "earth") == "distorted-earth"
    assert scoring._look_name("realistic", "mars") == "realistic"
    assert scoring._look_name("clean", "moon") == "clean"


# --------------------------------------------------------------------------------------------
# the whole chain (Blender + Dask)
# --------------------------------------------------------------------------------------------

#: A reduced ci profile: every table, the fewest renders.
SETTINGS = ["t4_presets=binary,clean", "t5_presets=binary", "window_presets=binary", "heading_presets=binary",
            "heading_offsets_m=0,20", "frames=7", "camera_width=128", "pano_width=480", "samples=1",
            "window_step_m=4", "acq_preset=binary", "robustness=true", "robustness_scene=scenes/test_tiny.toml",
            "robustness_limit=1"]
ARGS = ["--profile", "ci", "--seed", "5", "--poses", "2", "--acquisitions", "1", "--workers", "2", "--no-progress",
        *[a for s in SETTINGS for a in ("--set", s)]]


def _cli(out: Path, poses: int = 2, extra: list[str] | None = None, **kw) -> subprocess.Popen:
    env = dict(os.environ)
    args = [a if a != "2" or ARGS[i - 1] != "--poses" else str(poses) for i, a in enumerate(ARGS)]
    args += extra or []
    return subprocess.Popen([sys.executable, "-m", "skyloc.cli", "campaign", "--out", str(out), *args], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True, **kw)


def _rows(out: Path) -> list[dict]:
    with (out / "results.csv").open() as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def campaign_run(tmp_path_factory):
    pytest.importorskip("bpy")
    out = tmp_path_factory.mktemp("campaign") / "run"
    p = _cli(out)
    log, _ = p.communicate(timeout=900)
    assert p.returncode == 0, log
    return out, log


@pytest.mark.slow
@pytest.mark.blender
def test_campaign_rows_are_consistent_with_the_manifests(campaign_run):
    out, log = campaign_run
    rows = _rows(out)
    plan = json.loads((out / "poses.json").read_text())
    prof = get_profile("ci", **dict(parse_setting(s) for s in SETTINGS), n_poses=2, n_acquisitions=1,
                       n_window_poses=2, n_heading_poses=2)
    cases = planning.plan_cases(prof, len(plan["accepted"]))
    assert [r["case_id"] for r in rows if r["table"] != "R"] == [c.case_id for c in cases]
    # the robustness sets of the scene (one acquisition per set), located against their site's database
    rob = [r for r in rows if r["table"] == "R"]
    assert sorted(r["preset"].split("/")[0] for r in rob) == ["NL3", "OCCL", "REF"]
    for r in rob:
        acq = next((out / "robustness").glob(f"{r['preset'].split('/')[0]}/*/acq_000/acquisition.json"))
        truth = json.loads(acq.read_text())["truth"]
        assert float(r["true_x"]) == pytest.approx(truth["x"], abs=1e-3)
        assert float(r["true_heading_deg"]) == pytest.approx(truth["heading_deg"], abs=1e-3)
    assert set(scoring.COLUMNS[:24]) <= set(rows[0])
    assert {r["table"] for r in rows} == {"4", "5", "6", "7", "8", "R"}
    for r in rows:
        folder = out / "cases" / r["case_id"]
        if r["kind"] in ("panorama", "acquisition") and r["table"] != "R":
            manifest = folder / r["kind"] / f"{r['kind']}.json"
            truth = json.loads(manifest.read_text())["truth"]
            assert float(r["true_x"]) == pytest.approx(truth["x"], abs=1e-3)
            assert float(r["true_y"]) == pytest.approx(truth["y"], abs=1e-3)
            assert float(r["true_heading_deg"]) == pytest.approx(truth["heading_deg"], abs=1e-3)
            if r["kind"] == "panorama" and r["preset"] != "binary":  # the look rendered is the one reported
                assert json.loads(manifest.read_text())["meta"]["degradation"]["name"] == r["look"]
            assert float(r["pitch_deg"]) == pytest.approx(truth.get("pitch_deg", 0.0), abs=1e-6)
            assert float(r["off_grid_steps"]) >= planning.OFF_GRID_MARGIN - 1e-3
            if r["kept_deg"] != "":  # the seen arc holds the kept one, and their ratio is the kept fraction
                assert float(r["kept_deg"]) <= float(r["seen_deg"]) <= 360.0
                assert float(r["kept_fraction"]) == pytest.approx(float(r["kept_deg"]) / float(r["seen_deg"]),
                                                                  abs=1e-3)
        elif r["kind"] in ("window", "heading"):
            assert r["seen_deg"] == ""
        if r["error_m"] != "":
            e = math.hypot(float(r["fix_x"]) - float(r["true_x"]), float(r["fix_y"]) - float(r["true_y"]))
            assert float(r["error_m"]) == pytest.approx(e, abs=2e-3)
            assert r["status"] in ("ok", "ambiguous", "failed")
            wrong = e > scoring.WRONG_M or float(r["heading_error_deg"]) > scoring.WRONG_HEADING_DEG
            assert r["wrong"] == str(int(wrong))
        else:
            assert r["status"] == "no_fix" and r["reason"]
        if r["table"] == "5":
            assert abs(float(r["pitch_deg"])) + abs(float(r["roll_deg"])) == pytest.approx(10.0)
    summ = json.loads((out / "summary.json").read_text())
    assert summ["campaign"]["rows"] == len(rows) and summ["campaign"]["seed"] == 5
    assert sum(g["cases"] for g in summ["tables"].values()) == len(rows)
    assert summ["run"]["peak_rss_mb_main"] > 0 and summ["campaign"]["dem_sha256"]
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 3 and "reference report" in html
    assert "cases" in log and "4/binary" in log  # the one-screen summary


@pytest.mark.slow
@pytest.mark.blender
def test_the_database_floor_locates_each_true_horizon_near_its_pose(campaign_run):
    """benchmarks.campaign_db_floor: the run's ray-marched truths, as level queries in the north frame,
    land within half a grid step of the poses drawn off the grid, at heading 0 within 3 sigma (a truth or
    database azimuth frame off by a sample, or the poses mixed up, puts them metres to hundreds of metres
    away, or a degree off).  The campaign itself wrote that floor into its rows and summary."""
    from benchmarks.campaign_db_floor import floor_rows, main
    from board.skydb import SkyDB

    out, _ = campaign_run
    step = SkyDB.open(out / "db.zarr").meta.grid.geotransform[1]
    poses = json.loads((out / "poses.json").read_text())["accepted"]
    rows = floor_rows(out)
    assert [r["index"] for r in rows] == [p["index"] for p in poses]
    for r in rows:
        assert r["error_m"] <= 0.5 * step, r
        assert r["heading_error_deg"] <= 3.0 * r["sigma_heading_deg"] and r["status"] != "failed", r
    assert main([str(out / "no such run")]) == 2
    # the campaign wrote the same floor beside each case located against its database, and in its summary
    for c in _rows(out):
        if c["table"] != "R" and c["kind"] in scoring.FLOOR_KINDS:
            f = rows[int(c["pose"])]
            assert float(c["floor_error_m"]) == pytest.approx(f["error_m"], abs=1e-3), c["case_id"]
            assert c["floor_status"] == f["status"], c["case_id"]
        else:
            assert c["floor_error_m"] == "" and c["floor_status"] == ""
    doc = json.loads((out / "summary.json").read_text())["floor"]
    assert doc["n"] == len(poses) and doc["error_m_max"] == pytest.approx(max(r["error_m"] for r in rows), abs=1e-3)
    assert "Database floor" in (out / "summary.md").read_text()


def test_reextraction_variants_name_a_wrong_field_or_value():
    """The detector or extraction variant of a re-extraction (FIELD=VALUE) is parsed as Python literals for
    fields of the dataclass; an unknown field or a value that is not a literal is refused by name."""
    from benchmarks.campaign_reextract import field_values
    from board.detect import DetectorParams

    assert field_values(["reseat_on_step_above=False", "above_step_range=(0.1, 0.2)"], "--detector",
                        DetectorParams) == {"reseat_on_step_above": False, "above_step_range": (0.1, 0.2)}
    with pytest.raises(ValueError, match="has no field 'reseat'"):
        field_values(["reseat=False"], "--detector", DetectorParams)
    with pytest.raises(ValueError, match="Python literal"):
        field_values(["jump_cost_per_px=fast"], "--detector", DetectorParams)


@pytest.mark.slow
@pytest.mark.blender
def test_reextraction_scores_the_runs_pictures_as_the_campaign_did(campaign_run):
    """benchmarks.campaign_reextract runs a finished campaign's rendered panoramas and NavCam acquisitions through
    the extraction and the matcher again, with its own glue (an acquisition's panorama levelled with its
    manifest's attitude, the true skyline of a level mast): with the code that ran the campaign, every case's
    kept share, extraction error, fix and status are the campaign's own rows."""
    from benchmarks.campaign_reextract import _cases, evaluate_case, main

    out, _ = campaign_run
    cases = _cases(out, None)
    assert {row["kind"] for _, row in cases} == {"panorama", "acquisition"}
    for folder, row in cases:
        r = evaluate_case(str(out), str(folder), row)
        assert r["returned"] == (row["extract_status"] in ("ok", "degraded")), (row["case_id"], r.get("reason"))
        if not r["returned"]:
            continue
        assert r["kept_fraction"] == pytest.approx(float(row["kept_fraction"]), abs=1e-3), row["case_id"]
        assert r["n_gt1deg"] == int(row["n_gt1deg"]), row["case_id"]
        assert r["extract_median_abs_err_deg"] == pytest.approx(float(row["extract_median_abs_err_deg"]), abs=1e-3)
        assert r["error_m"] == pytest.approx(float(row["error_m"]), abs=0.01), row["case_id"]
        assert r["status"] == row["status"], row["case_id"]
    assert main([str(out / "no such run")]) == 1


@pytest.mark.slow
@pytest.mark.blender
def test_killed_campaign_resumes_to_the_same_results_without_recomputing(campaign_run, tmp_path):
    ref, _ = campaign_run
    out = tmp_path / "run"
    p = _cli(out)
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline and p.poll() is None:
        if len(list((out / "cases").glob("*/row.json"))) >= 3:
            break
        time.sleep(0.5)
    assert p.poll() is None, "the campaign ended before it could be killed"
    os.killpg(p.pid, signal.SIGKILL)
    p.wait(timeout=30)
    finished = {f.parent.name: f.stat().st_mtime_ns for f in (out / "cases").glob("*/row.json")}
    assert finished and not (out / "results.csv").exists()
    p = _cli(out)
    log, _ = p.communicate(timeout=900)
    assert p.returncode == 0, log
    assert f"{len(finished)} finished before" in log
    for cid, mtime in finished.items():  # nothing that finished was recomputed
        assert (out / "cases" / cid / "row.json").stat().st_mtime_ns == mtime
    a, b = _rows(ref), _rows(out)
    drop = set(scoring.TIME_COLUMNS)
    assert [{k: v for k, v in r.items() if k not in drop} for r in a] == \
           [{k: v for k, v in r.items() if k not in drop} for r in b]


@pytest.mark.slow
@pytest.mark.blender
def test_only_reruns_the_chosen_missing_cases_and_leaves_the_others_missing(campaign_run, tmp_path):
    """A finished campaign with two rows removed, resumed with ``--only`` naming one of them: that case runs
    again to the same row, the other stays missing (and out of results.csv), nothing else is recomputed."""
    ref, _ = campaign_run
    out = tmp_path / "run"
    shutil.copytree(ref, out)
    rows = _rows(ref)
    acq = next(r["case_id"] for r in rows if r["table"] == "6")
    win = next(r["case_id"] for r in rows if r["table"] == "7")
    for cid in (acq, win):
        (out / "cases" / cid / "row.json").unlink()
    kept = {f.parent.name: f.stat().st_mtime_ns for f in (out / "cases").glob("*/row.json")}
    p = _cli(out, extra=["--only", "t6-*"])
    log, _ = p.communicate(timeout=900)
    assert p.returncode == 0, log
    assert "--only t6-*:" in log and f"({acq};" in log and "1 to run" in log
    assert (out / "cases" / acq / "row.json").is_file() and not (out / "cases" / win / "row.json").exists()
    for cid, mtime in kept.items():
        assert (out / "cases" / cid / "row.json").stat().st_mtime_ns == mtime
    drop = set(scoring.TIME_COLUMNS)
    want = sorted(({k: v for k, v in r.items() if k not in drop} for r in rows if r["case_id"] != win),
                  key=lambda r: r["case_id"])
    got = sorted(({k: v for k, v in r.items() if k not in drop} for r in _rows(out)), key=lambda r: r["case_id"])
    assert got == want and any(r["table"] == "R" for r in got)  # the robustness rows kept, not re-run


@pytest.mark.slow
@pytest.mark.blender
def test_a_campaign_grown_by_a_pose_equals_one_run_at_both_and_keeps_its_first_rows(campaign_run, tmp_path):
    """A campaign of 1 pose resumed with --poses 2 draws the second pose as a 2-pose campaign does (same
    candidate, same truth), runs only the new cases, and ends with the 2-pose campaign's rows; a resume
    with fewer poses than it holds is refused and leaves the folder as it was."""
    ref, _ = campaign_run
    out = tmp_path / "run"
    p = _cli(out, poses=1)
    log1, _ = p.communicate(timeout=900)
    assert p.returncode == 0, log1
    first = {f.parent.name: f.stat().st_mtime_ns for f in (out / "cases").glob("*/row.json")}
    assert first and all(cid.endswith("-p00") or cid.startswith("r-") for cid in first), first  # r-: robustness
    p = _cli(out, poses=2)
    log2, _ = p.communicate(timeout=900)
    assert p.returncode == 0, log2
    assert "grown: n_heading_poses 1 -> 2, n_poses 1 -> 2, n_window_poses 1 -> 2" in log2
    assert f"{sum(not cid.startswith('r-') for cid in first)} finished before" in log2  # tables 4-8
    for cid, mtime in first.items():
        assert (out / "cases" / cid / "row.json").stat().st_mtime_ns == mtime, cid
    assert json.loads((out / "poses.json").read_text())["accepted"] == \
        json.loads((ref / "poses.json").read_text())["accepted"]
    with np.load(out / "truth.npz") as a, np.load(ref / "truth.npz") as b:
        np.testing.assert_array_equal(a["elevation_deg"], b["elevation_deg"])
    drop = set(scoring.TIME_COLUMNS)
    assert [{k: v for k, v in r.items() if k not in drop} for r in _rows(ref)] == \
           [{k: v for k, v in r.items() if k not in drop} for r in _rows(out)]
    doc = json.loads((out / "campaign.json").read_text())
    assert doc["arguments"]["profile"]["n_poses"] == 2 and doc["grown"][0]["n_poses"] == {"before": 1, "now": 2}
    before = {f: f.stat().st_mtime_ns for f in out.rglob("*") if f.is_file()}
    p = _cli(out, poses=1)
    log3, _ = p.communicate(timeout=300)
    assert p.returncode != 0 and "n_poses 1 < 2" in log3 and "not drop" in log3, log3
    assert {f: f.stat().st_mtime_ns for f in out.rglob("*") if f.is_file()} == before


def test_growing_a_campaign_is_the_only_change_a_resume_accepts(tmp_path):
    """More poses / acquisitions resume (returned as the growth), fewer are refused naming the count, and a
    count changed together with another field is refused as other arguments."""
    from render_service.campaign.runner import _check_arguments

    prof = get_profile("report", n_poses=10, n_heading_poses=10).to_dict()
    args = {"seed": 1, "dem": "x", "profile": json.loads(json.dumps(prof))}
    _check_arguments(tmp_path, args)
    more = {**args, "profile": {**args["profile"], "n_poses": 30, "n_acquisitions": 40}}
    assert _check_arguments(tmp_path, more) == {"n_poses": (10, 30), "n_acquisitions": (prof["n_acquisitions"], 40)}
    assert _check_arguments(tmp_path, args) == {}
    fewer = {**args, "profile": {**args["profile"], "n_poses": 30, "n_heading_poses": 5}}
    with pytest.raises(InvalidInputError, match="n_heading_poses 5 < 10.*not drop"):
        _check_arguments(tmp_path, fewer)
    other = {**args, "profile": {**args["profile"], "n_poses": 30, "pano_width": 1800}}
    with pytest.raises(InvalidInputError, match="profile: n_poses, pano_width differ"):
        _check_arguments(tmp_path, other)
    with pytest.raises(InvalidInputError, match="seed differ"):
        _check_arguments(tmp_path, {**more, "seed": 2})


def test_resuming_with_other_arguments_is_refused(tmp_path):
    from render_service.campaign.runner import CampaignOptions, _check_arguments

    out = tmp_path / "c"
    _check_arguments(out, {"seed": 1, "dem": "x"})
    _check_arguments(out, {"seed": 1, "dem": "x"})  # same arguments: resumes
    with pytest.raises(InvalidInputError, match="seed differ"):
        _check_arguments(out, {"seed": 2, "dem": "x"})
    assert CampaignOptions(out=out).profile == "ci"


def test_poses_option_leaves_the_tables_7_and_8_counts_that_set_names():
    """``--poses 30 --set n_window_poses=1`` ran the window table at 30 poses: --poses overrode the --set."""
    from render_service.cli_campaign import profile_overrides

    kw = dict(acquisitions=None, pano_width=None, samples=None)
    o = profile_overrides(["n_window_poses=1"], poses=30, **kw)
    assert o["n_poses"] == 30 and o["n_window_poses"] == 1 and o["n_heading_poses"] == 30
    assert get_profile("report", **o).n_window_poses == 1
    o = profile_overrides([], poses=None, **kw)
    assert o == {}
    o = profile_overrides(["n_heading_poses=0", "samples=8"], poses=5, acquisitions=2, pano_width=None, samples=None)
    assert (o["n_heading_poses"], o["n_window_poses"], o["n_acquisitions"], o["samples"]) == (0, 5, 2, 8)


def test_a_campaign_started_before_a_profile_field_existed_resumes(tmp_path):
    """campaign.json of an earlier version (a profile field missing) resumes when the field is at its default;
    another value of any field is refused with that field named."""
    from render_service.campaign.runner import _check_arguments

    args = {"dem": "x.tif", "profile": get_profile("report").to_dict(), "seed": 1, "body": None}
    args = json.loads(json.dumps(args))
    older = json.loads(json.dumps(args))
    del older["profile"]["site_margin_m"]
    (tmp_path / "campaign.json").write_text(json.dumps({"format": "skyloc-campaign", "version": 1,
                                                        "arguments": older}))
    _check_arguments(tmp_path, args)  # resumes
    changed = json.loads(json.dumps(args))
    changed["profile"]["site_margin_m"] = 50.0
    with pytest.raises(InvalidInputError, match=r"profile: site_margin_m"):
        _check_arguments(tmp_path, changed)
    changed = json.loads(json.dumps(args))
    changed["profile"]["samples"] = 32
    with pytest.raises(InvalidInputError, match=r"profile: samples"):
        _check_arguments(tmp_path, changed)


@pytest.mark.parametrize("field,now,before,bad,refusal", [
    ("db_elevation_unit_deg", 0.005, 0.01, 0.02, "db_elevation_unit_deg.*not one of 0.01, 0.005"),   # session 17
    ("db_azimuth_subsamples", 4, 1, 0, "db_azimuth_subsamples = 0"),                              # session 18
])
def test_a_campaign_from_before_a_database_change_resumes_only_as_it_ran(tmp_path, field, now, before, bad, refusal):
    """A campaign.json without ``field`` rendered its databases as ``before`` (0.01-degree units before session 17,
    point samples before session 18): run again with today's default it is refused with the field named, and
    resumes with the old value; an impossible value is refused by the profile."""
    from render_service.campaign.runner import _check_arguments

    args = json.loads(json.dumps({"dem": "x.tif", "profile": get_profile("report").to_dict(), "seed": 1,
                                  "body": None}))
    assert args["profile"][field] == now
    older = json.loads(json.dumps(args))
    del older["profile"][field]
    (tmp_path / "campaign.json").write_text(json.dumps({"format": "skyloc-campaign", "version": 1,
                                                        "arguments": older}))
    with pytest.raises(InvalidInputError, match=rf"profile: {field}"):
        _check_arguments(tmp_path, args)
    legacy = json.loads(json.dumps({**args, "profile": get_profile("report", **{field: before}).to_dict()}))
    _check_arguments(tmp_path, legacy)  # resumes
    with pytest.raises(InvalidInputError, match=refusal):
        get_profile("report", **{field: bad})
