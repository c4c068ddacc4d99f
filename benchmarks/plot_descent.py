"""Pictures of the descent simulator for docs/descent.md.

Usage: python -m benchmarks.plot_descent [--out docs/img]

* ``descent_pair.png``: a co-registered visible / thermal frame pair (trajectory 3, t = 100 s);
* ``descent_temperature.png``: the temperature map of the terrain (memorandum model and 1-D
  conduction) with its range in kelvin;
* ``descent_trajectories.png``: the ten trajectories (trial 0) over the shaded terrain.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from blender_addon.descent.render import AppearanceOptions  # noqa: E402
from blender_addon.descent.simulate import DescentConfig, cached_renderer, trial_motion  # noqa: E402
from blender_addon.descent.trajectories import TRAJECTORIES  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/img")
    args = ap.parse_args()
    out = Path(args.out)
    cfg = DescentConfig(trajectory=3)
    r = cached_renderer(cfg.terrain, cfg.terrain_res_m, cfg.terrain_size_m, tuple(cfg.lights), cfg.appearance)
    tr = r.terrain
    m = trial_motion(cfg, tr)
    t = 100.0
    frame = r.render(cfg.cameras()["visible"], m.rotation([t])[0], m.position([t])[0])
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.6))
    ax[0].imshow(cfg.visible_sensor.counts(frame["visible"], None), cmap="gray", vmin=0, vmax=255)
    ax[0].set_title(f"visible (eq. 9), trajectory 3, t = {t:.0f} s, {m.position([t])[0][2] - tr.height.max():.0f} m "
                    "above the top")
    im = ax[1].imshow(frame["thermal"], cmap="inferno")
    ax[1].set_title("thermal (memorandum model), K")
    fig.colorbar(im, ax=ax[1], fraction=0.035)
    for a in ax:
        a.set_xticks([])
        a.set_yticks([])
    fig.tight_layout()
    fig.savefig(out / "descent_pair.png", dpi=90)
    plt.close(fig)

    cond = cached_renderer(cfg.terrain, cfg.terrain_res_m, cfg.terrain_size_m, tuple(cfg.lights),
                           AppearanceOptions(thermal="conduction"))
    ext = tr.bounds[0], tr.bounds[2], tr.bounds[1], tr.bounds[3]
    fig, ax = plt.subplots(1, 2, figsize=(12, 5.2))
    for a, temp, name in ((ax[0], r.temperature, "memorandum (instantaneous + 3 smoothing passes)"),
                          (ax[1], cond.temperature, "1-D conduction, thermal inertia 70 SI")):
        im = a.imshow(temp, origin="lower", extent=ext, cmap="inferno")
        a.set_title(f"{name}\n{temp.min():.1f} - {temp.max():.1f} K (Sun az 90, el 30)", fontsize=10)
        a.set_xlabel("x east (m)")
        fig.colorbar(im, ax=a, fraction=0.04, label="K")
    ax[0].set_ylabel("y north (m)")
    fig.tight_layout()
    fig.savefig(out / "descent_temperature.png", dpi=80)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(7.5, 7))
    shade = r.normals[..., 0] * -0.8 + r.normals[..., 2] * 0.6
    ax.imshow(shade, origin="lower", extent=ext, cmap="gray")
    ts = np.linspace(0, cfg.duration_s, 200)
    for tid, spec in TRAJECTORIES.items():
        p = trial_motion(DescentConfig(trajectory=tid), tr).position(ts)
        ax.plot(p[:, 0], p[:, 1], lw=1.6, label=f"{tid} {spec.name} ({p[0, 2] - tr.height.max():.0f}->"
                f"{p[-1, 2] - tr.height.max():.0f} m)")
        ax.plot(p[0, 0], p[0, 1], "o", ms=4, color=ax.lines[-1].get_color())
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_title("the ten trajectories (trial 0, start = dot; heights above the terrain top)")
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(out / "descent_trajectories.png", dpi=80)
    plt.close(fig)


if __name__ == "__main__":
    main()
