"""locate() on ray-marched databases with queries rendered off the grid, tilted, noisy and partial.

Requirements checked (DESIGN.md): lost in space to 5 m, end of traverse to 1 m, heading to 1 deg,
robust to 10 degrees of pitch or roll.
"""
import math

import numpy as np
import pytest

from board.conventions import wrap_deg180
from board.errors import FormatError, InvalidInputError
from board.locate import locate
from board.skyline import Skyline


def _err(fix, x, y, h):
    return math.hypot(fix.x - x, fix.y - y), abs(float(wrap_deg180(fix.heading_deg - h)))


def _heading_mode_error(w, rng, offset_m: float, margin_steps: float) -> float:
    """Heading error (deg) of heading mode from a prior ``offset_m`` off, tilted mast, heading prior within 8 deg."""
    x, y = w.random_xy(rng, margin_steps=margin_steps)
    h = rng.uniform(0, 360)
    a = rng.uniform(0, 2 * np.pi)
    prior = (x + offset_m * np.cos(a), y + offset_m * np.sin(a))
    sky = w.query(x, y, heading=h, pitch=rng.uniform(-5, 5), roll=rng.uniform(-5, 5), noise=0.05, rng=rng)
    fix = locate(w.db, sky, mode="heading", prior_xy=prior, heading_prior_deg=h + rng.uniform(-8, 8))
    return _err(fix, x, y, h)[1]


@pytest.mark.parametrize("pitch,roll", [(0, 0), (5, 0), (0, -5), (10, 0), (0, 10), (-7, 7)])
def test_lost_in_space_full_panorama_with_tilt(raymarch_world, pitch, roll):
    w = raymarch_world
    rng = np.random.default_rng(100 + 7 * pitch + roll)
    x, y = w.random_xy(rng)
    h = rng.uniform(0, 360)
    fix = locate(w.db, w.query(x, y, heading=h, pitch=pitch, roll=roll, noise=0.05, rng=rng))
    d, dh = _err(fix, x, y, h)
    if (pitch, roll) == (0, 10):
        # this pose's best fit leaves 0.48 deg RMS even for a noise-free query (1.2 deg at the true pose:
        # the interpolated database does not explain this rolled view here), so the fix, 2.3 m off, is
        # not vouched for: a loose fit is never ok (Thresholds.max_ok_rms_deg)
        assert fix.status == "ambiguous" and "loosely" in fix.reason, fix.reason
    else:
        assert fix.status == "ok", fix.reason
    assert d <= 5.0 and dh <= 1.0
    assert abs(fix.pitch_deg - pitch) <= 1.5 and abs(fix.roll_deg - roll) <= 1.5


@pytest.mark.parametrize("arc", [242, 120])
def test_lost_in_space_partial_panorama(raymarch_world, arc):
    w = raymarch_world
    rng = np.random.default_rng(arc)
    errs = []
    for _ in range(4):
        x, y = w.random_xy(rng)
        h = rng.uniform(0, 360)
        sky = w.query(x, y, heading=h, pitch=rng.uniform(-5, 5), roll=rng.uniform(-5, 5), noise=0.05,
                      arc=arc, arc_start=rng.uniform(0, 360), rng=rng)
        fix = locate(w.db, sky)
        errs.append(_err(fix, x, y, h))
    d, dh = np.array(errs).T
    assert np.median(d) <= 5.0 and np.median(dh) <= 1.0


def test_single_frame_65_degrees_is_located_or_flagged(raymarch_world):
    """A 65-degree frame carries little information: a fix is right or it is not `ok`."""
    w = raymarch_world
    rng = np.random.default_rng(65)
    n_ok = 0
    for _ in range(6):
        x, y = w.random_xy(rng)
        h = rng.uniform(0, 360)
        fix = locate(w.db, w.query(x, y, heading=h, noise=0.05, arc=65, arc_start=rng.uniform(0, 360), rng=rng))
        d, _ = _err(fix, x, y, h)
        if fix.status == "ok":
            n_ok += 1
            assert d <= 5 * w.step
    assert n_ok >= 2


def test_window_mode_beats_half_the_grid_step(raymarch_world):
    """End of a traverse: prior within 15 m, 20 m radius; sub-grid refinement gives about 1 m."""
    w = raymarch_world
    rng = np.random.default_rng(7)
    errs = []
    for _ in range(6):
        x, y = w.random_xy(rng, margin_steps=5)
        h = rng.uniform(0, 360)
        a = rng.uniform(0, 2 * np.pi)
        prior = (x + 15 * np.cos(a), y + 15 * np.sin(a))
        fix = locate(w.db, w.query(x, y, heading=h, noise=0.03, rng=rng), mode="window", prior_xy=prior,
                     radius_m=20.0)
        errs.append(_err(fix, x, y, h)[0])
    assert np.median(errs) <= 1.0 < w.step / 2  # grid-node answers would be 1.9 m off on average
    assert max(errs) <= 2 * w.step


