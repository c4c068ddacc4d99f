"""Simulated acquisitions in headless Blender: geometry of the frames, manifests, seeds, CLI.

The geometry test renders a ring wall of known, azimuth-dependent height around the rover with pitch, roll,
pan, tilt and lens distortion, and checks that the skyline in every column of every frame
lies where board.camera (the manifest's camera and angles) says it must, the true
elevation coming from a brute-force ray march over the DEM.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
gdal = pytest.importorskip("osgeo.gdal")

from click.testing import CliRunner  # noqa: E402

from blender_addon.core.acquire import AcquisitionJob, Pose  # noqa: E402
from blender_addon.core.cameras import get_preset  # noqa: E402
from blender_addon.core.degrade import PRESETS, Degradation  # noqa: E402
from blender_addon.core.plans import plan_frames  # noqa: E402
from blender_addon.core.rocks import bilinear_height  # noqa: E402
from blender_addon.sim import Simulator  # noqa: E402
from board.acquisition import load_acquisition, load_schema  # noqa: E402
from board.camera import pixel_to_az_el  # noqa: E402
from board.conventions import curvature_drop_m  # noqa: E402

pytestmark = [pytest.mark.blender, pytest.mark.slow]

X0, Y0 = 500_000.0, 4_000_000.0      # UTM 33N, site centre
CELL = 2.0
N = 500                              # 1 km square
RING = (200.0, 240.0)                # inner and outer radius of the wall (m)


def _wall_height(az_rad):
    """Wall height (m) varying with azimuth, so the skyline pins heading, pan and distortion too."""
    return 28.0 + 14.0 * np.cos(2.0 * az_rad) + 6.0 * np.sin(5.0 * az_rad)


def _ring_dem(path):
    from osgeo import osr

    gdal.UseExceptions()
    xs = X0 - N * CELL / 2 + (np.arange(N) + 0.5) * CELL
    ys = Y0 + N * CELL / 2 - (np.arange(N) + 0.5) * CELL
    X, Y = np.meshgrid(xs, ys)
    r = np.hypot(X - X0, Y - Y0)
    h = _wall_height(np.arctan2(X - X0, Y - Y0))
    z = np.where((r >= RING[0]) & (r <= RING[1]), h, 0.0).astype(np.float32)
    ds = gdal.GetDriverByName("GTiff").Create(str(path), N, N, 1, gdal.GDT_Float32)
    ds.SetGeoTransform((X0 - N * CELL / 2, CELL, 0, Y0 + N * CELL / 2, 0, -CELL))
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(32633)
    ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).WriteArray(z)
    ds = None
    return z


def _true_horizon(z, cam_z, az_deg):
    """Brute force: max elevation (deg) along each azimuth over the bilinear DEM, curvature included."""
    d = np.arange(1.0, 300.0, 0.05)
    a = np.radians(np.asarray(az_deg))[:, None]
    px = X0 + d[None, :] * np.sin(a)
    py = Y0 + d[None, :] * np.cos(a)
    h = bilinear_height(z, X0 - N * CELL / 2, Y0 + N * CELL / 2, CELL, px, py)
    h = h - curvature_drop_m(d, 6_371_008.8)[None, :]
    return np.degrees(np.arctan2(h - cam_z, d[None, :])).max(axis=1)


@pytest.fixture(scope="module")
def ring(tmp_path_factory):
    path = tmp_path_factory.mktemp("ring") / "ring.tif"
    z = _ring_dem(path)
    sim = Simulator(path, (X0, Y0), grid_half_m=60.0)
    return sim, z


def test_skyline_lands_where_the_camera_model_says(ring, tmp_path):
    sim, z = ring
    cam = get_preset("custom", width=256, height=192, hfov_deg=60.0, mast_height_m=2.05)
    deg = Degradation.from_dict({"lens": {"k1": -0.1, "k2": 0.01, "p1": 1e-3, "p2": -5e-4}}, base=PRESETS["binary"])
    pose = Pose(X0, Y0, heading_deg=40.0, pitch_deg=6.0, roll_deg=-4.0)
    plan = plan_frames(3, 180, cam.hfov_deg, tilt_deg=5.0)
    out = sim.acquire(AcquisitionJob(pose, cam, plan, deg, seed=1), tmp_path / "acq")
    acq = load_acquisition(out)
    assert acq.camera.k1 == -0.1 and acq.camera.p1 == 1e-3       # the manifest carries the distortion
    cam_z = acq.truth.z - sim.ground_z(X0, Y0)
    assert cam_z == pytest.approx(2.05)
    table_az = np.arange(0.0, 360.0, 0.25)
    table_el = _true_horizon(z, cam_z, table_az)
    assert 1.0 < table_el.min() < 5.0 < 10.0 < table_el.max() < 14.0   # atan((h - 2.05) / ~200 m)
    errors = []
    for i, f in enumerate(acq.frames):
        img = acq.read_frame(i)
        terrain = (img if img.ndim == 2 else img[..., 0]) > 127
        vs = np.arange(0.0, cam.height - 1.0, 0.02)
        for u in range(2, cam.width - 2):
            col = terrain[:, u]
            if col.all() or not col.any():
                continue
            v_w = int(np.argmax(col))                                  # first terrain pixel from the top
            assert col[v_w:].all(), "terrain below the skyline must be solid"
            az, el = pixel_to_az_el(acq.camera, np.full_like(vs, u), vs, f.pan_deg, f.tilt_deg,
                                    heading_deg=pose.heading_deg, pitch_deg=pose.pitch_deg, roll_deg=pose.roll_deg)
            above = el - np.interp(np.mod(az, 360.0), table_az, table_el, period=360.0)
            k = int(np.argmax(above < 0))                              # first ray below the true skyline
            errors.append(vs[k] - (v_w - 0.5))
    errors = np.abs(np.array(errors))
    assert errors.size > 500
    # a 1 deg pan or roll error, or k1 off by 0.1, fails these bounds (mean >= 0.4 or max >= 1.7 px)
    assert errors.mean() < 0.4 and errors.max() < 1.4, (errors.mean(), errors.max())


def test_sun_behind_the_wall_is_hidden(ring):
    from blender_addon.scene.dressing import sun_visible
    from board.conventions import enu_from_az_el_deg

    sim, z = ring
    sim.ensure_scene()
    az = np.arange(0.0, 360.0, 30.0)
    wall = _true_horizon(z, 2.05, az)
    for a, w in zip(az, wall):
        assert not sun_visible(X0, Y0, 2.05, enu_from_az_el_deg(a, w - 0.7))
        assert sun_visible(X0, Y0, 2.05, enu_from_az_el_deg(a, w + 0.7))


def test_board_extraction_recovers_the_true_horizon(ring, tmp_path):
    """End to end: a distorted, tilted 13-frame binary acquisition read back by board.extraction
    (camera model + pan/tilt + attitude from the manifest) gives the brute-force horizon."""
    extraction = pytest.importorskip("board.extraction")
    sim, z = ring
    cam = get_preset("exomars", width=96)
    deg = Degradation.from_dict({"lens": {"k1": -0.08, "k2": 0.01, "p2": 5e-4}}, base=PRESETS["binary"])
    pose = Pose(X0 + 15.0, Y0 - 10.0, heading_deg=123.0, pitch_deg=5.0, roll_deg=-3.0)
    out = sim.acquire(AcquisitionJob(pose, cam, plan_frames(13, 360, cam.hfov_deg), deg, seed=2), tmp_path / "e")
    res = extraction.extract_from_acquisition(out)
    assert res.skyline is not None, (res.status, res.reason)
    el = res.skyline.elevation_deg
    az_rel = res.skyline.azimuths_deg()
    d = np.arange(1.0, 300.0, 0.05)
    a = np.radians(pose.heading_deg + az_rel)[:, None]
    h = bilinear_height(z, X0 - N * CELL / 2, Y0 + N * CELL / 2, CELL, pose.x + d * np.sin(a), pose.y + d * np.cos(a))
    h = h - curvature_drop_m(d, 6_371_008.8)[None, :]
    truth = np.degrees(np.arctan2(h - 2.05, d[None, :])).max(axis=1)
    ok = np.isfinite(el)
    err = np.abs(el[ok] - truth[ok])
    assert ok.sum() >= 300
    # 96 px over 65 deg: 0.68 deg per pixel
    assert np.median(err) < 0.2 and np.percentile(err, 90) < 0.45, (np.median(err), np.percentile(err, 90))


def test_seeds_reproduce_bytes_and_manifest_validates(ring, tmp_path):
    import jsonschema

    sim, _ = ring
    cam = get_preset("exomars", width=48)
    deg = Degradation.from_dict({"rocks": {"density_per_m2": 0.05, "near_count": 2}, "sensor": {"glare": 0.3}},
                                base=PRESETS["distorted"])
    plan = plan_frames(2, 120, cam.hfov_deg)
    pose = Pose(X0 + 10, Y0 - 5, 300.0, 3.0, 2.0)
    a = sim.acquire(AcquisitionJob(pose, cam, plan, deg, seed=11, samples=2), tmp_path / "a")
    b = sim.acquire(AcquisitionJob(pose, cam, plan, deg, seed=11, samples=2), tmp_path / "b")
    c = sim.acquire(AcquisitionJob(pose, cam, plan, deg, seed=12, samples=2), tmp_path / "c")
    for i in range(2):
        fa, fb, fc = ((p / f"frame_{i:03d}.png").read_bytes() for p in (a, b, c))
        assert fa == fb
        assert fa != fc
    doc = json.loads((a / "acquisition.json").read_text())
    jsonschema.Draft202012Validator(load_schema("acquisition")).validate(doc)
    acq = load_acquisition(a)
    assert (acq.truth.x, acq.truth.y, acq.truth.heading_deg) == (pose.x, pose.y, pose.heading_deg)
    assert acq.attitude == (3.0, 2.0)
    assert acq.meta["degradation"]["lens"]["dispersion"] == deg.lens.dispersion
    assert acq.meta["dressing"]["n_rocks_near_mast"] == 2
    img = acq.read_frame(0)
    assert img.shape == (48, 48, 3) and img.std() > 3      # textured, noisy, not blank
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())   # no temporary folders left


def test_adopt_renders_the_scene_already_built(ring, tmp_path):
    sim, _ = ring
    sim.ensure_scene()
    n_objects = len(bpy.data.objects)
    adopted = Simulator.adopt(sim.terrain, dem_spec="ring.tif", grid_half_m=60.0)
    assert len(bpy.data.objects) == n_objects                   # nothing reset or rebuilt
    job = AcquisitionJob(Pose(X0, Y0, 0.0), get_preset("exomars", width=32), plan_frames(1, 65.0, 65.0),
                         PRESETS["binary"])
    img = load_acquisition(adopted.acquire(job, tmp_path / "adopt")).read_frame(0)
    assert (img[-1] == 255).all() and (img[0] == 0).all()       # the wall's skyline crosses the frame


def test_cli_acquire_writes_a_folder_and_refuses_bad_input(tmp_path):
    from skyloc.cli import main

    runner = CliRunner()
    out = tmp_path / "cli_acq"
    res = runner.invoke(main, ["sim", "acquire", "--dem", "procedural:mars:11:2000:8", "--at", "20,-30",
                               "--heading", "90", "--pitch", "2", "--camera", "magellium", "--width", "40",
                               "--frames", "2", "--arc", "100", "--preset", "binary", "--out", str(out)])
    assert res.exit_code == 0, res.output
    acq = load_acquisition(out)
    assert (acq.camera.width, acq.camera.height) == (40, 30)
    assert acq.mast_height_m == 0.75 and len(acq.frames) == 2
    assert (acq.truth.x, acq.truth.y, acq.truth.pitch_deg) == (20.0, -30.0, 2.0)
    assert set(np.unique(acq.read_frame(0))) <= {0, 255}
    bad = runner.invoke(main, ["sim", "acquire", "--dem", "procedural:mars:11:2000:8", "--at", "1,2,3",
                               "--heading", "0", "--out", str(tmp_path / "bad")])
    assert bad.exit_code == 1 and "--at must be X,Y" in bad.output
    assert not (tmp_path / "bad").exists()
    gaps = runner.invoke(main, ["sim", "acquire", "--dem", "procedural:mars:11:2000:8", "--at", "0,0",
                                "--heading", "0", "--frames", "3", "--out", str(tmp_path / "gaps")])
    assert gaps.exit_code == 1 and "leave gaps" in gaps.output
