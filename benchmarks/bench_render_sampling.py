"""Render time of a dressed panorama with and without adaptive sampling, paired in one process.

The same poses of a finished campaign (``RUN``: its ``campaign.json``, ``summary.json`` and ``poses.json``) are
rendered in turn with every pixel at the profile's ``samples`` (``ADAPTIVE_MAX_FACTOR = 1``) and with the
noisy ones up to ``ADAPTIVE_MAX_FACTOR`` times more (the simulator's default), alternating so that a drift of the
machine's speed hits both alike.  Prints each render's seconds and the medians.

    python -m benchmarks.bench_render_sampling RUN [--look realistic] [--poses 1,2] [--repeats 2]
"""
from __future__ import annotations

import argparse
import json
import shutil
import statistics
import tempfile
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--look", default="realistic")
    ap.add_argument("--poses", default="1,2")
    ap.add_argument("--repeats", type=int, default=2)
    a = ap.parse_args(argv)
    import blender_addon.scene.render as R
    from blender_addon.core.sampling import ADAPTIVE_MAX_FACTOR
    from render_service.campaign.tasks import CampaignContext, render_panorama_case

    camp = json.loads((a.run / "campaign.json").read_text())
    summ = json.loads((a.run / "summary.json").read_text())
    site = summ["campaign"]["site"]
    prof = camp["arguments"]["profile"]
    body = json.loads((a.run / "terrain" / "db" / "terrain.json").read_text())["body"]["name"]
    dem = camp["arguments"]["dem"]
    ctx = CampaignContext(out_dir=str(a.run), dem_path=dem, dem_spec=dem, body=body,
                          site_xy=(site["center_x"], site["center_y"]), sim_half_m=prof["area_m"] / 2, db_path="",
                          terrain_dir="", profile=prof, n_azimuth=360, camera_height_m=prof["camera_height_m"])
    poses = json.loads((a.run / "poses.json").read_text())["accepted"]
    picks = [int(p) for p in a.poses.split(",") if p]
    tmp = Path(tempfile.mkdtemp())
    times: dict[int, list[float]] = {1: [], ADAPTIVE_MAX_FACTOR: []}
    try:
        render_panorama_case(ctx, {"preset": a.look}, poses[picks[0]], 0.0, 0.0, tmp / "warm-up")
        for rep in range(a.repeats):
            for factor in times:
                R.ADAPTIVE_MAX_FACTOR = factor
                for p in picks:
                    dt = render_panorama_case(ctx, {"preset": a.look}, poses[p], 0.0, 0.0, tmp / f"{rep}-{factor}-{p}")
                    times[factor].append(dt)
                    print(f"samples {prof['samples']} up to {factor * prof['samples']}: pose {p} {dt:.1f} s", flush=True)
    finally:
        R.ADAPTIVE_MAX_FACTOR = ADAPTIVE_MAX_FACTOR
        shutil.rmtree(tmp, ignore_errors=True)
    m1, ma = statistics.median(times[1]), statistics.median(times[ADAPTIVE_MAX_FACTOR])
    print(f"median {m1:.1f} s (every pixel {prof['samples']}) vs {ma:.1f} s (up to {ADAPTIVE_MAX_FACTOR * prof['samples']}): "
          f"x {ma / m1:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
