"""`skyloc descent eval` end to end: the ci profile's trajectories on the simulator, on a real Dask cluster."""
import csv
import json
import re

import pytest
from click.testing import CliRunner

from render_service.descent_eval.tasks import RESULT_COLUMNS, run_dir
from skyloc.cli import main

pytest.importorskip("distributed")
pytest.importorskip("numba")

# the ci profile's two trajectories, on fewer trials and frames (the test's budget); visible and dual run
# end to end in test_filter_tracking
ARGS = ["descent", "eval", "--profile", "ci", "--trials", "2", "--frames", "3", "--modes", "thermal,visible-64",
        "--workers", "1"]


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory):
    out = tmp_path_factory.mktemp("deval") / "out"
    res = CliRunner().invoke(main, [*ARGS, "--out", str(out)])
    assert res.exit_code == 0, res.output + repr(res.exception)
    return out, res.output


@pytest.mark.slow
def test_eval_writes_results_tables_and_a_self_contained_report(evaluated):
    out, output = evaluated
    with open(out / "results.csv") as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0].keys()) == RESULT_COLUMNS
    assert {(int(r["trajectory"]), int(r["trial"]), r["mode"]) for r in rows} == {
        (k, i, m) for k in (1, 3) for i in (0, 1) for m in ("thermal", "visible-64")}
    for r in rows:
        assert int(r["frames"]) == 3
        assert float(r["ate_m"]) >= 0 and float(r["nees"]) > 0 and float(r["distance_m"]) > 0
        assert float(r["landmarks_mean"]) == (32 if r["mode"] == "thermal" else 64)
        tum = (run_dir(out, int(r["trajectory"]), int(r["trial"]), r["mode"]) / "estimate.tum").read_text().split("\n")
        assert len([ln for ln in tum if ln.strip()]) == 3 and len(tum[0].split()) == 8
    md = (out / "tables.md").read_text()
    assert "Table 1" in md and "Table 3" in md and "12.31" in md
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 2  # one figure per trajectory
    assert not re.search(r"(src|href)=[\"']?(https?:|//|/)", html)  # nothing fetched from outside
    assert "median E" in output


@pytest.mark.slow
def test_eval_resumes_without_rerunning(evaluated):
    out, _ = evaluated
    m = run_dir(out, 1, 0, "thermal") / "metrics.json"
    before = m.stat().st_mtime_ns, json.loads(m.read_text())["E_percent"]
    res = CliRunner().invoke(main, [*ARGS, "--out", str(out), "--local"])
    assert res.exit_code == 0, res.output
    assert (m.stat().st_mtime_ns, json.loads(m.read_text())["E_percent"]) == before


def test_eval_refuses_bad_input(tmp_path):
    res = CliRunner().invoke(main, ["descent", "eval", "--profile", "ci", "--frames", "2", "--out", str(tmp_path / "o")])
    assert res.exit_code != 0 and "at least 3 frames" in res.output
    res = CliRunner().invoke(main, ["descent", "eval", "--profile", "ci", "--modes", "infrared", "--out",
                                    str(tmp_path / "o")])
    assert res.exit_code != 0 and "infrared" in res.output
    res = CliRunner().invoke(main, ["descent", "eval", "--trajectories", "1-x", "--out", str(tmp_path / "o")])
    assert res.exit_code != 0 and "--trajectories" in res.output
    assert not (tmp_path / "o" / "results.csv").exists()


def test_eval_refuses_to_mix_protocols_in_one_folder(tmp_path):
    out = tmp_path / "o"
    out.mkdir()
    (out / "profile.json").write_text(json.dumps({"name": "ci", "trajectories": [1], "trials": 1, "frames": 9,
                                                  "modes": ["visible"], "terrain": "procedural:europa:1", "seed": 0}))
    res = CliRunner().invoke(main, ["descent", "eval", "--profile", "ci", "--out", str(out), "--local"])
    assert res.exit_code != 0 and "another --out" in res.output


@pytest.mark.slow
def test_descent_run_on_one_sequence_reproduces_the_evaluation_run(evaluated, tmp_path):
    from render_service.descent_eval.tasks import filter_seed, sequence_dir

    out, _ = evaluated
    est = tmp_path / "est.tum"
    res = CliRunner().invoke(main, ["descent", "run", str(sequence_dir(out, 3, 1)), "--mode", "thermal", "--seed",
                                    str(filter_seed(0, 3, 1)), "--out", str(est)])
    assert res.exit_code == 0, res.output
    m = json.loads(res.output.strip().splitlines()[-1])
    ref = json.loads((run_dir(out, 3, 1, "thermal") / "metrics.json").read_text())
    assert m["frames"] == 3 and m["E_percent"] == pytest.approx(ref["E_percent"], abs=1e-3)
    assert est.read_text() == (run_dir(out, 3, 1, "thermal") / "estimate.tum").read_text()
    bad = CliRunner().invoke(main, ["descent", "run", str(tmp_path)])
    assert bad.exit_code != 0 and "sequence.json" in bad.output