@pytest.mark.parametrize("offset_m", [0.0, 2.5, 5.0])
def test_heading_mode_near_the_true_position(raymarch_world, offset_m):
    """Rough procedural terrain with near horizons: heading within 1 degree from a position a few metres off."""
    w = raymarch_world
    rng = np.random.default_rng(int(offset_m * 2) + 3)
    for _ in range(3):
        assert _heading_mode_error(w, rng, offset_m, margin_steps=5) <= 1.0


def test_heading_sweep_real_dem(real_world):
    """Table 8 of the report: heading from a position wrong by 0-20 m, real DEM, tilted mast.

    The heading error of a wrong position is about the parallax of the horizon, position error /
    horizon distance; near horizon points are down-weighted using the database's distances.
    """
    w = real_world
    rng = np.random.default_rng(8)
    errs = np.array([_heading_mode_error(w, rng, offset_m, margin_steps=3)
                     for offset_m in (0.0, 5.0, 10.0, 15.0, 20.0) for _ in range(4)])
    assert np.mean(errs <= 1.0) >= 0.9 and errs.max() <= 2.0
    assert np.all(errs[:4] <= 0.2)  # at the true position


def test_imu_tilt_prior_helps_a_tilted_single_frame(raymarch_world):
    w = raymarch_world
    rng = np.random.default_rng(11)
    without, with_prior = [], []
    for _ in range(4):
        x, y = w.random_xy(rng)
        h = rng.uniform(0, 360)
        p, r = rng.uniform(-10, 10), rng.uniform(-10, 10)
        sky = w.query(x, y, heading=h, pitch=p, roll=r, noise=0.05, arc=120, arc_start=rng.uniform(0, 360), rng=rng)
        imu = (p + rng.normal(0, 0.2), r + rng.normal(0, 0.2), 0.3)
        f1 = locate(w.db, sky)
        f2 = locate(w.db, sky, tilt_prior=imu)
        without.append(abs(f1.pitch_deg - p) + abs(f1.roll_deg - r))
        with_prior.append(abs(f2.pitch_deg - p) + abs(f2.roll_deg - r))
    assert np.median(with_prior) <= 0.5
    assert np.mean(with_prior) <= np.mean(without) + 0.05


@pytest.mark.parametrize("arc", [360, 242])
def test_real_dem_tilted(real_world, arc):
    """St Helens, 30 m DEM, 10 m grid: smooth skylines constrain position less; heading stays sharp."""
    w = real_world
    rng = np.random.default_rng(arc)
    for _ in range(2):
        x, y = w.random_xy(rng)
        h = rng.uniform(0, 360)
        fix = locate(w.db, w.query(x, y, heading=h, pitch=rng.uniform(-10, 10), roll=rng.uniform(-10, 10),
                                   noise=0.05, arc=arc, arc_start=rng.uniform(0, 360), rng=rng))
        d, dh = _err(fix, x, y, h)
        assert d <= 2 * w.step and dh <= 0.5
        dxy = np.array([fix.x - x, fix.y - y])
        assert dxy @ np.linalg.solve(fix.cov_xy, dxy) <= 5.991  # inside the 95 % ellipse


def test_bad_inputs_are_refused_with_the_problem_named(mountain_world, tmp_path):
    db = mountain_world.db
    with pytest.raises(InvalidInputError, match="no seen sample"):
        locate(db, Skyline(np.full(360, np.nan)))
    with pytest.raises(InvalidInputError, match="every 0.5 degrees"):
        locate(db, Skyline(np.zeros(720), azimuth_step_deg=0.5))
    with pytest.raises(InvalidInputError, match="outside the database grid"):
        locate(db, Skyline(np.sin(np.arange(360.0))), mode="window", prior_xy=(0.0, 0.0), radius_m=20)
    with pytest.raises(InvalidInputError, match="prior position"):
        locate(db, Skyline(np.sin(np.arange(360.0))), mode="window")
    with pytest.raises(InvalidInputError, match="unknown mode"):
        locate(db, Skyline(np.sin(np.arange(360.0))), mode="fast")
    with pytest.raises(FormatError, match="no skyline database"):
        locate(tmp_path / "missing.zarr", Skyline(np.sin(np.arange(360.0))))


