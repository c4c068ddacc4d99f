"""Surface temperature models (kelvin) of the terrain grid.

``instantaneous`` (the memorandum's section 4.3, ``--thermal-model tm``)
    absorbed flux ``F = (1 - A) * sum_s E_s max(0, n . l_s) * lit_s`` (A the bolometric Bond albedo;
    Jupiter's thermal emission, when present, is absorbed with the emissivity instead), temperature
    of a grey body in radiative balance ``T = (F / (eps sigma))^(1/4)``, then ``passes`` passes of a
    3x3 box filter as the first-order lateral diffusion.
``conduction`` (``--thermal-model conduction``)
    1-D heat conduction into the ground over Europa's 85.2 h day, periodic steady state, with a
    thermal inertia ``Gamma = sqrt(k rho c)``: ``rho c dT/dt = d/dz (k dT/dz)``, surface balance
    ``eps sigma T^4 = F(t) + k dT/dz``, no flux at the bottom (6 diurnal skin depths).  The Sun follows
    the equatorial east-west path through the zenith; the facet's temperature at the Sun's current
    hour angle is interpolated from a table over facet orientation (no cast-shadow history).

Normals are (ny, nx, 3) unit world vectors (x east, y north, z up).
"""
from __future__ import annotations

import logging
import math

import numpy as np

from board.errors import InvalidInputError

from .constants import (BOND_ALBEDO, EMISSIVITY, EUROPA_DAY_S, ICE_HEAT_CAPACITY_J_KG_K, REGOLITH_DENSITY_KG_M3,
                        SIGMA_SB, THERMAL_INERTIA_SI)
from .lights import Light

log = logging.getLogger(__name__)

#: Memorandum: "several smoothing passes"; we use 3 passes of a 3x3 box by default.
DEFAULT_SMOOTHING_PASSES = 3


def absorbed_flux(normals, lights: list[Light], *, lit: dict[str, np.ndarray] | None = None,
                  bond_albedo: float = BOND_ALBEDO, emissivity: float = EMISSIVITY) -> np.ndarray:
    """Absorbed flux (W/m2) of facets with unit ``normals`` (..., 3) under ``lights``.

    Sunlight and reflected light are absorbed with ``1 - bond_albedo``; a "thermal" light (infrared)
    with ``emissivity`` (Kirchhoff).  ``lit[name]`` (0..1, shape of the facets) scales a source for
    cast shadows; absent = N.L shading only (the memorandum's "shades from the DEM's gradient").
    """
    n = np.asarray(normals, dtype=np.float64)
    f = np.zeros(n.shape[:-1])
    for s in lights:
        cos = np.clip(n @ s.direction, 0.0, None)
        absorb = emissivity if s.kind == "thermal" else 1.0 - bond_albedo
        shade = 1.0 if lit is None or s.name not in lit else lit[s.name]
        f += absorb * s.irradiance_w_m2 * cos * shade
    return f


def radiative_equilibrium_k(flux_w_m2, *, emissivity: float = EMISSIVITY) -> np.ndarray:
    """Grey-body temperature (K) in radiative balance with an absorbed flux: ``(F / (eps sigma))^(1/4)``."""
    return (np.clip(np.asarray(flux_w_m2, dtype=np.float64), 0.0, None) / (emissivity * SIGMA_SB)) ** 0.25


def box_smooth(t: np.ndarray, passes: int) -> np.ndarray:
    """``passes`` passes of a 3x3 mean filter (edges replicated): the memorandum's thermal smoothing."""
    out = np.asarray(t, dtype=np.float64)
    for _ in range(int(passes)):
        p = np.pad(out, 1, mode="edge")
        out = sum(p[1 + dy:p.shape[0] - 1 + dy, 1 + dx:p.shape[1] - 1 + dx]
                  for dy in (-1, 0, 1) for dx in (-1, 0, 1)) / 9.0
    return out


