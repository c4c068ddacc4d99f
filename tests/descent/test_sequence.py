"""The descent-sequence contract: round trip, refusals with the reason, atomic writes."""
import json

import numpy as np
import pytest

from board.camera import CameraModel
from board.descent.sequence import (DescentCamera, Radiometric, frame_name, read_sequence, write_sequence)
from board.errors import FormatError, InvalidInputError

W, H = 32, 24


def _camera(radiometric):
    cam = CameraModel.from_fov(W, H, 40.0)
    R = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])   # camera z = body -z
    return DescentCamera(cam, R, np.array([0.1, 0.0, -0.2]), 14 if radiometric else 8, radiometric).to_dict()


def _meta():
    rad = Radiometric("K", 0.01, 0.0, (8.0, 14.0))
    return {"body": {"name": "europa", "radius_m": 1_560_800.0, "gravity_mps2": 1.315},
            "terrain": {"dem": "procedural:europa:1", "sha256": "0" * 64, "size_m": 400.0, "res_m": 0.5},
            "cameras": {"visible": _camera(None), "thermal": _camera(rad)},
            "frame_rate_hz": 1.0,
            "imu": {"rate_hz": 100.0, "gyro_noise_rad_s_sqrt_hz": 1e-4, "accel_noise_m_s2_sqrt_hz": 1e-3,
                    "gyro_bias_rw": 1e-6, "accel_bias_rw": 1e-5},
            "altimeter": {"sigma_m": 0.1, "rate_hz": 10.0, "dropout_prob": 0.01},
            "lights": [{"name": "sun", "azimuth_deg": 90.0, "elevation_deg": 30.0, "irradiance_w_m2": 50.0}],
            "trajectory": {"id": 1, "name": "linear"}, "trial": 3, "seed": 42,
            "models": {"brdf": "tm", "thermal": "tm"}}


