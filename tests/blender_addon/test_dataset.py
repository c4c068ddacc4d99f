"""Datasets from scene files: the tiny scene end to end, manifests, reproducibility, resume."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("bpy")

from blender_addon.core.scene_spec import load_scene, set_jobs  # noqa: E402
from blender_addon.sim import generate_dataset  # noqa: E402
from board.acquisition import load_acquisition  # noqa: E402

pytestmark = [pytest.mark.blender, pytest.mark.slow]

TINY = Path(__file__).resolve().parents[2] / "scenes" / "test_tiny.toml"


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny")
    calls = []
    path = generate_dataset(TINY, out, progress=lambda d, t, m: calls.append((d, t, m)))
    return out, path, calls


def test_every_set_has_validated_acquisitions_with_truth(tiny):
    out, path, calls = tiny
    scene = load_scene(TINY)
    doc = json.loads(path.read_text())
    assert doc["format"] == "skyloc-dataset" and doc["seed"] == scene.seed
    assert [s["name"] for s in doc["sets"]] == [s.name for s in scene.sets]
    assert calls[-1][:2] == (4, 4) and all(t == 4 for _, t, _ in calls)
    # one progress protocol: the count of finished acquisitions never goes back, and while one is
    # built and rendered the message says what runs (the terrain first, then frame by frame)
    done = [d for d, _, _ in calls]
    assert done == sorted(done) and set(done) == {0, 1, 2, 3, 4}
    assert calls[0] == (0, 4, "building the terrain of site hills")
    assert any(m.startswith("REF 1/") and "frame" in m for d, _, m in calls if d == 0)
    assert doc["sites"]["hills"]["dem"] == scene.sites["hills"].dem and len(doc["sites"]["hills"]["dem_sha256"]) == 64
    for s in scene.sets:
        manifest = json.loads((out / s.name / "manifest.json").read_text())
        jobs = set_jobs(scene, s)
        assert len(manifest["acquisitions"]) == s.count == len(jobs)
        for entry, job in zip(manifest["acquisitions"], jobs):
            acq = load_acquisition(out / entry["dir"])           # schema-validated
            assert (acq.truth.x, acq.truth.y, acq.truth.heading_deg) == (job.pose.x, job.pose.y, job.pose.heading_deg)
            assert acq.truth.pitch_deg == job.pose.pitch_deg
            assert acq.meta["degradation"]["name"] == job.degradation.name
            assert acq.camera.k1 == job.degradation.lens.k1
            assert len(acq.frames) == job.plan.n_frames and acq.read_frame(0).shape == (64, 64, 3)
    # the noise-level set reuses REF's pose but not its images
    ref = load_acquisition(out / "REF" / "acq_000")
    nl3 = load_acquisition(out / "NL3" / "acq_000")
    assert (ref.truth.x, ref.truth.y) == (nl3.truth.x, nl3.truth.y)
    assert (out / "REF/acq_000/frame_000.png").read_bytes() != (out / "NL3/acq_000/frame_000.png").read_bytes()


def test_same_seed_same_images_and_resume(tiny, tmp_path):
    out, path, _ = tiny
    again = generate_dataset(TINY, tmp_path / "again", sets=["NL3"])
    a = sorted((out / "NL3").rglob("*.png"))
    b = sorted((tmp_path / "again" / "NL3").rglob("*.png"))
    assert len(a) == len(b) == 3
    assert all(x.read_bytes() == y.read_bytes() for x, y in zip(a, b))
    assert json.loads(again.read_text())["sets"][0]["name"] == "NL3"
    # resuming the full dataset re-renders nothing
    stamps = {p: p.stat().st_mtime_ns for p in out.rglob("frame_*.png")}
    generate_dataset(TINY, out)
    assert {p: p.stat().st_mtime_ns for p in out.rglob("frame_*.png")} == stamps


def test_preview_overrides_limit_width_and_samples(tmp_path):
    path = generate_dataset(TINY, tmp_path / "preview", sets=["REF"], limit=1, width=32, samples=1)
    doc = json.loads(path.read_text())
    assert doc["overrides"] == {"limit": 1, "width": 32, "samples": 1}
    manifest = json.loads((tmp_path / "preview" / "REF" / "manifest.json").read_text())
    assert len(manifest["acquisitions"]) == 1
    acq = load_acquisition(tmp_path / "preview" / "REF" / "acq_000")
    assert (acq.camera.width, acq.camera.height) == (32, 32) and acq.meta["samples"] == 1
    # the preview keeps the full set's first pose and seed
    first = set_jobs(load_scene(TINY), load_scene(TINY).set_by_name("REF"))[0]
    assert (acq.truth.x, acq.truth.y, acq.meta["seed"]) == (first.pose.x, first.pose.y, first.seed)


def test_unknown_set_is_refused_before_rendering(tmp_path):
    from board.errors import InvalidInputError

    with pytest.raises(InvalidInputError, match="sets XYZ are not in"):
        generate_dataset(TINY, tmp_path / "x", sets=["XYZ"])
    with pytest.raises(InvalidInputError, match="width must be at least 8"):
        generate_dataset(TINY, tmp_path / "x", width=4)
    assert not (tmp_path / "x").exists()


def test_flattened_site_dem_keeps_georeferencing_and_nodata(tmp_path):
    gdal = pytest.importorskip("osgeo.gdal")
    import numpy as np
    from osgeo import osr

    from blender_addon.core.dataset import scaled_dem

    gdal.UseExceptions()
    src = tmp_path / "src.tif"
    z = np.random.default_rng(0).uniform(-50, 300, (700, 300)).astype(np.float32)   # > one 512-row block
    z[3, 4] = -9999.0
    ds = gdal.GetDriverByName("GTiff").Create(str(src), 300, 700, 1, gdal.GDT_Float32)
    ds.SetGeoTransform((1000.0, 2.0, 0.0, 5000.0, 0.0, -2.0))
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(32633)
    ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).SetNoDataValue(-9999.0)
    ds.GetRasterBand(1).WriteArray(z)
    ds = None
    out = scaled_dem(src, 0.1, tmp_path / "sites" / "flat.tif")
    d = gdal.Open(str(out))
    a = d.GetRasterBand(1).ReadAsArray()
    assert d.GetGeoTransform() == (1000.0, 2.0, 0.0, 5000.0, 0.0, -2.0)
    assert osr.SpatialReference(wkt=d.GetProjectionRef()).IsSame(srs)
    assert a[3, 4] == -9999.0 and d.GetRasterBand(1).GetNoDataValue() == -9999.0
    keep = z != -9999.0
    np.testing.assert_allclose(a[keep], z[keep] * 0.1, rtol=1e-6)