def instantaneous_temperature(normals, lights: list[Light], *, lit=None, passes: int = DEFAULT_SMOOTHING_PASSES,
                              bond_albedo: float = BOND_ALBEDO, emissivity: float = EMISSIVITY) -> np.ndarray:
    """The memorandum's thermal model: radiative balance of the absorbed flux, then box smoothing (K)."""
    t = radiative_equilibrium_k(absorbed_flux(normals, lights, lit=lit, bond_albedo=bond_albedo,
                                              emissivity=emissivity), emissivity=emissivity)
    return box_smooth(t, passes) if np.ndim(t) == 2 else t


# -- 1-D conduction ---------------------------------------------------------------------------------
def sun_hour_angle_rad(sun: Light) -> float:
    """Hour angle (rad) of the Sun on the equatorial path: -pi/2 rising in the east, 0 at the zenith, +pi/2 setting."""
    d = sun.direction
    return math.atan2(-d[0], d[2])


def _sun_path(hour_angle):
    """(..., 3) unit world direction of the Sun at hour angle(s) (rad) on the equatorial east-west path."""
    h = np.asarray(hour_angle, dtype=np.float64)
    return np.stack([-np.sin(h), np.zeros_like(h), np.cos(h)], axis=-1)


def conduction_surface_temperature(normals, lights: list[Light], *, thermal_inertia: float = THERMAL_INERTIA_SI,
                                   hour_angle_rad: float | None = None, day_s: float = EUROPA_DAY_S,
                                   bond_albedo: float = BOND_ALBEDO, emissivity: float = EMISSIVITY,
                                   density: float = REGOLITH_DENSITY_KG_M3,
                                   heat_capacity: float = ICE_HEAT_CAPACITY_J_KG_K, days: int = 8,
                                   steps_per_day: int = 360, n_layers: int = 30,
                                   return_history: bool = False):
    """Surface temperature (K) of facets (..., 3) in the periodic steady state of 1-D conduction.

    The "sun" light moves on the equatorial path (its current hour angle from its direction unless
    ``hour_angle_rad`` is given); other lights stay fixed.  Backward-Euler in time, a linearised
    radiative surface condition, geometric layers from skin/30 to 6 skin depths.
    return_history : also return (hour angles (steps,), temperatures (steps, ...)) of the last day.
    """
    if not (1.0 <= thermal_inertia <= 5000.0):
        raise InvalidInputError(f"thermal inertia {thermal_inertia} SI: use 1-5000 J m-2 K-1 s-1/2 "
                                "(Europa: 40-140)")
    n = np.asarray(normals, dtype=np.float64)
    shape = n.shape[:-1]
    n = n.reshape(-1, 3)
    suns = [s for s in lights if s.kind == "sun"]
    others = [s for s in lights if s.kind != "sun"]
    f_fixed = absorbed_flux(n, others, bond_albedo=bond_albedo, emissivity=emissivity)
    sun_e = sum(s.irradiance_w_m2 for s in suns)
    h_now = (sun_hour_angle_rad(suns[0]) if suns else 0.0) if hour_angle_rad is None else hour_angle_rad
    k_cond = thermal_inertia ** 2 / (density * heat_capacity)
    kappa = k_cond / (density * heat_capacity)
    skin = math.sqrt(kappa * day_s / math.pi)
    # layer thicknesses: geometric from skin/30, total >= 6 skin depths
    dz0 = skin / 30.0
    ratio = 1.0
    while dz0 * (ratio ** n_layers - 1) / max(ratio - 1, 1e-12) < 6 * skin if ratio > 1 else dz0 * n_layers < 6 * skin:
        ratio += 0.005
    dz = dz0 * ratio ** np.arange(n_layers)
    dt = day_s / steps_per_day
    cap = density * heat_capacity * dz                    # J/m2/K per layer
    cond = k_cond / (0.5 * (dz[:-1] + dz[1:]))            # W/m2/K between layers
    hours = -math.pi + 2 * math.pi * (np.arange(steps_per_day) + 0.5) / steps_per_day
    sun_dirs = _sun_path(hours)                            # (steps, 3)
    flux_day = f_fixed[None, :] + (1 - bond_albedo) * sun_e * np.clip(sun_dirs @ n.T, 0.0, None)
    # start every facet near its own deep temperature (the day-mean balance), so facets converge alike
    t0 = 0.95 * radiative_equilibrium_k(flux_day.mean(axis=0), emissivity=emissivity)
    t = np.repeat(t0[:, None], n_layers, axis=1)
    # tridiagonal system per facet: a_j T_{j-1} + b_j T_j + c_j T_{j+1} = d_j
    lower = np.concatenate([[0.0], -cond])
    upper = np.concatenate([-cond, [0.0]])
    diag0 = cap / dt + np.concatenate([cond, [0.0]]) + np.concatenate([[0.0], cond])
    history = np.empty((steps_per_day, n.shape[0]))
    for day in range(days):
        for step in range(steps_per_day):
            ts = t[:, 0]
            rad_lin = 4.0 * emissivity * SIGMA_SB * ts ** 3
            b = np.broadcast_to(diag0, t.shape).copy()
            b[:, 0] += rad_lin
            d = t * (cap / dt)
            d[:, 0] += flux_day[step] + 3.0 * emissivity * SIGMA_SB * ts ** 4
            # Thomas algorithm, vectorised over facets
            cp = np.empty_like(t)
            dp = np.empty_like(t)
            cp[:, 0] = upper[0] / b[:, 0]
            dp[:, 0] = d[:, 0] / b[:, 0]
            for j in range(1, n_layers):
                m = b[:, j] - lower[j] * cp[:, j - 1]
                cp[:, j] = upper[j] / m
                dp[:, j] = (d[:, j] - lower[j] * dp[:, j - 1]) / m
            t[:, -1] = dp[:, -1]
            for j in range(n_layers - 2, -1, -1):
                t[:, j] = dp[:, j] - cp[:, j] * t[:, j + 1]
            if day == days - 1:
                history[step] = t[:, 0]
    # surface temperature at the current hour angle: periodic linear interpolation of the last day
    pos = ((h_now + math.pi) / (2 * math.pi) * steps_per_day - 0.5) % steps_per_day
    i0 = int(math.floor(pos))
    w1 = pos - i0
    now = (1 - w1) * history[i0] + w1 * history[(i0 + 1) % steps_per_day]
    if return_history:
        return now.reshape(shape), hours, history.reshape((steps_per_day, *shape))
    return now.reshape(shape)