def test_truncated_database_is_refused(mountain_world, tmp_path):
    import shutil

    from board.skydb import SkyDB

    path = tmp_path / "db.zarr"
    shutil.copytree(mountain_world.db.path, path)
    chunks = sorted(p for p in (path / "elevation").rglob("*") if p.is_file() and p.name != "zarr.json")
    chunks[len(chunks) // 2].write_bytes(b"\x00garbage")
    sky = mountain_world.query(*mountain_world.random_xy(np.random.default_rng(0)), heading=0.0)
    with pytest.raises(FormatError, match="truncated or corrupt"):
        locate(SkyDB.open(path), sky)


def test_heading_mode_with_an_exact_position(raymarch_world):
    """position_sigma_m=0: the position is taken as exact, only heading, pitch and roll are fitted."""
    w = raymarch_world
    rng = np.random.default_rng(17)
    for _ in range(3):
        x, y = w.random_xy(rng)
        h = rng.uniform(0, 360)
        sky = w.query(x, y, heading=h, pitch=rng.uniform(-5, 5), roll=rng.uniform(-5, 5), noise=0.05, rng=rng)
        fix = locate(w.db, sky, mode="heading", prior_xy=(x, y), heading_prior_deg=h - 6.0, position_sigma_m=0)
        assert _err(fix, x, y, h) == (pytest.approx(0.0, abs=1e-9), pytest.approx(0.0, abs=0.5))
        assert math.isnan(fix.sigma_x_m) and fix.to_json_dict()["sigma_x_m"] is None


def test_window_that_misses_the_rover_is_not_ok(mountain_world):
    """A window 60 m from the rover: the best match sits on the window's edge and says so."""
    w = mountain_world
    rng = np.random.default_rng(23)
    g = w.db.grid
    x, y = g.xy(g.ny // 2, g.nx // 2)
    sky = w.query(x, y, heading=40.0, noise=0.03, rng=rng)
    fix = locate(w.db, sky, mode="window", prior_xy=(x + 60.0, y + 10.0), radius_m=12.0)
    assert fix.status != "ok" and "edge of the search window" in fix.reason
    assert locate(w.db, sky, mode="window", prior_xy=(x + 6.0, y + 1.0), radius_m=12.0).status == "ok"


def test_fix_is_the_deepest_minimum_near_the_truth(raymarch_world):
    """The interpolated-database cost has several local minima a cell apart near close horizons.

    Independent check: refinements started from the 9 grid nodes around the TRUE position (ray-marched
    off-grid query, tilted, noisy, 242-degree arc) must not find a lower cost than the fix's.  Before
    the multistart refinement the walk could stop in a shallower minimum (here one query: 214 vs
    208 deg^2; the demo's query: 12.5 vs 5.3 deg^2 and 9.3 m instead of 5.5 m off).
    """
    from board.pose.refine import LocalDB, refine
    from board.skydb import Tile

    w = raymarch_world
    g = w.db.grid
    checked = 0
    for seed in range(60, 70):
        rng = np.random.default_rng(seed)
        x, y = w.random_xy(rng)
        h = rng.uniform(0, 360)
        sky = w.query(x, y, heading=h, pitch=rng.uniform(-5, 5), roll=rng.uniform(-5, 5), noise=0.05, arc=242,
                      arc_start=rng.uniform(0, 360), rng=rng)
        fix = locate(w.db, sky)
        if math.hypot(fix.x - x, fix.y - y) > 2 * w.step:
            continue  # a wrong basin of the coarse search: not what this test is about
        checked += 1
        theta, el = sky.azimuths_deg()[sky.seen], sky.elevation_deg[sky.seen]
        fix_cost = fix.rms_residual_deg ** 2 * theta.size
        fi, fj = g.ij(x, y)
        r, c = int(round(fi)), int(round(fj))
        r0, c0 = max(r - 3, 0), max(c - 3, 0)
        tile = Tile(-1, -1, r0, c0, min(r + 4, g.ny) - r0, min(c + 4, g.nx) - c0)
        local = LocalDB(w.db.read_tile(tile).astype(np.float64), r0, c0, w.db.meta.azimuth_start_deg)
        bounds = {"row": (max(r - 2.5, 0), min(r + 2.5, g.ny - 1)), "col": (max(c - 2.5, 0), min(c + 2.5, g.nx - 1))}
        best = min(refine(local, theta, el, {"row": r + dr, "col": c + dc, "heading": fix.heading_deg,
                                             "pitch": fix.pitch_deg, "roll": fix.roll_deg}, bounds=bounds).cost
                   for dr in (-1, 0, 1) for dc in (-1, 0, 1))
        assert fix_cost <= 1.01 * best, (seed, fix_cost, best)
    assert checked >= 7
