"""Benchmark of the descent filter (issue 15): one filter step per frame pair at N = 64 on one core, and memory.

Run with ``make bench-descent-filter`` (``python -m benchmarks.bench_descent_filter``).  The filter runs in
``dual`` mode (64 landmarks, both cameras: SIFT on two 640 x 480 frames, active search, 1-point RANSAC,
updates, map management) and ``visible-64`` on a synthetic descent (board.descent.synthetic) or on a
descent-sequence folder (``--sequence``), single-threaded (OpenCV and BLAS limited to one thread).
Prints per-step CPU and wall time (ms: mean, median, max) and the peak resident memory of the
process (ru_maxrss, MB) with the load average, as a markdown table.
"""
from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import resource  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from board.descent.runner import DescentNavigator  # noqa: E402


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def bench(seq, mode: str, frames: int) -> dict:
    import cv2  # noqa: PLC0415

    cv2.setNumThreads(1)
    nav = DescentNavigator(seq, mode, seed=0)
    cpu, wall = [], []
    n = min(frames, seq.frame_times.size)
    for i in range(n):
        t, c = time.perf_counter(), time.process_time()
        nav.step(i)
        wall.append(1e3 * (time.perf_counter() - t))
        cpu.append(1e3 * (time.process_time() - c))
    cpu_a, wall_a = np.array(cpu[1:]), np.array(wall[1:])  # frame 0 only initialises
    return {"mode": mode, "frames": n, "landmarks": len(nav.ekf.landmarks), "state": nav.ekf.n,
            "cpu_mean": cpu_a.mean(), "cpu_median": np.median(cpu_a), "cpu_max": cpu_a.max(),
            "wall_mean": wall_a.mean(), "wall_max": wall_a.max(), "rss_mb": _rss_mb()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--sequence", default=None, help="a descent-sequence folder (default: a synthetic descent)")
    args = ap.parse_args()
    base = _rss_mb()
    if args.sequence:
        from board.descent.sequence import read_sequence  # noqa: PLC0415
        seq = read_sequence(args.sequence)
        src = args.sequence
    else:
        from board.descent.synthetic import make_sequence  # noqa: PLC0415
        seq = make_sequence(5, n_frames=args.frames)
        src = f"synthetic (board.descent.synthetic, seed 5, {args.frames} frames in memory)"
    rows = [bench(seq, m, args.frames) for m in ("dual", "visible-64")]
    print(f"source: {src}; load average {os.getloadavg()}; RSS after imports {base:.0f} MB")
    print("| mode | frames | landmarks | state size | CPU ms/step mean | median | max | wall ms mean | max | "
          "peak RSS MB |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['mode']} | {r['frames']} | {r['landmarks']} | {r['state']} | {r['cpu_mean']:.0f} | "
              f"{r['cpu_median']:.0f} | {r['cpu_max']:.0f} | {r['wall_mean']:.0f} | {r['wall_max']:.0f} | "
              f"{r['rss_mb']:.0f} |")


if __name__ == "__main__":
    main()
