"""Benchmark of the descent simulator (issue 14): frame pairs per second of the fast renderer at 640 x 480.

Run with ``python -m benchmarks.bench_descent_sim`` (``make bench-descent-sim``).  On the default
procedural Europa terrain (400 m at 0.25 m) and trajectory 3 it measures:

* one process: CPU seconds per frame pair, split into the ray cast + shading (fused kernel), the
  two sensor models and the two PNG writes;
* ``--workers`` processes at once (the campaign's Dask layout, one trial each, ``--frames`` frames,
  terrain and renderer built once per worker and not counted): frame pairs per wall second;
* the scene set-up (terrain, normals, temperature map), once per worker;
* with ``--blender N``: the agreement of the Blender path (eq. 9 as shader nodes, the temperature as
  an emission texture, Cycles) with the fast renderer on N frames of the trajectory (median and 90th
  percentile absolute differences of the visible brightness and of the kelvin), and Cycles' time.

Prints a markdown table with the load average (the machine's 2 cores are shared).  The target is the
300-trial set of ~200 s trajectories in <= 4 h on 2 cores, i.e. >= 8 pairs/s.
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import tempfile
import time
from pathlib import Path

import numpy as np


def _setup(cfg):
    from blender_addon.descent.simulate import cached_renderer

    t0 = time.process_time()
    r = cached_renderer(cfg.terrain, cfg.terrain_res_m, cfg.terrain_size_m, tuple(cfg.lights), cfg.appearance)
    return r, time.process_time() - t0


def _worker(args):
    """One trial's frames in a fresh process: returns (pairs, wall seconds of the frames, setup CPU s)."""
    trajectory, trial, frames, out = args
    from blender_addon.descent.simulate import DescentConfig, simulate_trial

    cfg = DescentConfig(trajectory=trajectory, trial=trial, frames=1)
    _, setup_s = _setup(cfg)
    simulate_trial(cfg, Path(out) / f"warm{trial}")               # compiles / loads the numba cache
    cfg = DescentConfig(trajectory=trajectory, trial=trial, frames=frames)
    t0, c0 = time.perf_counter(), time.process_time()
    simulate_trial(cfg, Path(out) / f"t{trial}")
    return frames, time.perf_counter() - t0, setup_s, time.process_time() - c0


