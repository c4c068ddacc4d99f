"""`skyloc locate` end to end: JSON keys, picture, clean errors and exit status."""
import json

import numpy as np
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
