"""Panorama building from pan/tilt frames, checked against the same scene rendered analytically
on the panorama grid (independent of the frame -> panorama projection)."""
from __future__ import annotations

import numpy as np
import pytest

from board.acquisition import PanoramaGeometry, load_acquisition
from board.camera import CameraModel
from board.detect import detect_skyline
from board.panorama import build_panorama, frame_footprint, panorama_geometry_for
from board.synthetic import SceneLook, SkylineFunction, frame_plan, synth_acquisition, synth_panorama

CAM = CameraModel.from_fov(240, 180, 60.0, k1=-0.18, k2=0.04, p1=0.0008, p2=-0.0005)
LOOK = SceneLook(texture=0.0)        # smooth ground: pixel values comparable after resampling


@pytest.fixture(scope="module")
def acq_dir(tmp_path_factory):
    f = SkylineFunction.random(7)
    d = tmp_path_factory.mktemp("acq")
    synth_acquisition(d, CAM, frame_plan(8, (4.0,)), f, look=LOOK, pitch_deg=4.0, roll_deg=-3.0)
    return d, f


def test_footprint_of_a_frame():
    cam = CameraModel.from_fov(200, 100, 60.0)
    half_centre = np.degrees(np.arctan((cam.width / 2 - 0.5) / cam.fx))   # border pixel centres
    fp = frame_footprint(cam, 90.0, 0.0)
    assert fp.az_start_deg == pytest.approx(90.0 - half_centre, abs=1e-6)
    assert fp.az_width_deg == pytest.approx(2 * half_centre, abs=1e-6)
    assert -fp.el_min_deg == pytest.approx(fp.el_max_deg, abs=1e-6)
    seam = frame_footprint(cam, 0.0, 0.0)          # straddles north
    assert seam.az_start_deg == pytest.approx(360.0 - half_centre, abs=1e-6)
    assert seam.az_width_deg == pytest.approx(2 * half_centre, abs=1e-6)
    zen = frame_footprint(cam, 0.0, 80.0)          # contains the zenith
    assert zen.az_width_deg == 360.0 and zen.el_max_deg == 90.0


def test_panorama_matches_analytic_rendering(acq_dir):
    d, f = acq_dir
    pano = build_panorama(d)
    g = pano.geometry
    assert g.is_full_circle and g.azimuth_reference == "heading"
    assert g.azimuth_step_deg == pytest.approx(np.degrees(1 / CAM.fx), rel=0.01)
    ref = synth_panorama(g, f, look=LOOK) * 255.0
    diff = np.abs(pano.image.astype(float) - ref)
    # away from the line (where resampling blurs a step) the two agree to a grey level or two
    rows = np.arange(g.height)[:, None]
    line = g.row_of_el(f(g.azimuths_deg()))[None, :]
    far = pano.seen & (np.abs(rows - line) > 3)
    assert pano.seen.mean() > 0.75 and pano.seen.any(axis=0).all()
    assert np.median(diff[far]) <= 1.0 and np.percentile(diff[far], 99) <= 4.0


def test_skyline_from_built_panorama_within_one_pixel(acq_dir):
    d, f = acq_dir
    pano = build_panorama(d)
    det = detect_skyline(pano.image, seen=pano.seen, wrap=True)
    err = det.line_row - pano.geometry.row_of_el(f(pano.geometry.azimuths_deg()))
    # the calibrated column confidence (issue 11) masks the columns it cannot vouch for: a masked column is
    # better than a wrong kept one, and at least 90 % of the seen ones must stay (the target)
    assert det.valid.mean() > 0.97
    # measured: kept 0.999, mean 0.20 px, p95 1.0 px since the line is placed on the local grey step and
    # quantisation is not texture (before: kept 0.951, mean 0.51 px, p95 2.24 px)
    kept = np.abs(err[det.valid])
    assert kept.mean() <= 0.3 and np.percentile(kept, 95) <= 1.5


def test_attitude_levels_the_panorama(acq_dir, tmp_path):
    # the same frames read as if the body were level: the skyline comes out tilted, i.e. wrong
    d, f = acq_dir
    acq = load_acquisition(d)
    acq.attitude = None
    pano = build_panorama(acq)
    det = detect_skyline(pano.image, seen=pano.seen, wrap=True)
    err = det.line_row - pano.geometry.row_of_el(f(pano.geometry.azimuths_deg()))
    assert np.nanmax(np.abs(err)) * pano.geometry.elevation_step_deg > 2.0    # degrees off somewhere


def test_unseen_sectors_are_masked_not_filled(tmp_path):
    f = SkylineFunction.random(8)
    cam = CameraModel.from_fov(240, 180, 60.0)      # no distortion: the footprint is exactly 60 degrees wide
    synth_acquisition(tmp_path, cam, [(0.0, 0.0), (50.0, 0.0), (200.0, 0.0)], f, look=LOOK)
    pano = build_panorama(tmp_path)
    g = pano.geometry
    az = g.azimuths_deg()
    seen_cols = pano.seen.any(axis=0)
    # frame at pan 0 covers [-30, 30] across the seam, pan 50 covers [20, 80], pan 200 covers [170, 230]
    assert seen_cols[(az < 29) | (az > 331)].all()
    assert seen_cols[(az > 21) & (az < 79)].all() and seen_cols[(az > 171) & (az < 229)].all()
    assert not seen_cols[(az > 81) & (az < 169)].any() and not seen_cols[(az > 231) & (az < 329)].any()
    assert np.all(pano.image[~pano.seen] == 0)