def _blender_agreement(cfg, renderer, motion, cam, n: int) -> dict:
    """Median / p90 absolute differences Blender - fast over ``n`` frames of the trajectory."""
    from blender_addon.scene import descent as blender_descent

    dv, dk, pair_s, build_s = [], [], 0.0, 0.0
    for t in np.linspace(0, cfg.duration_s, n):
        R, p = motion.rotation([t])[0], motion.position([t])[0]
        f = renderer.render(cam, R, p)
        # the Blender scene holds the frame's footprint (+ 5 m) of the 2.6-million-node terrain
        t0 = time.perf_counter()
        blender_descent.build_descent_scene(renderer, window=(np.nanmin(f["x"]) - 5, np.nanmin(f["y"]) - 5,
                                                              np.nanmax(f["x"]) + 5, np.nanmax(f["y"]) + 5))
        build_s += time.perf_counter() - t0
        t0 = time.perf_counter()
        b = blender_descent.render_pair(cam, R, p)
        pair_s += time.perf_counter() - t0
        dv.append(np.abs(b["visible"] - f["visible"]).ravel())
        dk.append(np.abs(b["thermal"] - f["thermal"]).ravel())
    dv, dk = np.concatenate(dv), np.concatenate(dk)
    return {"n": n, "vis_med": float(np.median(dv)), "vis_p90": float(np.percentile(dv, 90)),
            "k_med": float(np.median(dk)), "k_p90": float(np.percentile(dk, 90)), "build_s": build_s / n,
            "pair_s": pair_s / n}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30, help="frames per worker's trial")
    ap.add_argument("--workers", type=int, default=2, help="processes at once (the machine has 2 cores)")
    ap.add_argument("--trajectory", type=int, default=3)
    ap.add_argument("--blender", type=int, default=0, help="frames compared with the Blender path (0: skip)")
    args = ap.parse_args()

    import cv2

    from blender_addon.descent.simulate import DescentConfig, trial_motion
    from board.descent.sequence import png_write_params

    PNG_PARAMS = png_write_params()

    cfg = DescentConfig(trajectory=args.trajectory)
    renderer, setup_s = _setup(cfg)
    motion = trial_motion(cfg, renderer.terrain)
    cam = cfg.cameras()["visible"]
    rng = np.random.default_rng(0)
    times = np.linspace(0, cfg.duration_s, 12)
    renderer.render(cam, motion.rotation([0.0])[0], motion.position([0.0])[0])     # compile
    parts = {"render": 0.0, "sensors": 0.0, "png": 0.0}
    with tempfile.TemporaryDirectory() as tmp:
        for t in times:
            R, p = motion.rotation([t])[0], motion.position([t])[0]
            c0 = time.process_time()
            out = renderer.render(cam, R, p)
            c1 = time.process_time()
            v = cfg.visible_sensor.counts(out["visible"], rng)
            th = cfg.thermal_sensor.counts(out["thermal"], rng)
            c2 = time.process_time()
            cv2.imwrite(os.path.join(tmp, "v.png"), v, PNG_PARAMS)
            cv2.imwrite(os.path.join(tmp, "t.png"), th, PNG_PARAMS)
            c3 = time.process_time()
            parts["render"] += c1 - c0
            parts["sensors"] += c2 - c1
            parts["png"] += c3 - c2
        one = {k: v / len(times) for k, v in parts.items()}
        ctx = mp.get_context("spawn")
        t0 = time.perf_counter()
        with ctx.Pool(args.workers) as pool:
            res = pool.map(_worker, [(args.trajectory, k, args.frames, tmp) for k in range(args.workers)])
        wall = time.perf_counter() - t0
    pairs = sum(r[0] for r in res)
    frame_wall = max(r[1] for r in res)
    trial_cpu = sum(r[3] for r in res)
    agree = _blender_agreement(cfg, renderer, motion, cam, args.blender) if args.blender else None
    load = os.getloadavg()
    print(f"| measure | value |\n| --- | --- |")
    print(f"| one process, CPU s per pair: render (cast + shading) | {one['render']:.3f} |")
    print(f"| one process, CPU s per pair: sensors (both cameras) | {one['sensors']:.3f} |")
    print(f"| one process, CPU s per pair: 2 PNG writes | {one['png']:.3f} |")
    print(f"| one process, pairs per CPU second | {1.0 / sum(one.values()):.2f} |")
    print(f"| {args.workers} processes, {pairs} pairs (whole trials incl. IMU, altimeter), pairs per wall s | "
          f"{pairs / frame_wall:.2f} |")
    print(f"| {args.workers} processes: pairs per CPU s of the whole trials (x {args.workers} = pairs/s on "
          f"{args.workers} idle cores) | {pairs / trial_cpu:.2f} |")
    print(f"| scene set-up per worker (terrain, normals, temperature), CPU s | {setup_s:.1f} |")
    print(f"| total wall s incl. set-up and warm-up | {wall:.1f} |")
    if agree:
        print(f"| Blender path vs fast renderer, {agree['n']} frames at {cam.model.width} x {cam.model.height}: "
              f"visible brightness, median / p90 abs. difference | {agree['vis_med']:.2e} / {agree['vis_p90']:.2e} |")
        print(f"| Blender path vs fast renderer: temperature, median / p90 abs. difference (K) | "
              f"{agree['k_med']:.4f} / {agree['k_p90']:.3f} |")
        print(f"| Blender path: scene build s (footprint window), Cycles s per pair (wall) | {agree['build_s']:.1f}, {agree['pair_s']:.1f} |")
    print(f"| load average during the run (1, 5, 15 min) | {load[0]:.1f}, {load[1]:.1f}, {load[2]:.1f} |")


if __name__ == "__main__":
    main()