def _data(n_frames=3, rng=None):
    rng = rng or np.random.default_rng(0)
    vis = [rng.integers(0, 256, (H, W), dtype=np.uint8) for _ in range(n_frames)]
    th = [rng.integers(0, 2 ** 14, (H, W)).astype(np.uint16) for _ in range(n_frames)]
    t = np.arange(0, n_frames, 0.01)
    imu = np.column_stack([t, rng.normal(size=(t.size, 6))])
    alt = np.column_stack([t[::10], 50 + rng.normal(size=t[::10].size), np.ones(t[::10].size)])
    alt[2, 1:] = (np.nan, 0)
    q = rng.normal(size=(t.size, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    gt = np.column_stack([t, rng.normal(size=(t.size, 3)), q])
    return vis, th, imu, alt, gt


def test_round_trip_keeps_every_value(tmp_path):
    vis, th, imu, alt, gt = _data()
    out = write_sequence(tmp_path / "trial", _meta(), iter(vis), th, imu, alt, gt, frame_times=[0.0, 1.0, 2.0])
    seq = read_sequence(out)
    assert seq.modes == ("visible", "thermal")
    np.testing.assert_array_equal(seq.frame_times, [0.0, 1.0, 2.0])
    for i in range(3):
        assert seq.load_frame("visible", i).dtype == np.uint8
        np.testing.assert_array_equal(seq.load_frame("visible", i), vis[i])
        np.testing.assert_array_equal(seq.load_frame("thermal", i), th[i])
        assert seq.frame_path("thermal", i) == out / frame_name("thermal", i)
    np.testing.assert_allclose(seq.imu, imu, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(seq.altimeter, alt, atol=1e-6)
    assert np.isnan(seq.altimeter[2, 1]) and seq.altimeter[2, 2] == 0
    np.testing.assert_allclose(seq.groundtruth, gt, atol=1e-9)
    np.testing.assert_array_equal(seq.gravity_w, [0.0, 0.0, -1.315])
    th_cam = seq.cameras["thermal"]
    assert th_cam.radiometric.unit == "K" and th_cam.bit_depth == 14
    np.testing.assert_allclose(th_cam.radiometric.to_physical(th[0]), 0.01 * th[0])
    np.testing.assert_array_equal(th_cam.R_body_cam @ [0, 0, 1], [0, 0, -1])
    assert seq.cameras["visible"].model == CameraModel.from_fov(W, H, 40.0)


def test_only_the_written_modes_are_described(tmp_path):
    vis, _, imu, alt, gt = _data()
    seq = read_sequence(write_sequence(tmp_path / "v", _meta(), vis, None, imu, alt, gt, frame_times=[0, 1, 2]))
    assert seq.modes == ("visible",) and "thermal" not in seq.meta["cameras"]
    with pytest.raises(InvalidInputError, match="no 'thermal' camera"):
        seq.load_frame("thermal", 0)


@pytest.mark.parametrize("edit, match", [
    (lambda d: d.update(format="skyloc-acquisition"), "is not 'skyloc-descent-sequence'"),
    (lambda d: d.update(version=2), "version 2 is not supported"),
    (lambda d: d["body"].pop("gravity_mps2"), "gravity_mps2"),
    (lambda d: d["cameras"]["thermal"]["radiometric"].update(unit="counts"), "radiometric"),
])
def test_reader_refuses_with_the_reason(tmp_path, edit, match):
    vis, th, imu, alt, gt = _data()
    out = write_sequence(tmp_path / "trial", _meta(), vis, th, imu, alt, gt, frame_times=[0, 1, 2])
    doc = json.loads((out / "sequence.json").read_text())
    edit(doc)
    (out / "sequence.json").write_text(json.dumps(doc))
    with pytest.raises(FormatError, match=match):
        read_sequence(out)


@pytest.mark.parametrize("missing", ["imu.csv", "altimeter.csv", "groundtruth.tum", "thermal/000001.png",
                                     "sequence.json"])
def test_reader_refuses_a_missing_file(tmp_path, missing):
    vis, th, imu, alt, gt = _data()
    out = write_sequence(tmp_path / "trial", _meta(), vis, th, imu, alt, gt, frame_times=[0, 1, 2])
    (out / missing).unlink()
    with pytest.raises(FormatError, match="missing|does not exist"):
        read_sequence(out)


def test_a_failed_write_leaves_nothing(tmp_path):
    vis, th, imu, alt, gt = _data()

    def frames():
        yield th[0]
        raise RuntimeError("renderer crashed")

    with pytest.raises(RuntimeError):
        write_sequence(tmp_path / "trial", _meta(), vis, frames(), imu, alt, gt, frame_times=[0, 1, 2])
    assert list(tmp_path.iterdir()) == []
    bad = [np.zeros((H, W + 1), np.uint8)] * 3
    with pytest.raises(InvalidInputError, match="shape"):
        write_sequence(tmp_path / "trial", _meta(), bad, None, imu, alt, gt, frame_times=[0, 1, 2])
    with pytest.raises(InvalidInputError, match="2 visible frames for 3"):
        write_sequence(tmp_path / "trial", _meta(), vis[:2], None, imu, alt, gt, frame_times=[0, 1, 2])
    assert list(tmp_path.iterdir()) == []


def test_writer_refuses_bad_tables_and_overwrites_only_when_asked(tmp_path):
    vis, th, imu, alt, gt = _data()
    with pytest.raises(InvalidInputError, match="unit quaternions"):
        write_sequence(tmp_path / "t", _meta(), vis, th, imu, alt, np.column_stack([gt[:, :7], gt[:, 7] * 2]),
                       frame_times=[0, 1, 2])
    with pytest.raises(InvalidInputError, match="imu must be"):
        write_sequence(tmp_path / "t", _meta(), vis, th, imu[:, :6], alt, gt, frame_times=[0, 1, 2])
    write_sequence(tmp_path / "t", _meta(), vis, th, imu, alt, gt, frame_times=[0, 1, 2])
    with pytest.raises(InvalidInputError, match="already exists"):
        write_sequence(tmp_path / "t", _meta(), vis, th, imu, alt, gt, frame_times=[0, 1, 2])
    write_sequence(tmp_path / "t", _meta(), vis[:2], None, imu, alt, gt, frame_times=[0, 1], overwrite=True)
    assert read_sequence(tmp_path / "t").n_frames == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t"]
