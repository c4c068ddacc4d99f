"""Benchmark of skyline extraction (issue 6): speed on a 3600 x 900 panorama and accuracy per scene.

Run with ``make bench-extract`` (``python -m benchmarks.bench_extract``).  Prints markdown tables:

1. time of the skyloc detector, the report's graph solved by dynamic programming, and the same
   graph solved the report's way (Dijkstra over the explicit graph, scipy.sparse.csgraph), all in
   the same run on the same image, with a check that DP and Dijkstra reach the same optimum;
2. panorama building from an acquisition (frames through the camera model and pan/tilt);
3. mean absolute pixel error against the analytic skyline for clean and degraded scenes
   (noise, dust, glare, black sky), skyloc vs the baseline, with the fraction of columns kept.

The machine's 2 cores are shared with other work: the load average is printed with the figures.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np

from board.acquisition import Panorama, PanoramaGeometry
from board.camera import CameraModel
from board.detect import detect_baseline, detect_skyline
from board.detect.baseline import baseline_graph
from board.detect.graph_dp import shortest_path_dp
from board.extraction import extract_from_panorama
from board.panorama import build_panorama
from board.synthetic import SceneLook, SkylineFunction, frame_plan, synth_acquisition, synth_panorama


def _u8(img: np.ndarray) -> np.ndarray:
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def _best_of(fn, repeat: int) -> tuple[tuple[float, float], object]:
    """Best (wall, CPU) seconds over ``repeat`` runs and the last result.  CPU time (all threads of
    this process) is what the algorithm costs; wall time also counts waiting for the shared cores."""
    best, out = (float("inf"), float("inf")), None
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        best = min(best, (time.perf_counter() - t, time.process_time() - c))
    return best, out


def dijkstra_report_way(node: np.ndarray, pair: np.ndarray, vert: np.ndarray) -> float:
    """Shortest source->sink distance over the explicit graph (scipy Dijkstra): the report's solver."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    H, W = node.shape
    ids = np.arange(H * W).reshape(H, W)
    src, dst, w = [], [], []
    for d in (-1, 0, 1):                       # (r + d, c - 1) -> (r, c)
        r = np.arange(max(0, -d), min(H, H - d))
        s = ids[r + d, :-1]
        t = ids[r, 1:]
        src.append(s.ravel()), dst.append(t.ravel()), w.append((pair[d + 1, r, 1:] + node[r, 1:]).ravel())
    src.append(ids[:-1].ravel()), dst.append(ids[1:].ravel()), w.append((vert[1:] + node[1:]).ravel())
    src.append(ids[1:].ravel()), dst.append(ids[:-1].ravel()), w.append((vert[1:] + node[:-1]).ravel())
    S, T = H * W, H * W + 1
    src.append(np.full(H, S)), dst.append(ids[:, 0]), w.append(node[:, 0])
    src.append(ids[:, -1]), dst.append(np.full(H, T)), w.append(np.zeros(H))
    src = np.concatenate(src)
    dst = np.concatenate(dst)
    w = np.concatenate(w).astype(np.float64) + 1e-9      # keep zero-cost edges as edges
    G = coo_matrix((w, (src, dst)), shape=(H * W + 2, H * W + 2)).tocsr()
    dist = dijkstra(G, indices=S, min_only=True)
    return float(dist[T] - 1e-9 * (W + 1))


def speed(width: int, height: int, repeat: int, with_dijkstra: bool) -> list[tuple[str, float, str]]:
    g = PanoramaGeometry.full_circle(width, height, elevation_top_deg=30.0, elevation_bottom_deg=-15.0)
    f = SkylineFunction.random(2026)
    img = _u8(synth_panorama(g, f, noise_sigma=0.02, seed=1))
    rows = []
    t_imp, _ = _best_of(lambda: detect_skyline(img, wrap=True), repeat)
    rows.append(("skyloc detector (sky regions, L1 DP, confidence), 360 wrap", t_imp, ""))
    t_ext, _ = _best_of(lambda: extract_from_panorama(Panorama(img, g)), repeat)
    rows.append(("skyloc extract_from_panorama (checks + detector + 1 deg samples)", t_ext, ""))
    t_base, _ = _best_of(lambda: detect_baseline(img, wrap=True), repeat)
    rows.append(("report baseline graph, solved by vectorised DP, 360 wrap", t_base, ""))
    t_feat, gr = _best_of(lambda: baseline_graph(img), 1)
    t_dp, res = _best_of(lambda: shortest_path_dp(gr.node, pair_cost=gr.pair, vert_cost=gr.vert), 1)
    rows.append(("report graph: features + costs only", t_feat, ""))
    rows.append(("report graph: DP solve, no wrap", t_dp, f"cost {res.cost:.4f}"))
    if with_dijkstra:
        t_dj, dist = _best_of(lambda: dijkstra_report_way(gr.node, gr.pair, gr.vert), 1)
        same = abs(dist - res.cost) <= 1e-3 * max(1.0, abs(res.cost))
        rows.append(("report graph: scipy Dijkstra over the explicit graph (build + solve), no wrap", t_dj,
                     f"cost {dist:.4f} ({'same optimum' if same else 'DIFFERENT optimum'}); "
                     f"CPU {t_dj[1] / max(t_imp[1], 1e-9):.0f}x the skyloc detector's"))
    return rows


