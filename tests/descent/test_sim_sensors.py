"""Camera sensor models against Planck / Stefan-Boltzmann and their stated noise."""
import math

import numpy as np
import pytest

from blender_addon.descent.constants import SIGMA_SB
from blender_addon.descent.sensors import ThermalSensor, VisibleSensor, planck_band_radiance


def test_band_radiance_over_the_whole_spectrum_is_stefan_boltzmann_over_pi():
    for t in (60.0, 100.0, 130.0):
        wide = planck_band_radiance(t, (2.0, 3000.0), n=200000)
        assert wide == pytest.approx(SIGMA_SB * t ** 4 / math.pi, rel=2e-3)
    # an 8-14 um band sees under 1 % of what the 17-50 um band sees of a 90 K scene
    assert planck_band_radiance(90.0, (8.0, 14.0)) < 0.01 * planck_band_radiance(90.0, (17.0, 50.0))


def test_netd_grows_as_the_scene_cools():
    s = ThermalSensor(mode="noisy")
    netd = s.netd_k([60.0, 80.0, 110.0, 130.0])
    assert netd[2] == pytest.approx(s.netd_ref_k, rel=1e-6)
    assert np.all(np.diff(netd) < 0) and netd[0] > 5 * netd[2]


def test_ideal_thermal_counts_are_the_temperature_in_hundredths_of_a_kelvin():
    s = ThermalSensor()
    t = np.array([[27.004, 131.2], [0.0, np.nan]])
    c = s.counts(t, None)
    assert c.dtype == np.uint16 and c.tolist() == [[2700, 13120], [0, 0]]
    np.testing.assert_allclose(s.radiometric.to_physical(c[0]), [27.0, 131.2])
    assert s.counts(np.array([500.0]), None)[0] == 2 ** 14 - 1        # 14-bit saturation


def test_noisy_thermal_temporal_noise_is_the_netd_and_the_pattern_is_fixed():
    s = ThermalSensor(mode="noisy")
    scene = np.full((120, 160), 95.0)
    a = s.counts(scene, np.random.default_rng(1)) * 0.01
    b = s.counts(scene, np.random.default_rng(2)) * 0.01
    # temporal noise: the difference of two frames cancels the fixed pattern, std = sqrt(2) NETD(95 K)
    std = np.std(a - b) / math.sqrt(2)
    assert std == pytest.approx(float(s.netd_k(95.0)), rel=0.05)
    # fixed pattern: the mean of many frames keeps a per-pixel structure of about fpn_offset_k
    gain, off = s.fixed_pattern(scene.shape)
    assert np.array_equal(gain, s.fixed_pattern(scene.shape)[0])
    mean = np.mean([s.counts(scene, np.random.default_rng(k)) * 0.01 for k in range(16)], axis=0)
    assert 0.5 * s.fpn_offset_k < np.std(mean) < 3 * s.fpn_offset_k


def test_visible_sensor_photon_and_read_noise_and_saturation():
    ideal = VisibleSensor()
    assert ideal.counts(np.array([0.0, 0.8, 1.6, 3.0, np.nan]), None).tolist() == [0, 128, 255, 255, 0]
    s = VisibleSensor(mode="noisy")
    e = np.full((200, 200), 0.8)                     # half of full scale -> 0.45 full wells of electrons
    c = s.counts(e, np.random.default_rng(0)).astype(float)
    electrons = 0.8 / s.full_scale * s.exposure * s.full_well_e
    gain = 4095 / s.full_well_e                       # counts per electron
    assert c.mean() == pytest.approx(electrons * gain, rel=2e-3)
    assert c.std() == pytest.approx(math.sqrt(electrons + s.read_noise_e ** 2) * gain, rel=0.03)
    sat = s.counts(np.full((10, 10), 5.0), np.random.default_rng(0))
    assert sat.min() == 4095 and sat.dtype == np.uint16
