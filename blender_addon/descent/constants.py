"""Physical constants and Europa's published values used by the descent simulator (SI units).

Sources: the NASA memorandum (seed 000, section 4: irradiances, apparent sizes, Bond albedo,
emissivity), Spencer et al. 1999 (Galileo PPR: Europa's night-side 86-132 K, thermal inertia
~70 SI), Rathbun et al. 2010 (thermal inertia 40-140 SI), Domingue et al. 1991 / Buratti 1995
(Hapke parameters), IAU / JPL (radius, gravity, orbital period = day).
"""
from __future__ import annotations

from board.conventions import BODIES

#: Stefan-Boltzmann constant, W m-2 K-4 (CODATA 2018, exact).
SIGMA_SB = 5.670374419e-8
#: Planck constant (J s), speed of light (m/s), Boltzmann constant (J/K) (CODATA 2018, exact).
H_PLANCK = 6.62607015e-34
C_LIGHT = 299_792_458.0
K_BOLTZMANN = 1.380649e-23

#: Europa's mean radius (m), from board.conventions.
EUROPA_RADIUS_M = BODIES["europa"].radius_m
#: Europa's surface gravity, m/s2 (GM = 3202.7 km3/s2 over R^2).
EUROPA_GRAVITY_MPS2 = 1.315
#: Europa's solar day = its orbital period (synchronous rotation), seconds (3.5512 d = 85.2 h).
EUROPA_DAY_S = 3.5512 * 86400.0

#: Memorandum section 4.3: irradiances at normal incidence (W/m2) and apparent diameters (arcmin).
SUN_IRRADIANCE_W_M2 = 50.0
JUPITER_REFLECTED_IRRADIANCE_W_M2 = 0.0897
JUPITER_REFLECTED_SUN_W_M2 = 0.0001       # "the reflection of the Sun in Jupiter"
SUN_DIAMETER_ARCMIN = 6.14
JUPITER_DIAMETER_ARCMIN = 717.55
#: Jupiter's own thermal emission at Europa (W/m2, normal incidence): sigma T_eff^4 (R_J / a)^2 with
#: T_eff = 124.4 K, R_J = 71 492 km, a = 671 100 km (not in the memorandum; the conduction mode's extra source).
JUPITER_THERMAL_IRRADIANCE_W_M2 = SIGMA_SB * 124.4 ** 4 * (71_492.0 / 671_100.0) ** 2

#: Memorandum section 4.3: bolometric Bond albedo and emissivity of the ice surface.
BOND_ALBEDO = 0.68
EMISSIVITY = 0.94

#: Thermal inertia of Europa's surface, J m-2 K-1 s-1/2 (Rathbun et al. 2010: 40-140; Spencer 1999: 70).
THERMAL_INERTIA_SI = 70.0
#: Water ice regolith: bulk density (kg/m3) and heat capacity (J/kg/K) at ~100 K.
REGOLITH_DENSITY_KG_M3 = 500.0
ICE_HEAT_CAPACITY_J_KG_K = 840.0

#: Hapke parameters of Europa's leading/trailing average (Domingue et al. 1991; Buratti 1995):
#: single-scattering albedo w, opposition-surge amplitude B0 and width h, macroscopic roughness (deg),
#: one-term Henyey-Greenstein asymmetry g (negative = backscattering).
HAPKE_W = 0.96
HAPKE_B0 = 0.5
HAPKE_H = 0.0016
HAPKE_THETA_BAR_DEG = 10.0
HAPKE_G = -0.3
#: Europa's normal albedo, the centre of the memorandum's randomised albedo maps.
EUROPA_ALBEDO = 0.67
