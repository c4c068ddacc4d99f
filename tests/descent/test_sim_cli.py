"""`skyloc sim descent` and `skyloc sim descent-set` end to end (real Dask LocalCluster for the set)."""
import numpy as np
import pytest
from click.testing import CliRunner

from board.descent.sequence import read_sequence
from skyloc.cli import main

SMALL = ["--width", "32", "--height", "24", "--terrain-res", "1.0", "--duration", "20"]


def test_sim_descent_writes_a_readable_sequence(tmp_path):
    out = tmp_path / "t"
    r = CliRunner().invoke(main, ["sim", "descent", "--trajectory", "3", "--trial", "1", "--frames", "3",
                                  "--modes", "thermal,visible", "--thermal-model", "tm", "--brdf", "tm", *SMALL,
                                  "--out", str(out)])
    assert r.exit_code == 0, r.output
    seq = read_sequence(out)
    assert seq.n_frames == 3 and seq.modes == ("visible", "thermal")
    assert seq.meta["trajectory"] == {"id": 3, "name": "s-shape", "duration_s": 20.0, "noise_pos_m": 2.0,
                                      "noise_att_deg": 1.0}
    assert seq.meta["models"]["brdf"] == "tm" and seq.meta["terrain"]["dem"] == "procedural:europa:1"
    th = seq.cameras["thermal"].radiometric.to_physical(seq.load_frame("thermal", 0))
    assert 30.0 < th.min() and th.max() < 140.0            # kelvin, the memorandum's day-side range
    assert seq.imu[-1, 0] == pytest.approx(2.0) and seq.altimeter.shape[1] == 3
    again = CliRunner().invoke(main, ["sim", "descent", "--trajectory", "3", "--frames", "1", *SMALL,
                                      "--out", str(out)])
    assert again.exit_code != 0 and "already exists" in again.output


def test_sim_descent_options_change_the_models(tmp_path):
    r = CliRunner().invoke(main, ["sim", "descent", "--trajectory", "6", "--frames", "1", "--modes", "visible",
                                  "--brdf", "hapke", "--sensor", "noisy", *SMALL, "--out", str(tmp_path / "h")])
    assert r.exit_code == 0, r.output
    seq = read_sequence(tmp_path / "h")
    assert seq.modes == ("visible",) and seq.cameras["visible"].bit_depth == 12
    assert seq.meta["models"]["shadows"] is True and seq.load_frame("visible", 0).dtype == np.uint16


@pytest.mark.parametrize("args, message", [
    (["--modes", "infrared"], "visible, thermal"),
    (["--sun", "90,-5"], "daylight"),
    (["--sun", "east"], "AZIMUTH,ELEVATION"),
    (["--terrain", "procedural:mars:1"], "procedural:europa:SEED"),
    (["--trajectory", "11"], "1<=x<=10"),
])
def test_sim_descent_refuses_bad_input_with_the_fix(tmp_path, args, message):
    base = ["sim", "descent", "--frames", "1", *SMALL, "--out", str(tmp_path / "x")]
    if "--trajectory" not in args:
        base += ["--trajectory", "1"]
    r = CliRunner().invoke(main, base + args)
    assert r.exit_code != 0 and message in r.output
    assert not (tmp_path / "x").exists()


@pytest.mark.slow
def test_descent_set_on_dask_is_resumable(tmp_path):
    out = tmp_path / "set"
    args = ["sim", "descent-set", "--trajectories", "2,5", "--trials", "2", "--frames", "2", *SMALL,
            "--terrain-size", "120", "--workers", "1", "--out", str(out)]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    dirs = sorted(p.relative_to(out).as_posix() for p in out.glob("traj*/trial*"))
    assert dirs == ["traj02/trial00", "traj02/trial01", "traj05/trial00", "traj05/trial01"]
    seqs = {d: read_sequence(out / d) for d in dirs}
    assert {s.meta["trial"] for s in seqs.values()} == {0, 1}
    # trials differ (actuation noise), trajectories differ
    assert not np.allclose(seqs["traj02/trial00"].groundtruth[:, 1:4], seqs["traj02/trial01"].groundtruth[:, 1:4])
    stamp = (out / "traj02/trial00/sequence.json").stat().st_mtime_ns
    # interrupt: one trial removed, one half-written folder left behind
    import shutil

    shutil.rmtree(out / "traj05/trial01")
    (out / "traj05/.trial01.abc.part").mkdir()
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    assert (out / "traj02/trial00/sequence.json").stat().st_mtime_ns == stamp        # not redone
    assert read_sequence(out / "traj05/trial01").meta["trial"] == 1
    assert not list(out.glob("traj05/.trial01.*.part"))
    import json

    m = json.loads((out / "descent_set.json").read_text())
    assert m["complete"] == 4 and m["failed"] == {}
