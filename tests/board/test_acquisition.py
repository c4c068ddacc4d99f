"""Acquisition and panorama folders: round trips, schema validation, refusals with reasons."""
from __future__ import annotations

import json

import numpy as np
import pytest

from board.acquisition import (
    Acquisition,
    FrameInfo,
    GroundTruth,
    PanoramaGeometry,
    load_acquisition,
    load_panorama,
    load_schema,
    write_acquisition,
    write_panorama,
)
from board.camera import CameraModel
from board.errors import FormatError, InvalidInputError

CAM = CameraModel(64, 48, 50.0, 50.0, 31.5, 23.5, k1=-0.1, p2=0.001)


def _acq(n=3):
    frames = [FrameInfo(f"f{i}.png", 120.0 * i, 5.0) for i in range(n)]
    return Acquisition(CAM, 1.9, frames, attitude=(2.0, -1.0),
                       truth=GroundTruth(100.0, 200.0, 33.0, z=5.0, pitch_deg=2.0, crs="EPSG:32633",
                                         extra={"scene": "ref"}), meta={"seed": 4})


def test_acquisition_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    imgs = [rng.integers(0, 65535, (48, 64), dtype=np.uint16) for _ in range(3)]
    write_acquisition(tmp_path, _acq(), images=imgs)
    acq = load_acquisition(tmp_path)
    assert acq.camera == CAM and acq.mast_height_m == 1.9 and acq.attitude == (2.0, -1.0)
    assert [f.pan_deg for f in acq.frames] == [0.0, 120.0, 240.0]
    assert acq.truth.heading_deg == 33.0 and acq.truth.crs == "EPSG:32633" and acq.truth.extra == {"scene": "ref"}
    np.testing.assert_array_equal(acq.read_frame(1), imgs[1])
    assert not list(tmp_path.glob("*.part*"))


def test_unknown_version_refused_with_reason(tmp_path):
    write_acquisition(tmp_path, _acq(1), images=[np.zeros((48, 64), np.uint8)])
    doc = json.loads((tmp_path / "acquisition.json").read_text())
    doc["version"] = 7
    (tmp_path / "acquisition.json").write_text(json.dumps(doc))
    with pytest.raises(FormatError, match="version 7 is not supported"):
        load_acquisition(tmp_path)


def test_schema_violation_names_the_field(tmp_path):
    write_acquisition(tmp_path, _acq(1), images=[np.zeros((48, 64), np.uint8)])
    doc = json.loads((tmp_path / "acquisition.json").read_text())
    doc["frames"][0]["tilt_deg"] = 120
    (tmp_path / "acquisition.json").write_text(json.dumps(doc))
    with pytest.raises(FormatError, match="frames/0/tilt_deg"):
        load_acquisition(tmp_path)


def test_missing_frame_and_wrong_size_refused(tmp_path):
    write_acquisition(tmp_path, _acq(2), images=[np.zeros((48, 64), np.uint8)] * 2)
    (tmp_path / "f1.png").unlink()
    with pytest.raises(FormatError, match="f1.png is missing"):
        load_acquisition(tmp_path)
    with pytest.raises(InvalidInputError, match="camera is 64x48"):
        write_acquisition(tmp_path / "b", _acq(1), images=[np.zeros((10, 10), np.uint8)])
    with pytest.raises(FormatError, match="does not exist"):
        load_acquisition(tmp_path / "nowhere")


def test_panorama_round_trip_and_geometry(tmp_path):
    g = PanoramaGeometry.full_circle(360, 90, elevation_top_deg=30.0, elevation_bottom_deg=-15.0, kind="binary")
    assert g.is_full_circle and g.azimuth_col0_deg == pytest.approx(0.5) and g.elevation_step_deg == 0.5
    np.testing.assert_allclose(g.col_of_az([0.5, 359.5, -0.5, 720.5]), [0, 359, 359, 0])
    assert g.row_of_el(g.elevations_deg()[17]) == pytest.approx(17)
    img = np.zeros((90, 360), np.uint8)
    img[50:] = 255
    seen = np.ones((90, 360), bool)
    seen[:, 100:150] = False
    write_panorama(tmp_path, img, g, seen=seen, mast_height_m=2.0,
                   truth=GroundTruth(1.0, 2.0, 90.0))
    p = load_panorama(tmp_path)
    assert p.geometry == g and p.mast_height_m == 2.0 and p.truth.heading_deg == 90.0
    np.testing.assert_array_equal(p.image, img)
    np.testing.assert_array_equal(p.seen, seen)


def test_partial_panorama_column_wrap():
    g = PanoramaGeometry(100, 10, 350.0, 0.5, 5.0, 0.5)  # 350 .. 399.5 deg
    np.testing.assert_allclose(g.col_of_az([350.0, 10.0, 39.5, 349.0]), [0.0, 40.0, 99.0, -2.0])


def test_panorama_refusals(tmp_path):
    g = PanoramaGeometry.full_circle(36, 9, elevation_top_deg=10, elevation_bottom_deg=-8)
    write_panorama(tmp_path, np.zeros((9, 36), np.uint8), g)
    doc = json.loads((tmp_path / "panorama.json").read_text())
    doc["format"] = "something-else"
    (tmp_path / "panorama.json").write_text(json.dumps(doc))
    with pytest.raises(FormatError, match="is not 'skyloc-panorama'"):
        load_panorama(tmp_path)
    with pytest.raises(InvalidInputError, match="exceed 360"):
        PanoramaGeometry(400, 9, 0.0, 1.0, 0.0, 1.0)


def test_schemas_are_valid_json_schemas():
    import jsonschema

    for name in ("acquisition", "panorama"):
        jsonschema.Draft202012Validator.check_schema(load_schema(name))
