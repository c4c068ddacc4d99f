"""CameraModel and pan-tilt geometry against OpenCV and analytic geometry."""
from __future__ import annotations

import numpy as np
import pytest

from board.camera import CameraModel, az_el_to_pixel, camera_to_body, pixel_to_az_el, rotation_body_from_camera
from board.conventions import az_el_from_enu_deg
from board.errors import FormatError, InvalidInputError

cv2 = pytest.importorskip("cv2")

DISTORTED = CameraModel(1024, 768, 800.0, 805.0, 515.3, 380.2, k1=-0.21, k2=0.06, p1=0.0012, p2=-0.0008, k3=-0.004)


def test_project_matches_opencv_projectpoints():
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(-0.6, 0.6, 500), rng.uniform(-0.45, 0.45, 500), np.ones(500)])
    pts *= rng.uniform(0.5, 30.0, (500, 1))
    u, v = DISTORTED.project(pts)
    ref, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), DISTORTED.matrix,
                               DISTORTED.dist_coeffs)
    np.testing.assert_allclose(np.column_stack([u, v]), ref.reshape(-1, 2), atol=1e-6)


def test_unproject_project_round_trip_with_distortion():
    u, v = DISTORTED.pixel_grid()
    d = DISTORTED.unproject(u, v)
    assert np.all(np.isfinite(d))
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)
    u2, v2 = DISTORTED.project(d)
    assert np.max(np.abs(u2 - u)) < 1e-6 and np.max(np.abs(v2 - v)) < 1e-6


def test_undistort_matches_opencv():
    rng = np.random.default_rng(2)
    uv = np.column_stack([rng.uniform(0, 1023, 300), rng.uniform(0, 767, 300)])
    ref = cv2.undistortPointsIter(uv.reshape(-1, 1, 2), DISTORTED.matrix, DISTORTED.dist_coeffs, None, None,
                                  (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)).reshape(-1, 2)
    x, y = DISTORTED.undistort((uv[:, 0] - DISTORTED.cx) / DISTORTED.fx, (uv[:, 1] - DISTORTED.cy) / DISTORTED.fy)
    np.testing.assert_allclose(np.column_stack([x, y]), ref, atol=1e-6)


def test_behind_camera_is_nan():
    u, v = DISTORTED.project(np.array([[0.1, 0.2, -1.0], [0.0, 0.0, 0.0]]))
    assert np.all(np.isnan(u)) and np.all(np.isnan(v))


def test_from_fov_edges():
    cam = CameraModel.from_fov(640, 480, 60.0)
    # the left edge of the image (u = -0.5) is 30 degrees left of the axis
    d = cam.unproject(np.array([-0.5]), np.array([cam.cy]))[0]
    assert np.degrees(np.arctan2(-d[0], d[2])) == pytest.approx(30.0, abs=1e-9)
    assert cam.hfov_deg == pytest.approx(60.0)


@pytest.mark.parametrize("heading,pan,expect_az", [(0, 90, 90), (0, 0, 0), (30, 90, 120), (350, 20, 10),
                                                    (0, -90, 270), (200, 180, 20)])
def test_pan_clockwise_from_heading(heading, pan, expect_az):
    cam = CameraModel.from_fov(101, 81, 50.0)
    az, el = pixel_to_az_el(cam, cam.cx, cam.cy, pan, 0.0, heading_deg=heading)
    assert float(az) == pytest.approx(expect_az % 360, abs=1e-9)
    assert float(el) == pytest.approx(0.0, abs=1e-9)


def test_tilt_up_and_image_axes():
    cam = CameraModel.from_fov(101, 81, 50.0)
    az, el = pixel_to_az_el(cam, cam.cx, cam.cy, 0.0, 12.5)
    assert float(el) == pytest.approx(12.5, abs=1e-9)
    # image right looks right (clockwise), image up looks up
    az_r, _ = pixel_to_az_el(cam, cam.cx + 20, cam.cy, 0.0, 0.0)
    _, el_up = pixel_to_az_el(cam, cam.cx, cam.cy - 20, 0.0, 0.0)
    assert 0 < float(az_r) < 90 and float(el_up) > 0


def test_rotation_is_proper_and_pan_about_up():
    for pan, tilt in [(0, 0), (37, -8), (-120, 25)]:
        R = rotation_body_from_camera(pan, tilt)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
    # the optical axis at tilt t has body elevation t, whatever the pan
    az, el = az_el_from_enu_deg(camera_to_body(np.array([0.0, 0.0, 1.0]), 77.0, -9.0))
    assert float(el) == pytest.approx(-9.0)


def test_az_el_to_pixel_inverts_pixel_to_az_el_with_attitude():
    u, v = DISTORTED.pixel_grid()
    u, v = u[::37, ::41], v[::37, ::41]
    kw = dict(heading_deg=123.0, pitch_deg=4.0, roll_deg=-7.0)
    az, el = pixel_to_az_el(DISTORTED, u, v, 45.0, 10.0, **kw)
    u2, v2 = az_el_to_pixel(DISTORTED, az, el, 45.0, 10.0, **kw)
    np.testing.assert_allclose(u2, u, atol=1e-6)
    np.testing.assert_allclose(v2, v, atol=1e-6)


def test_dict_round_trip_and_refusals():
    assert CameraModel.from_dict(DISTORTED.to_dict()) == DISTORTED
    with pytest.raises(FormatError, match="fx"):
        CameraModel.from_dict({"width": 10, "height": 10})
    with pytest.raises(InvalidInputError, match="positive"):
        CameraModel(0, 10, 1.0, 1.0, 0.0, 0.0)
