"""`skyloc locate` end to end: JSON keys, picture, clean errors and exit status."""
import json

import numpy as np
import pytest
from click.testing import CliRunner

from skyloc.cli import main

KEYS = {"x", "y", "heading_deg", "pitch_deg", "roll_deg", "sigma_x_m", "sigma_y_m", "sigma_heading_deg", "status",
        "reason", "elapsed_s"}


def test_locate_cli_json_and_plot(mountain_world, tmp_path):
    w = mountain_world
    rng = np.random.default_rng(9)
    x, y = w.random_xy(rng)
    sky = w.query(x, y, heading=211.0, pitch=4.0, roll=-3.0, noise=0.05, arc=242, arc_start=-121, rng=rng)
    sky.save(tmp_path / "sky.json")
    png = tmp_path / "fix.png"
    res = CliRunner().invoke(main, ["locate", "--db", str(w.db.path), "--skyline", str(tmp_path / "sky.json"),
                                    "--json", "--plot", str(png), "--out", str(tmp_path / "fix.json")])
    assert res.exit_code == 0, res.output
    d = json.loads(res.output)
    assert KEYS <= set(d)
    assert d == json.loads((tmp_path / "fix.json").read_text())
    assert np.hypot(d["x"] - x, d["y"] - y) <= w.step and abs((d["heading_deg"] - 211.0 + 180) % 360 - 180) < 0.5
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # window and heading modes
    for args in (["--mode", "window", "--prior", f"{x + 8},{y - 5}", "--radius", "20"],
                 ["--mode", "heading", "--prior", f"{x},{y}", "--heading-prior", "205"]):
        res = CliRunner().invoke(main, ["locate", "--db", str(w.db.path), "--skyline", str(tmp_path / "sky.json"),
                                        "--json", *args])
        assert res.exit_code == 0, res.output
        assert abs((json.loads(res.output)["heading_deg"] - 211.0 + 180) % 360 - 180) < 0.5


def test_locate_cli_errors_name_the_problem(mountain_world, tmp_path):
    w = mountain_world
    sky = tmp_path / "sky.json"
    sky.write_text(json.dumps({"version": 1, "azimuth_start_deg": 0, "azimuth_step_deg": 1.0,
                               "elevation_deg": [None] * 360}))
    cases = [
        (["--skyline", str(sky)], "no seen sample"),
        (["--skyline", str(tmp_path / "nope.json")], "does not exist"),
        (["--skyline", str(sky), "--mode", "window", "--prior", "1,2,3"], "two numbers"),
        (["--skyline", str(sky), "--tilt-prior", "1,2"], "pitch,roll,sigma"),
        ([], "exactly one of --skyline"),
    ]
    for args, msg in cases:
        png = tmp_path / "p.png"
        res = CliRunner().invoke(main, ["locate", "--db", str(w.db.path), "--plot", str(png), *args])
        assert res.exit_code == 1 and msg in res.output, (args, res.output)
        assert not png.exists()  # nothing half-written
    res = CliRunner().invoke(main, ["locate", "--db", str(tmp_path / "none.zarr"), "--skyline", str(sky)])
    assert res.exit_code == 1 and "no skyline database" in res.output


# --- honesty of the CLI: truth, exit codes, provenance, grid edge (issue 13 points 1-2) -------------------------

def _acquisition_at(world, folder, x, y, heading, pitch, roll, *, meta=None, horizon=None):
    """An acquisition folder seen from (x, y) at ``heading`` with the mast tilted by pitch/roll (truth in it)."""
    from board.acquisition import Acquisition, FrameInfo, GroundTruth, write_acquisition
    from board.camera import CameraModel
    from board.synthetic import frame_plan, synth_frames

    az, el = (horizon or world.horizon)(x, y)
    # the synthetic body looks along azimuth 0: its skyline is the world's, turned by the heading
    sky = lambda a: np.interp(np.asarray(a) + heading, az, el, period=360.0)  # noqa: E731
    cam = CameraModel.from_fov(320, 240, 60.0)
    plan = frame_plan(8, (5.0,))
    imgs = synth_frames(cam, plan, sky, pitch_deg=pitch, roll_deg=roll, noise_sigma=0.01, seed=4)
    frames = [FrameInfo(f"frame_{i:03d}.png", p, t) for i, (p, t) in enumerate(plan)]
    write_acquisition(folder, Acquisition(cam, 2.0, frames, attitude=(pitch, roll),
                                          truth=GroundTruth(x, y, heading, pitch_deg=pitch, roll_deg=roll),
                                          meta=meta or {}),
                      images=imgs)
    return folder


