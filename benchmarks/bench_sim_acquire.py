"""Benchmark of simulated NavCam acquisitions (issue 4): frame time at the default quality.

Run with ``python -m benchmarks.bench_sim_acquire`` (also part of ``make bench-blender`` when
that target calls it).  On a procedural Mars site (20 km at 5 m) it renders ExoMars NavCam
frames (1024 x 1024, 16 samples per pixel, Cycles CPU) for the clean and realistic looks and
prints a markdown table with, per look:

* the first frame of an acquisition (scene sync and BVH build after dressing, then render),
* the following frames (persistent data: only the camera moves),
* the numpy post-processing of one frame (distortion, dispersion, glare, blur, noise),

as wall and CPU seconds.  The machine's 2 cores are shared with other work: the load average is
printed with the figures.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np

from blender_addon.core.acquire import AcquisitionJob, Pose
from blender_addon.core.cameras import get_preset
from blender_addon.core.degrade import PRESETS, degrade_frame, render_camera_for
from blender_addon.core.plans import plan_frames
from blender_addon.sim import Simulator


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=1024, help="frame width, pixels (ExoMars NavCam: 1024)")
    ap.add_argument("--frames", type=int, default=3, help="frames per look (the first one includes scene sync)")
    ap.add_argument("--samples", type=int, default=16, help="Cycles samples per pixel (default quality: 16)")
    ap.add_argument("--dem", default="procedural:mars:7")
    ap.add_argument("--looks", default="clean,realistic")
    args = ap.parse_args()

    cam = get_preset("exomars", width=args.width)
    plan = plan_frames(args.frames, 360, cam.hfov_deg, allow_gaps=True)
    t0 = time.perf_counter()
    sim = Simulator(args.dem, (0.0, 0.0), grid_half_m=100.0)
    build_s = time.perf_counter() - t0
    rows = []
    for look in args.looks.split(","):
        deg = PRESETS[look]
        marks: list[tuple[float, float]] = []

        def progress(done: int, total: int, msg: str) -> None:
            marks.append((time.perf_counter(), time.process_time()))

        job = AcquisitionJob(Pose(30.0, -20.0, 45.0), cam, plan, deg, seed=1, samples=args.samples)
        start = (time.perf_counter(), time.process_time())
        with tempfile.TemporaryDirectory() as tmp:
            sim.acquire(job, os.path.join(tmp, "acq"), progress=progress)
        first = (marks[0][0] - start[0], marks[0][1] - start[1])
        rest_w = np.diff([m[0] for m in marks])
        rest_c = np.diff([m[1] for m in marks])
        rows.append((look, first, (float(np.median(rest_w)), float(np.median(rest_c))) if len(rest_w) else None))
    # numpy post-processing alone (distorted look: every effect on)
    deg = PRESETS["distorted"]
    model = cam.camera_model(**deg.lens.distortion)
    pin = render_camera_for(model, dispersion=deg.lens.dispersion)
    render = np.random.default_rng(0).random((pin.height, pin.width, 3)).astype(np.float32)
    w0, c0 = time.perf_counter(), time.process_time()
    degrade_frame(render, pin, model, deg, np.random.default_rng(1), sun_dir_cam=np.array([0.3, -0.2, 1.0]))
    post = (time.perf_counter() - w0, time.process_time() - c0)

    load = os.getloadavg()
    print(f"\nSimulated NavCam frames, {cam.width} x {cam.height} px, {args.samples} samples, Cycles CPU, "
          f"dem {args.dem}; terrain built in {build_s:.1f} s; load average {load[0]:.1f} on {os.cpu_count()} cores\n")
    print("| look | first frame of an acquisition, wall / CPU s | next frames (median), wall / CPU s |")
    print("| --- | --- | --- |")
    for look, first, rest in rows:
        r = "n/a" if rest is None else f"{rest[0]:.1f} / {rest[1]:.1f}"
        print(f"| {look} | {first[0]:.1f} / {first[1]:.1f} | {r} |")
    print(f"| numpy post-processing only (distorted look) | {post[0]:.2f} / {post[1]:.2f} | |")


if __name__ == "__main__":
    main()