def build_speed(n_frames: int, width: int, height: int) -> tuple[float, tuple[int, int]]:
    cam = CameraModel.from_fov(width, height, 60.0, k1=-0.15, k2=0.03)
    f = SkylineFunction.random(7)
    with tempfile.TemporaryDirectory() as d:
        synth_acquisition(d, cam, frame_plan(n_frames, (3.0,)), f, noise_sigma=0.01, pitch_deg=2.0, roll_deg=-1.0)
        t, pano = _best_of(lambda: build_panorama(d), 1)
    return t, pano.image.shape


SCENES = {
    "clean (noise 1%)": dict(noise_sigma=0.01),
    "noise 5%": dict(noise_sigma=0.05),
    "dust over 80 deg (90% haze)": dict(noise_sigma=0.02, look=SceneLook(dust=((40.0, 120.0, 0.9),))),
    "glare: 40 deg saturated": dict(noise_sigma=0.02, glare=(100.0, 140.0)),
    "black sky (Moon)": dict(noise_sigma=0.01, look=SceneLook(sky_top=0.03, sky_horizon=0.03, ground=0.5)),
}


def accuracy(width: int, height: int, seeds: list[int]) -> list[tuple]:
    g = PanoramaGeometry.full_circle(width, height, elevation_top_deg=30.0, elevation_bottom_deg=-15.0)
    az = g.azimuths_deg()
    out = []
    for name, kw in SCENES.items():
        mae, p95, kept, base_mae, status = [], [], [], [], []
        for seed in seeds:
            f = SkylineFunction.random(seed)
            img = synth_panorama(g, f, look=kw.get("look", SceneLook()), noise_sigma=kw["noise_sigma"], seed=seed)
            if "glare" in kw:
                sel = (az >= kw["glare"][0]) & (az <= kw["glare"][1])
                img[:, sel] = np.clip(img[:, sel] * 3.0, 0, 1)
            u8 = _u8(img)
            truth = g.row_of_el(f(az))
            res = extract_from_panorama(Panorama(u8, g))
            status.append(res.status)
            if res.detection is not None:
                e = np.abs(res.detection.line_row - truth)
                mae.append(np.nanmean(e))
                p95.append(np.nanpercentile(e, 95))
                kept.append(res.detection.valid.mean())
            base_mae.append(np.mean(np.abs(detect_baseline(u8, wrap=True) - truth)))
        out.append((name, float(np.mean(mae)), float(np.mean(p95)), float(np.mean(kept)), float(np.mean(base_mae)),
                    "/".join(sorted(set(status)))))
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=3600)
    ap.add_argument("--height", type=int, default=900)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-dijkstra", action="store_true", help="skip the slow Dijkstra reference")
    ap.add_argument("--seeds", type=int, default=3, help="scenes per accuracy row")
    args = ap.parse_args(argv)

    load = os.getloadavg()
    print(f"# skyline extraction benchmark ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
          f"load average {load[0]:.1f} on {os.cpu_count()} cores)\n")
    print(f"## Speed, {args.width} x {args.height} panorama (best of {args.repeat})\n")
    print("| step | wall (s) | CPU (s) | note |\n| --- | ---: | ---: | --- |")
    for name, (t, c), note in speed(args.width, args.height, args.repeat, not args.no_dijkstra):
        print(f"| {name} | {t:.3f} | {c:.3f} | {note} |")
    (t, c), shape = build_speed(8, 1024, 768)
    print(f"\n## Panorama building\n\n| frames | panorama (H x W) | wall (s) | CPU (s) |\n| --- | --- | ---: | ---: |\n"
          f"| 8 x 1024x768, distortion, levelled | {shape[0]} x {shape[1]} | {t:.3f} | {c:.3f} |")
    print(f"\n## Accuracy against the analytic skyline, {args.width} x {args.height}, "
          f"mean of {args.seeds} seeds (pixels)\n")
    print("| scene | skyloc MAE (kept columns) | skyloc p95 | columns kept | baseline MAE (all columns) | status |")
    print("| --- | ---: | ---: | ---: | ---: | --- |")
    for name, mae, p95, kept, base, status in accuracy(args.width, args.height, list(range(100, 100 + args.seeds))):
        print(f"| {name} | {mae:.3f} | {p95:.2f} | {100 * kept:.1f}% | {base:.2f} | {status} |")


if __name__ == "__main__":
    main()