def test_locate_acquisition_compares_with_its_truth_and_says_what_the_tilt_is(mountain_world, tmp_path):
    w = mountain_world
    x, y, h = 1003.0, 1994.0, 57.0
    acq = _acquisition_at(w, tmp_path / "acq", x, y, h, 2.0, -1.0)
    png = tmp_path / "fix.png"
    res = CliRunner().invoke(main, ["locate", "--db", str(w.db.path), "--acquisition", str(acq), "--json",
                                    "--plot", str(png)])
    d = json.loads(res.output)
    assert res.exit_code == d["exit_code"] == {"ok": 0, "ambiguous": 3, "failed": 4}[d["status"]], res.output
    t = d["truth"]
    assert (t["x"], t["y"], t["heading_deg"], t["pitch_deg"], t["roll_deg"]) == (x, y, h, 2.0, -1.0)
    # the errors are the fix minus the truth, computed here independently
    assert t["error_m"] == pytest.approx(np.hypot(d["x"] - x, d["y"] - y), abs=1e-5)
    assert t["heading_error_deg"] == pytest.approx((d["heading_deg"] - h + 180) % 360 - 180, abs=1e-5)
    # the panorama was levelled with the manifest's attitude: the fitted tilt is the residual after it
    assert d["levelled_with_deg"] == [2.0, -1.0] and "levelled with the attitude" in d["tilt_reference"]
    assert abs(d["pitch_deg"]) < 0.5 and abs(d["roll_deg"]) < 0.5
    assert t["pitch_error_deg"] == pytest.approx(2.0 + d["pitch_deg"] - 2.0, abs=1e-5)
    assert t["error_m"] < 2 * w.step and abs(t["heading_error_deg"]) < 1.0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = CliRunner().invoke(main, ["locate", "--db", str(w.db.path), "--acquisition", str(acq)]).output
    assert "residual after levelling with the acquisition's attitude (pitch 2.00, roll -1.00)" in text
    assert f"position error {t['error_m']:.2f} m" in text and "heading error" in text


def test_locate_truth_option_and_the_95_ellipse(mountain_world, tmp_path):
    w = mountain_world
    rng = np.random.default_rng(21)
    x, y = w.random_xy(rng, margin_steps=4)
    w.query(x, y, heading=140.0, noise=0.05, rng=rng).save(tmp_path / "sky.json")
    base = ["locate", "--db", str(w.db.path), "--skyline", str(tmp_path / "sky.json"), "--json"]
    d = json.loads(CliRunner().invoke(main, [*base, "--truth", f"{x},{y},140"]).output)
    t = d["truth"]
    dx, dy = d["x"] - x, d["y"] - y
    m2 = np.array([dx, dy]) @ np.linalg.solve(np.array(d["cov_xy"]), np.array([dx, dy]))
    assert t["in_ellipse95"] == bool(m2 <= 5.991464547107979)
    assert t["pitch_error_deg"] is None and t["source"] == "--truth"
    # a truth far away is outside the ellipse
    d = json.loads(CliRunner().invoke(main, [*base, "--truth", f"{x + 60},{y}"]).output)
    assert d["truth"]["in_ellipse95"] is False and d["truth"]["heading_error_deg"] is None
    res = CliRunner().invoke(main, [*base, "--truth", "1,2,3,4"])
    assert res.exit_code == 1 and "--truth must be X,Y[,HEADING]" in res.output


def test_locate_exit_codes_are_distinct_and_allow_uncertain_gives_0(mountain_world, tmp_path):
    w = mountain_world
    rng = np.random.default_rng(5)
    x, y = 1000.0, 2000.0
    w.query(x, y, heading=10.0, noise=0.05, rng=rng).save(tmp_path / "sky.json")
    base = ["locate", "--db", str(w.db.path), "--skyline", str(tmp_path / "sky.json"), "--json"]
    # failed: a skyline of no place in this database
    from board.skyline import Skyline
    from board.synthetic import SkylineFunction

    alien = SkylineFunction.random(3, amplitude_deg=6.0)
    Skyline(alien(np.arange(360.0))).save(tmp_path / "alien.json")
    alien_args = ["locate", "--db", str(w.db.path), "--skyline", str(tmp_path / "alien.json"), "--json"]
    res = CliRunner().invoke(main, alien_args)
    assert json.loads(res.output)["status"] == "failed" and res.exit_code == 4
    # ambiguous: the rover is 40 m from a 10 m search window, so the best match is pinned to its edge
    res = CliRunner().invoke(main, [*base, "--mode", "window", "--prior", f"{x + 40},{y}", "--radius", "10"])
    assert json.loads(res.output)["status"] == "ambiguous" and res.exit_code == 3
    for args in (alien_args, [*base, "--mode", "window", "--prior", f"{x + 40},{y}", "--radius", "10"]):
        res = CliRunner().invoke(main, [*args, "--allow-uncertain"])
        assert res.exit_code == 0 and json.loads(res.output)["exit_code"] == 0
    assert CliRunner().invoke(main, base).exit_code == 0


