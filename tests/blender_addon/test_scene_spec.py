"""Scene files: parsing, validation messages, and reproducible expansion into jobs."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from blender_addon.core.scene_spec import load_scene, parse_scene, set_jobs, set_poses
from board.errors import InvalidInputError

REPO = Path(__file__).resolve().parents[2]

MINI = """
[dataset]
seed = 5
[sites.a]
dem = "procedural:mars:1"
center = [100.0, -50.0]
pose_half_m = 20.0
[cameras.c]
preset = "magellium"
width = 80
[plans.p]
frames = 13
arc_deg = 360
[degradations.dusty]
base = "realistic"
sky = { dust_tau = 2.5 }
[degradations.dustier]
base = "dusty"
sensor = { exposure_ev = 1.0 }
[[sets]]
name = "A"
degradations = ["dusty", "dustier", "clean"]
count = 5
pitch_deg = [-10, 10]
[[sets]]
name = "B"
degradations = "binary"
count = 3
poses_from = "A"
"""


def test_robustness_scene_has_the_report_sets():
    scene = load_scene(REPO / "scenes" / "robustness.toml")
    names = [s.name for s in scene.sets]
    for required in ("REF", "HREL", "SCOM", "LREL", "CLUT", "OCCL", "COND", "NL1", "NL2", "NL3"):
        assert required in names
    assert scene.cameras["navcam"].width == 1024                     # realistic size
    lrel = set_jobs(scene, scene.set_by_name("LREL"))
    tilt = np.array([[j.pose.pitch_deg, j.pose.roll_deg] for j in lrel])
    assert np.abs(tilt).max() <= 10 and np.abs(tilt).max() > 3
    ref = set_jobs(scene, scene.set_by_name("REF"))
    nl3 = set_jobs(scene, scene.set_by_name("NL3"))
    assert [j.pose for j in nl3] == [j.pose for j in ref[: len(nl3)]]   # noise levels at REF's poses
    assert nl3[0].degradation.lens.k1 != 0 and nl3[0].degradation.lens.dispersion > 0
    assert scene.sites["plain"].z_scale < 0.1                          # HREL: flattened terrain
    assert all(j.plan.n_frames == 13 for j in ref) and ref[0].plan.overlap == pytest.approx(0.574, abs=0.01)
    scom = set_jobs(scene, scene.set_by_name("SCOM"))[0]
    assert scom.plan.n_frames == 5 and scom.plan.tilt_deg[0] < 0
    cond = {j.degradation.name for j in set_jobs(scene, scene.set_by_name("COND"))}
    assert cond == {"glare", "overexposed", "lowlight"}


def test_expansion_is_reproducible_and_inherits():
    a = parse_scene(MINI, source="mini.toml")
    b = parse_scene(MINI, source="mini.toml")
    ja, jb = set_jobs(a, a.sets[0]), set_jobs(b, b.sets[0])
    assert [(j.pose, j.seed) for j in ja] == [(j.pose, j.seed) for j in jb]
    assert len({j.seed for j in ja}) == 5
    assert [j.degradation.name for j in ja] == ["dusty", "dustier", "clean", "dusty", "dustier"]
    dustier = a.degradations["dustier"]
    assert dustier.sky.dust_tau == 2.5 and dustier.sensor.exposure_ev == 1.0
    assert dustier.rocks.density_per_m2 > 0          # from "realistic" through "dusty"
    for j in ja:
        assert abs(j.pose.x - 100) <= 20 and abs(j.pose.y + 50) <= 20 and -10 <= j.pose.pitch_deg <= 10
    assert [p.x for p in set_poses(a, a.sets[1])] == [j.pose.x for j in ja[:3]]
    # another seed moves the poses
    c = parse_scene(MINI.replace("seed = 5", "seed = 6"), source="mini.toml")
    assert set_jobs(c, c.sets[0])[0].pose != ja[0].pose


@pytest.mark.parametrize("edit,message", [
    (("count = 5", "count = 0"), r"count = 0 is out of range"),
    (('preset = "magellium"', 'preset = "hazcam"'), r"\[cameras.c\].*unknown camera 'hazcam'"),
    (("frames = 13", "frames = 3"), r"leave gaps"),
    (('base = "dusty"', 'base = "dustier"'), r"cycle"),
    (("sky = { dust_tau = 2.5 }", "sky = { dust_tau = 2.5, haze = 1 }"), r"unknown setting 'haze'"),
    (('poses_from = "A"', 'poses_from = "Z"'), r"poses_from = 'Z' names no set"),
    (("count = 3", "count = 9"), r"at most 5 acquisitions"),
    (('name = "B"', 'name = "A"'), r"two sets are named 'A'"),
    (("pitch_deg = [-10, 10]", "pitch_deg = [10, -10]"), r"min <= max"),
    (("arc_deg = 360", "arc_deg = 360\nspeed = 3"), r"unknown key\(s\) 'speed'"),
    (('degradations = "binary"', 'degradations = "foggy"'), r"unknown degradation 'foggy'"),
    (("[dataset]", "[dataset\n"), r"not valid TOML"),
])
def test_errors_name_the_place_and_the_fix(edit, message):
    with pytest.raises(InvalidInputError, match=message):
        parse_scene(MINI.replace(*edit), source="mini.toml")


def test_relative_dem_paths_resolve_against_the_scene_file(tmp_path):
    (tmp_path / "dems").mkdir()
    text = MINI.replace('dem = "procedural:mars:1"', 'dem = "dems/site.tif"')
    f = tmp_path / "s.toml"
    f.write_text(text)
    assert load_scene(f).sites["a"].dem == str((tmp_path / "dems" / "site.tif").resolve())
    with pytest.raises(InvalidInputError, match="does not exist"):
        load_scene(tmp_path / "missing.toml")
