"""Camera sensor models: scene radiance / temperature to stored counts.

Visible camera (``VisibleSensor``)
    ``ideal`` (default, the memorandum's mode): a fixed exposure maps the unitless brightness of
    :mod:`brdf` linearly to 8-bit counts, ``count = round(clip(E / full_scale, 0, 1) * 255)``.
    ``noisy``: the exposure fills ``exposure`` of the full well at brightness ``full_scale``; photon
    (Poisson) noise, Gaussian read noise (electrons), saturation at the full well, 12-bit ADC.
Thermal camera (``ThermalSensor``), 14-bit radiometric output in kelvin (value = 0.01 K x count)
    ``ideal`` (default): the surface's kinetic temperature, quantised (the memorandum's mode).
    ``noisy``: in-band radiance ``eps B_band(T)`` through Planck over the camera's band (default
    17-50 um: at Europa's 80-130 K an 8-14 um band sees almost nothing), temporal noise of a constant
    noise-equivalent radiance (so the NETD in kelvin grows as the scene cools: NETD(T) = NEL / dB/dT),
    fixed-pattern noise (per-pixel gain and offset, fixed per camera), then the brightness
    temperature (the black-body temperature of the measured radiance) is stored.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from board.descent.sequence import Radiometric
from board.errors import InvalidInputError

from .constants import C_LIGHT, EMISSIVITY, H_PLANCK, K_BOLTZMANN

THERMAL_SCALE_K = 0.01
THERMAL_BITS = 14


def planck_band_radiance(t_k, band_um: tuple[float, float], *, n: int = 400) -> np.ndarray:
    """Black-body radiance (W m-2 sr-1) integrated over ``band_um`` (micrometres) at temperature(s) ``t_k``.

    B_lambda(T) = 2 h c^2 / lambda^5 / (exp(h c / (lambda k T)) - 1), trapezoidal rule over ``n`` wavelengths.
    """
    lam = np.linspace(band_um[0], band_um[1], n) * 1e-6
    t = np.maximum(np.asarray(t_k, dtype=np.float64), 1e-3)[..., None]
    with np.errstate(over="ignore"):
        b = 2.0 * H_PLANCK * C_LIGHT ** 2 / lam ** 5 / np.expm1(H_PLANCK * C_LIGHT / (lam * K_BOLTZMANN * t))
    return np.sum(0.5 * (b[..., 1:] + b[..., :-1]) * np.diff(lam), axis=-1)


@dataclass(frozen=True)
class VisibleSensor:
    """Visible camera: mode "ideal" (8-bit) or "noisy" (12-bit, photon + read noise, saturation)."""

    mode: str = "ideal"
    full_scale: float = 1.6
    full_well_e: float = 20000.0
    read_noise_e: float = 15.0
    exposure: float = 0.9

    def __post_init__(self) -> None:
        if self.mode not in ("ideal", "noisy"):
            raise InvalidInputError(f"visible sensor mode {self.mode!r}: use ideal or noisy")

    @property
    def bit_depth(self) -> int:
        return 8 if self.mode == "ideal" else 12

    def counts(self, brightness: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Stored counts (uint8 ideal, uint16 noisy) of a brightness image (unitless, NaN = nothing seen)."""
        e = np.nan_to_num(np.asarray(brightness, dtype=np.float64), nan=0.0)
        top = 2 ** self.bit_depth - 1
        if self.mode == "ideal":
            return np.rint(np.clip(e / self.full_scale, 0.0, 1.0) * top).astype(np.uint8)
        electrons = rng.poisson(np.clip(e / self.full_scale, 0.0, None) * self.exposure * self.full_well_e)
        electrons = np.minimum(electrons + rng.normal(0.0, self.read_noise_e, e.shape), self.full_well_e)
        return np.clip(np.rint(electrons / self.full_well_e * top), 0, top).astype(np.uint16)

    def describe(self) -> dict:
        return {"mode": self.mode, "full_scale": self.full_scale, "full_well_e": self.full_well_e,
                "read_noise_e": self.read_noise_e, "exposure": self.exposure}