def conduction_temperature_map(normals: np.ndarray, lights: list[Light], *, table_size: int = 33,
                               passes: int = 1, **kw) -> np.ndarray:
    """Conduction temperatures (K) of a (ny, nx, 3) normal grid through a table over facet orientation.

    The table samples the normal's horizontal components (nx, ny) on a ``table_size``^2 grid over
    [-0.9, 0.9]^2 and is interpolated bilinearly; ``passes`` box passes smooth the result.
    """
    grid = np.linspace(-0.9, 0.9, table_size)
    gx, gy = np.meshgrid(grid, grid)
    gz = np.sqrt(np.clip(1.0 - gx ** 2 - gy ** 2, 0.01, None))
    tn = np.stack([gx, gy, gz], axis=-1)
    tn /= np.linalg.norm(tn, axis=-1, keepdims=True)
    table = conduction_surface_temperature(tn, lights, **kw)          # (table, table)
    nrm = np.asarray(normals, dtype=np.float64)
    step = grid[1] - grid[0]
    fx = np.clip((nrm[..., 0] - grid[0]) / step, 0, table_size - 1.000001)
    fy = np.clip((nrm[..., 1] - grid[0]) / step, 0, table_size - 1.000001)
    ix, iy = fx.astype(np.int64), fy.astype(np.int64)
    tx, ty = fx - ix, fy - iy
    out = ((1 - tx) * (1 - ty) * table[iy, ix] + tx * (1 - ty) * table[iy, ix + 1]
           + (1 - tx) * ty * table[iy + 1, ix] + tx * ty * table[iy + 1, ix + 1])
    return box_smooth(out, passes)
