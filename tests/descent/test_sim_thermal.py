"""Thermal models against analytic truths: radiative balance, energy conservation, Europa's observed range."""
import numpy as np
import pytest

from blender_addon.descent.constants import BOND_ALBEDO, EMISSIVITY, SIGMA_SB
from blender_addon.descent.lights import Light, default_lights
from blender_addon.descent.thermal import (absorbed_flux, box_smooth, conduction_surface_temperature,
                                           conduction_temperature_map, instantaneous_temperature)

UP = np.array([0.0, 0.0, 1.0])
#: a coarser spin-up where convergence is not what is tested
FAST = dict(days=4, steps_per_day=180, n_layers=20)


def test_flat_plate_matches_the_analytic_radiative_balance():
    lights = default_lights(sun_elevation_deg=30.0, jupiter_elevation_deg=60.0)
    # by hand: (1 - A) (50 sin 30 + (0.0897 + 0.0001) sin 60) + eps * E_jth sin 60 = eps sigma T^4
    e_jth = [s for s in lights if s.kind == "thermal"][0].irradiance_w_m2
    flux = (1 - 0.68) * (50.0 * 0.5 + 0.0898 * np.sin(np.radians(60))) + 0.94 * e_jth * np.sin(np.radians(60))
    t_hand = (flux / (0.94 * 5.670374419e-8)) ** 0.25
    plate = np.tile(UP, (40, 50, 1))
    t = instantaneous_temperature(plate, lights, passes=5)
    assert t.shape == (40, 50)
    np.testing.assert_allclose(t, t_hand, rtol=1e-12)
    assert 105.0 < t_hand < 115.0


def test_night_side_of_the_memorandum_model_is_about_27_kelvin():
    night = [s for s in default_lights() if s.name in ("jupiter", "jupiter_sun_glint")]
    night = [Light(s.name, s.azimuth_deg, 90.0, s.irradiance_w_m2, s.apparent_diameter_arcmin, s.kind) for s in night]
    t = instantaneous_temperature(UP[None], night, passes=0)[0]
    assert t == pytest.approx(((1 - BOND_ALBEDO) * 0.0898 / (EMISSIVITY * SIGMA_SB)) ** 0.25, rel=1e-12)
    assert 26.0 < t < 28.0


def test_facet_turned_away_gets_nothing_and_cast_shadows_remove_the_sun():
    sun = Light("sun", 90.0, 30.0, 50.0, 6.14)
    west = np.array([-np.sin(np.radians(40)), 0.0, np.cos(np.radians(40))])   # tilted 40 deg to the west
    assert absorbed_flux(west[None], [sun])[0] == 0.0
    assert absorbed_flux(UP[None], [sun], lit={"sun": np.zeros(1)})[0] == 0.0


def test_box_smoothing_keeps_uniform_fields_and_the_mean_of_a_periodic_bump():
    assert np.allclose(box_smooth(np.full((9, 9), 80.0), 4), 80.0)
    a = np.zeros((21, 21))
    a[10, 10] = 81.0
    s = box_smooth(a, 1)
    assert s[9:12, 9:12] == pytest.approx(np.full((3, 3), 9.0)) and s.sum() == pytest.approx(81.0)


def test_conduction_conserves_energy_over_the_day_and_gives_europa_night_temperatures():
    lights = default_lights()
    now, hours, hist = conduction_surface_temperature(UP[None], lights, thermal_inertia=70.0, return_history=True)
    flux_day = absorbed_flux(UP[None], [s for s in lights if s.kind != "sun"])[0] + (1 - BOND_ALBEDO) * 50.0 * np.clip(
        np.cos(hours), 0.0, None)
    emitted = EMISSIVITY * SIGMA_SB * hist[:, 0] ** 4
    # periodic steady state: what is emitted over a day is what was absorbed (to the spin-up's convergence)
    assert emitted.mean() == pytest.approx(flux_day.mean(), rel=0.02)
    night = hist[np.cos(hours) < 0, 0]
    # Galileo PPR night-side 86-132 K (Spencer 1999); the instantaneous balance would give ~30 K
    assert 75.0 < night.min() < 100.0 and night.max() < 132.0
    assert hist[:, 0].max() < (flux_day.max() / (EMISSIVITY * SIGMA_SB)) ** 0.25


def test_low_thermal_inertia_follows_the_instantaneous_balance():
    lights = [Light("sun", 90.0, 45.0, 50.0, 6.14)]
    t_cond = conduction_surface_temperature(UP[None], lights, thermal_inertia=2.0, **FAST)[0]
    t_inst = instantaneous_temperature(UP[None], lights, passes=0)[0]
    assert t_cond == pytest.approx(t_inst, abs=2.0)


def test_conduction_map_interpolates_the_orientation_table():
    lights = default_lights()
    rng = np.random.default_rng(3)
    n = rng.normal(size=(4, 5, 3)) * [0.3, 0.3, 0.0] + [0, 0, 1]
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    direct = conduction_surface_temperature(n, lights, **FAST)
    mapped = conduction_temperature_map(n, lights, passes=0, table_size=33, **FAST)
    np.testing.assert_allclose(mapped, direct, atol=0.5)