@dataclass(frozen=True)
class ThermalSensor:
    """Thermal camera: mode "ideal" or "noisy"; 14-bit counts of 0.01 K (brightness temperature when noisy).

    band_um : spectral band (micrometres); netd_ref_k : NETD (K) at ``t_ref_k``; fpn_gain, fpn_offset_k :
    1-sigma fixed-pattern gain (fraction) and offset (K at t_ref); fpn_seed : the camera's own pattern.
    """

    mode: str = "ideal"
    band_um: tuple[float, float] = (17.0, 50.0)
    netd_ref_k: float = 0.1
    t_ref_k: float = 110.0
    fpn_gain: float = 0.005
    fpn_offset_k: float = 0.1
    fpn_seed: int = 7
    emissivity: float = EMISSIVITY
    _tables: dict = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.mode not in ("ideal", "noisy"):
            raise InvalidInputError(f"thermal sensor mode {self.mode!r}: use ideal or noisy")

    @property
    def bit_depth(self) -> int:
        return THERMAL_BITS

    @property
    def radiometric(self) -> Radiometric:
        return Radiometric("K", THERMAL_SCALE_K, 0.0, self.band_um)

    def _table(self):
        if "t" not in self._tables:
            t = np.linspace(1.0, THERMAL_SCALE_K * (2 ** THERMAL_BITS - 1) + 50.0, 4000)
            self._tables["t"] = t
            self._tables["b"] = planck_band_radiance(t, self.band_um)
        return self._tables["t"], self._tables["b"]

    def netd_k(self, t_k) -> np.ndarray:
        """Noise-equivalent temperature difference (K) at scene temperature(s) ``t_k``: constant NEL / dB/dT."""
        t, b = self._table()
        dbdt = np.gradient(b, t)
        nel = self.netd_ref_k * float(np.interp(self.t_ref_k, t, dbdt))
        return nel / np.interp(np.asarray(t_k, dtype=np.float64), t, dbdt)

    def fixed_pattern(self, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """Per-pixel (gain, offset radiance W m-2 sr-1) of this camera (same every frame and trial)."""
        key = ("fpn", shape)
        if key not in self._tables:
            rng = np.random.Generator(np.random.PCG64([self.fpn_seed, *shape]))
            t, b = self._table()
            dbdt_ref = float(np.interp(self.t_ref_k, t, np.gradient(b, t)))
            self._tables[key] = (1.0 + self.fpn_gain * rng.standard_normal(shape),
                                 self.fpn_offset_k * dbdt_ref * rng.standard_normal(shape))
        return self._tables[key]

    def counts(self, temperature_k: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Stored 14-bit counts (uint16, 0.01 K) of a temperature image (K; NaN = nothing seen, stored 0)."""
        tk = np.asarray(temperature_k, dtype=np.float64)
        if self.mode == "noisy":
            t, b = self._table()
            gain, off = self.fixed_pattern(tk.shape)
            lrad = self.emissivity * np.interp(np.nan_to_num(tk, nan=1.0), t, b)
            nel = self.netd_ref_k * float(np.interp(self.t_ref_k, t, np.gradient(b, t)))
            lrad = gain * lrad + off + nel * rng.standard_normal(tk.shape)
            tk = np.where(np.isnan(tk), np.nan, np.interp(lrad, b, t))
        return self.radiometric.to_counts(np.nan_to_num(tk, nan=0.0), THERMAL_BITS)

    def describe(self) -> dict:
        return {"mode": self.mode, "band_um": list(self.band_um), "netd_ref_k": self.netd_ref_k,
                "t_ref_k": self.t_ref_k, "fpn_gain": self.fpn_gain, "fpn_offset_k": self.fpn_offset_k,
                "stored": "brightness temperature" if self.mode == "noisy" else "surface temperature"}