def test_locate_refuses_a_query_from_another_dem_or_body(tmp_path):
    from board.match.synthetic import MountainField
    from board.skydb import GridSpec, SkyDBMeta, SkyDBWriter
    from board.skyline import Skyline

    mf = MountainField.random(4, r_min=300.0)
    grid = GridSpec.from_center((0.0, 0.0), 40.0, 5.0)
    meta = SkyDBMeta(grid=grid, camera_height_m=2.0, tile_size=16, renderer="analytic", body="mars",
                     dem_sha256="a" * 64)
    wr = SkyDBWriter.create(tmp_path / "db.zarr", meta)
    for t in wr.tiles:
        ii, jj = np.mgrid[t.row0:t.row0 + t.nrows, t.col0:t.col0 + t.ncols]
        gx, gy = grid.xy(ii, jj)
        wr.write_tile(t, mf.horizon_chunked(gx.ravel(), gy.ravel(), meta.azimuths_deg()).reshape(t.nrows, t.ncols, -1))
    wr.finalize()
    el = mf.horizon(1.0, 2.0, np.arange(360.0))[0]
    Skyline(el, meta={"dem_sha256": "b" * 64, "body": "earth"}).save(tmp_path / "earth.json")
    out = tmp_path / "fix.json"
    args = ["locate", "--db", str(tmp_path / "db.zarr"), "--skyline", str(tmp_path / "earth.json"), "--out", str(out)]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 1 and "does not come from the terrain" in res.output
    assert "DEM: the query was made from DEM sha256 bbbbbbbbbbbb" in res.output and "body: the query is on earth" \
        in res.output and "--ignore-provenance" in res.output
    assert not out.exists()
    res = CliRunner().invoke(main, [*args, "--ignore-provenance", "--allow-uncertain"])
    assert res.exit_code == 0 and out.exists()
    # the same DEM and body: matched without a word
    Skyline(el, meta={"dem_sha256": "a" * 64, "body": "Mars"}).save(tmp_path / "mars.json")
    res = CliRunner().invoke(main, ["locate", "--db", str(tmp_path / "db.zarr"), "--skyline",
                                    str(tmp_path / "mars.json"), "--allow-uncertain"])
    assert res.exit_code == 0, res.output
    # an acquisition says where it comes from in its manifest (the simulator writes meta.dem_sha256)
    az = np.arange(0.0, 360.0, 0.25)
    acq = _acquisition_at(None, tmp_path / "acq", 1.0, 2.0, 30.0, 0.0, 0.0, meta={"dem_sha256": "c" * 64},
                          horizon=lambda x, y: (az, mf.horizon(x, y, az)[0]))
    res = CliRunner().invoke(main, ["locate", "--db", str(tmp_path / "db.zarr"), "--acquisition", str(acq)])
    assert res.exit_code == 1 and "DEM: the query was made from DEM sha256 cccccccccccc" in res.output


def test_locate_flags_a_fix_within_a_step_of_the_grid_edge(mountain_world, tmp_path):
    w = mountain_world
    x0, y0, x1, y1 = w.db.grid.bounds()
    rng = np.random.default_rng(8)
    for x, y, edge in ((x0 + 0.4 * w.step, 0.5 * (y0 + y1) + 1.3, True), (0.5 * (x0 + x1) + 1.1, y1 - 2.5 * w.step,
                                                                         False)):
        w.query(x, y, heading=300.0, noise=0.02, rng=rng).save(tmp_path / "sky.json")
        res = CliRunner().invoke(main, ["locate", "--db", str(w.db.path), "--skyline", str(tmp_path / "sky.json"),
                                        "--allow-uncertain"])
        d = json.loads(CliRunner().invoke(main, ["locate", "--db", str(w.db.path), "--skyline",
                                                 str(tmp_path / "sky.json"), "--json", "--allow-uncertain"]).output)
        # independent truth: the fix's distance to the grid's outermost nodes, in steps
        dist = min(d["x"] - x0, x1 - d["x"], d["y"] - y0, y1 - d["y"]) / w.step
        assert d["at_grid_edge"] is (dist < 1.0) is edge, (x, y, d)
        assert ("within one grid step of the database grid's edge" in res.output) is edge