@pytest.mark.parametrize("seed", [9, 19])
def test_yaw_refinement_recovers_pan_errors(tmp_path, seed):
    f = SkylineFunction.random(seed)
    err = np.random.default_rng(seed).uniform(-1.0, 1.0, 8)
    cam = CameraModel.from_fov(400, 300, 60.0, k1=-0.18, k2=0.04, p1=0.0008, p2=-0.0005)
    synth_acquisition(tmp_path, cam, frame_plan(8, (2.0,)), f, pan_error_deg=err, noise_sigma=0.01)
    pano = build_panorama(tmp_path, refine_yaw=True, pan_sigma_deg=1.0)
    corr = np.array(pano.meta["pan_corrections_deg"])
    # only relative yaw is observable: compare after removing the mean
    np.testing.assert_allclose(corr - corr.mean(), err - err.mean(), atol=0.08)


def test_yaw_refinement_keeps_exact_angles(tmp_path):
    f = SkylineFunction.random(10)
    synth_acquisition(tmp_path, CAM, frame_plan(8, (2.0,)), f, noise_sigma=0.01)
    corr = np.array(build_panorama(tmp_path, refine_yaw=True).meta["pan_corrections_deg"])
    assert np.max(np.abs(corr)) <= 0.05


def test_geometry_options(acq_dir):
    d, _ = acq_dir
    acq = load_acquisition(d)
    g = panorama_geometry_for(acq, azimuth_step_deg=0.5, elevation_range_deg=(-10.0, 20.0))
    assert isinstance(g, PanoramaGeometry) and g.width == 720 and g.height == 60
    assert g.el_of_row(-0.5) == pytest.approx(20.0) and g.el_of_row(g.height - 0.5) == pytest.approx(-10.0)


def test_black_beyond_the_frames_is_not_a_step_above_the_line(tmp_path):
    """A NavCam-like acquisition (13 frames of 65 deg) leaves unseen black wedges at the top of the panorama,
    between the frames' corners.  The detector's features look a few rows across: blurred with that black,
    the first seen rows of a sky darker than the ground read as a band of "more sky than sky" and the
    step from it as a sky-to-ground step above the line, which masks the column (held-out Mars 403: 30 % of
    every acquisition masked, its lines right).  The unseen pixels are filled from the seen ones first."""
    from board.detect import DetectorParams
    from board.detect.sky_regions import _detect_direct

    cam = CameraModel.from_fov(192, 192, 65.0)
    look = SceneLook(sky_top=0.35, sky_horizon=0.35, ground=0.6, texture=0.05)
    for seed in (3, 4):
        f = SkylineFunction.random(seed)
        d = tmp_path / f"acq{seed}"
        synth_acquisition(d, cam, frame_plan(13), f, look=look, noise_sigma=0.01, seed=seed)
        pano = build_panorama(d)
        assert 0.002 < 1.0 - pano.seen.mean() < 0.05                 # the wedges are there, and small
        truth = pano.geometry.row_of_el(f(pano.geometry.azimuths_deg()))
        det = detect_skyline(pano.image, seen=pano.seen, wrap=True)
        assert det.valid.mean() >= 0.95
        assert np.nanmean(np.abs(det.line_row - truth)) <= 0.5
        # the control: the same detector on the unfilled image masks most of the view
        unfilled = _detect_direct(pano.image, pano.seen, True, DetectorParams())
        assert unfilled.valid.mean() < 0.5


@pytest.mark.parametrize("seed", range(3))
def test_unseen_pixels_take_the_nearest_seen_pixel_of_their_column(seed):
    from board.detect.preprocess import fill_unseen_rows

    rng = np.random.default_rng(seed)
    H, W = 40, 30
    img = rng.integers(1, 255, (H, W, 3)).astype(np.uint8)
    seen = rng.random((H, W)) > 0.4
    seen[:, 5] = False                                                 # a column with nothing seen
    filled = fill_unseen_rows(img, seen)
    for c in range(W):
        rows = np.flatnonzero(seen[:, c])
        for r in range(H):
            if seen[r, c] or rows.size == 0:
                np.testing.assert_array_equal(filled[r, c], img[r, c])
                continue
            d = np.abs(rows - r)
            near = rows[d == d.min()]
            # the nearest seen pixel (a tie between one above and one below may take either)
            assert any(np.array_equal(filled[r, c], img[k, c]) for k in near)
    assert fill_unseen_rows(img, np.ones((H, W), bool)) is img
    np.testing.assert_array_equal(fill_unseen_rows(img, seen, block_columns=7), filled)   # blocks of columns
