"""The geometric precision of a campaign's poses: how far a skyline can pin the position at all.

A fix is a least-squares fit of the skyline's samples.  Near a pose, each 1-degree sample moves with the
position by the horizon's own gradient (degrees per metre, ray-marched here on the database's terrain at
+-1 m), with the heading by the skyline's slope, with pitch and roll by the first harmonic and with the
mean-offset term the matcher fits by a constant.  For errors that are white, ``sigma_deg`` per sample, the
least-squares (Cramer-Rao) standard deviation of x and y is ``sigma_deg * sqrt(diag((J^T J)^-1))``: no
detector and no matcher does better with that noise; correlated errors do worse.  On a flat lunar floor,
whose rims stand 20-40 km away, a metre moves the horizon by 0.15-0.3 millidegree, so a whole-chain error
of 0.003 deg per sample (a twentieth of a 1024 px NavCam pixel) already means 1.5 m per axis.

    python -m benchmarks.campaign_precision RUN [RUN ...] [--noise-deg 0.003] [--within-m 2.5] [--poses N]

Per pose: the gradient's size, sigma_x / sigma_y per 0.001 deg of white noise, and the chance the fix lands
within ``--within-m`` at ``--noise-deg``; per run, the share of poses expected within it and the white noise
per sample at which 90 % would be.  Metres in the DEM's metric CRS, degrees of elevation.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: the position step of the central differences, metres (the horizon is smooth over it: far rims move by
#: a fraction of a millidegree per metre; near horizons are what the database's 5 m grid interpolates)
DIFF_STEP_M = 1.0
#: the Jacobian's columns: x and y, then what a fix also estimates
COLUMNS = ("x", "y", "heading", "pitch", "roll", "offset")


@dataclass(frozen=True)
class Precision:
    """Geometric precision at one position.

    jacobian : (n_azimuth, 6) degrees of elevation per metre (x east, y north) and per degree (heading, pitch,
        roll, offset), columns :data:`COLUMNS`; cov_xy : (2, 2) covariance of x and y (m^2) per deg^2 of white
        noise per sample, the other parameters free; cov_xy_fixed_tilt : the same with pitch and roll known.
    """

    jacobian: np.ndarray
    cov_xy: np.ndarray
    cov_xy_fixed_tilt: np.ndarray

    @property
    def sigma_per_mdeg_m(self) -> np.ndarray:
        """(2,) standard deviation of x and y, metres per 0.001 deg of white noise per sample."""
        return 1e-3 * np.sqrt(np.diag(self.cov_xy))

    @property
    def sigma_fixed_tilt_per_mdeg_m(self) -> np.ndarray:
        """:attr:`sigma_per_mdeg_m` with pitch and roll known exactly."""
        return 1e-3 * np.sqrt(np.diag(self.cov_xy_fixed_tilt))

    @property
    def gradient_rms_deg_per_m(self) -> np.ndarray:
        """(2,) RMS over the azimuths of d(elevation)/dx, /dy, degrees per metre."""
        return np.sqrt(np.mean(self.jacobian[:, :2] ** 2, axis=0))

    def covariance_m2(self, noise_deg: float) -> np.ndarray:
        """(2, 2) covariance of x, y (m^2) for white noise of ``noise_deg`` per sample, nuisances free."""
        return float(noise_deg) ** 2 * self.cov_xy


def precision_from_jacobian(jac: np.ndarray) -> Precision:
    """:class:`Precision` of a (n, 6) Jacobian (columns :data:`COLUMNS`)."""
    jac = np.asarray(jac, dtype=np.float64)
    keep = [i for i, c in enumerate(COLUMNS) if c not in ("pitch", "roll")]
    return Precision(jac, np.linalg.inv(jac.T @ jac)[:2, :2], np.linalg.inv(jac[:, keep].T @ jac[:, keep])[:2, :2])


def horizon_jacobian(horizon, x: float, y: float, n_azimuth: int, step_m: float = DIFF_STEP_M) -> np.ndarray:
    """(n_azimuth, 6) Jacobian of the skyline at (x, y) (metres) from ``horizon(x, y)`` -> (n_azimuth,) degrees,
    sample k at azimuth k * 360 / n_azimuth from the first sample's (a shift of all samples leaves the
    information unchanged): central differences in x and y, the slope for the
    heading, cos / sin of the azimuth for pitch / roll, ones for the offset."""
    el0 = np.asarray(horizon(x, y), dtype=np.float64)
    if el0.shape != (n_azimuth,) or not np.isfinite(el0).all():
        raise ValueError(f"the horizon at ({x:.1f}, {y:.1f}) is not {n_azimuth} finite samples")
    jx = (np.asarray(horizon(x + step_m, y)) - np.asarray(horizon(x - step_m, y))) / (2.0 * step_m)
    jy = (np.asarray(horizon(x, y + step_m)) - np.asarray(horizon(x, y - step_m))) / (2.0 * step_m)
    az_step = 360.0 / n_azimuth
    slope = (np.roll(el0, -1) - np.roll(el0, 1)) / (2.0 * az_step)
    az = np.radians(np.arange(n_azimuth) * az_step)
    return np.stack([jx, jy, slope, np.cos(az), np.sin(az), np.ones(n_azimuth)], axis=1)


def share_within(cov_m2: np.ndarray, radius_m: float) -> float:
    """Probability that a zero-mean 2-D Gaussian of covariance ``cov_m2`` lands within ``radius_m`` (exact for
    a circular one, 1 - exp(-r^2 / 2 s^2); otherwise integrated over the angle)."""
    lam = np.clip(np.linalg.eigvalsh(np.asarray(cov_m2, dtype=np.float64)), 1e-30, None)
    t = np.linspace(0.0, 2.0 * math.pi, 721)[:-1]
    # in polar coordinates on the covariance's axes the density is exp(-r^2 / 2v(t)) / (2 pi sqrt(l1 l2)) with
    # 1 / v(t) = cos^2 t / l1 + sin^2 t / l2; its integral over r in [0, R] is v (1 - exp(-R^2 / 2v)), and the
    # mean over t times 2 pi is the integral over the angle
    v = 1.0 / (np.cos(t) ** 2 / lam[0] + np.sin(t) ** 2 / lam[1])
    inner = v * (1.0 - np.exp(-radius_m ** 2 / (2.0 * v))) / (2.0 * math.pi * math.sqrt(lam[0] * lam[1]))
    return float(np.mean(inner) * 2.0 * math.pi)


def run_precision(run: Path, *, poses: int | None = None) -> list[tuple[dict, Precision]]:
    """Every accepted pose of a finished campaign folder (or the first ``poses``) and its :class:`Precision` on
    the database's terrain, at the database's camera height and azimuth sampling (box samples as stored)."""
    from board.skydb import SkyDB
    from render_service.renderers.base import RenderSpec
    from render_service.renderers.raymarch import horizon_at
    from render_service.workers import worker_terrain

    db = SkyDB.open(run / "db.zarr")
    meta = db.meta
    terrain = worker_terrain(str(run / "terrain" / "db"))
    spec = RenderSpec(camera_height_m=meta.camera_height_m, n_azimuth=meta.n_azimuth,
                      azimuth_start_deg=meta.azimuth_start_deg, azimuth_subsamples=meta.azimuth_subsamples,
                      body_radius_m=float(terrain.body.radius_m))
    rays = spec.ray_spec()

    def horizon(x: float, y: float) -> np.ndarray:
        # each sample the mean of its rays as RenderSpec.box_mean takes it, kept in float64: the central
        # differences subtract elevations of ~10 deg that differ by ~0.0003 deg
        _, el, _ = horizon_at(terrain, x, y, rays)
        return np.asarray(el, dtype=np.float64).reshape(meta.n_azimuth, spec.azimuth_subsamples).mean(axis=1)

    accepted = json.loads((run / "poses.json").read_text())["accepted"][:poses]
    return [(p, precision_from_jacobian(horizon_jacobian(horizon, p["x"], p["y"], meta.n_azimuth)))
            for p in accepted]


def noise_for_share(precs: list[Precision], radius_m: float, share: float = 0.9) -> float:
    """The white noise per sample (degrees) at which ``share`` of these poses' expected fixes fall within
    ``radius_m`` (bisection on the mean of :func:`share_within`)."""
    lo, hi = 1e-6, 1.0
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        got = np.mean([share_within(p.covariance_m2(mid), radius_m) for p in precs])
        lo, hi = (mid, hi) if got >= share else (lo, mid)
    return lo


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="campaign output folders (poses.json, db.zarr, terrain/db)")
    ap.add_argument("--noise-deg", type=float, default=0.003,
                    help="white error per 1-degree sample of the whole chain (default 0.003 deg)")
    ap.add_argument("--within-m", type=float, default=2.5, help="the target radius (default 2.5 m)")
    ap.add_argument("--poses", type=int, default=None, help="only the first N poses")
    a = ap.parse_args(argv)
    if not (a.noise_deg > 0 and a.within_m > 0):
        print("--noise-deg and --within-m must be positive", file=sys.stderr)
        return 2
    for run in a.runs:
        missing = [f for f in ("poses.json", "db.zarr", "terrain/db") if not (run / f).exists()]
        if missing:
            print(f"{run}: not a finished campaign folder (missing {', '.join(missing)})", file=sys.stderr)
            return 2
        rows = run_precision(run, poses=a.poses)
        print(f"\n{run}: {len(rows)} poses, white noise {a.noise_deg} deg per sample, target {a.within_m} m")
        print("| pose | gradient RMS x / y (mdeg/m) | sigma x / y per 0.001 deg (m) | same, tilt known (m) | "
              f"P(within {a.within_m} m) |")
        print("| ---: | --- | --- | --- | ---: |")
        shares = []
        for p, pr in rows:
            s = share_within(pr.covariance_m2(a.noise_deg), a.within_m)
            shares.append(s)
            g, sg, sf = 1e3 * pr.gradient_rms_deg_per_m, pr.sigma_per_mdeg_m, pr.sigma_fixed_tilt_per_mdeg_m
            print(f"| {p['index']} | {g[0]:.3f} / {g[1]:.3f} | {sg[0]:.2f} / {sg[1]:.2f} | {sf[0]:.2f} / {sf[1]:.2f} "
                  f"| {s:.0%} |")
        need = noise_for_share([pr for _, pr in rows], a.within_m)
        print(f"summary: expected within {a.within_m} m {np.mean(shares):.0%} of the poses at {a.noise_deg} deg; "
              f"90 % needs white noise <= {need:.4f} deg per sample")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
