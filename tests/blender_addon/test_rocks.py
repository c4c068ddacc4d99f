"""Rocks: the size-frequency law (fitted exponent), placement, meshes."""
from __future__ import annotations

import numpy as np
import pytest

from blender_addon.core.rocks import (
    bilinear_height, expected_count, fit_power_law_exponent, icosphere, place_rocks, rock_mesh, sample_power_law,
)
from board.errors import InvalidInputError


@pytest.mark.parametrize("b", [1.5, 2.5, 3.2])
def test_sampled_sizes_follow_the_power_law(b):
    d = sample_power_law(40_000, 0.05, 2.0, b, np.random.default_rng(int(b * 10)))
    assert d.min() >= 0.05 and d.max() <= 2.0
    # MLE of the exponent: standard error ~ b / sqrt(n) = 0.5 % of b
    assert fit_power_law_exponent(d, 0.05, 2.0) == pytest.approx(b, rel=0.03)
    # and the empirical cumulative count matches the law at a few diameters
    r = (2.0 / 0.05) ** -b
    for q in (0.1, 0.2, 0.5):
        expected = ((q / 0.05) ** -b - r) / (1 - r)
        assert (d > q).mean() == pytest.approx(expected, abs=4 * np.sqrt(expected / d.size) + 1e-3)


def test_placement_density_keep_out_and_near_rocks():
    rng = np.random.default_rng(7)
    kw = dict(density_per_m2=0.5, d_min_m=0.05, d_max_m=1.0, exponent=2.5, radius_m=30.0, near_count=4,
              near_distance_m=(2.0, 5.0), near_diameter_m=(0.8, 1.2))
    f = place_rocks((1000.0, 2000.0), rng, **kw)
    mean = expected_count(0.5, 30.0, 1.2)
    n_far = int((~f.near).sum())
    assert abs(n_far - mean) < 5 * np.sqrt(mean)
    r = np.hypot(f.x - 1000.0, f.y - 2000.0)
    assert (r <= 30.0 + 1e-9).all()
    assert (r >= 1.2 + f.diameter / 2 - 1e-9).all()
    assert f.near.sum() == 4
    assert ((r[f.near] >= 2.0) & (r[f.near] <= 5.0)).all()
    assert ((f.diameter[f.near] >= 0.8) & (f.diameter[f.near] <= 1.2)).all()
    # uniform over the disc: half the far rocks lie beyond radius sqrt((30^2 + 1.2^2) / 2)
    assert np.mean(r[~f.near] > np.sqrt((30 ** 2 + 1.2 ** 2) / 2)) == pytest.approx(0.5, abs=0.05)
    g = place_rocks((0.0, 0.0), np.random.default_rng(7), **kw)
    np.testing.assert_array_equal(f.diameter, g.diameter)     # same seed, same rocks
    with pytest.raises(InvalidInputError, match="lower rocks.density_per_m2"):
        place_rocks((0, 0), rng, density_per_m2=100, d_min_m=0.01, d_max_m=1, exponent=2, radius_m=100)


def test_icosphere_is_closed_and_outward():
    v, f = icosphere(2)
    assert v.shape == (162, 3) and f.shape == (320, 3)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0)
    # every edge shared by exactly two faces, and the signed volume is positive (outward winding)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all()
    vol = np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6
    assert vol == pytest.approx(4 / 3 * np.pi, rel=0.1)


def test_rock_mesh_sits_on_the_ground():
    rng = np.random.default_rng(3)
    f = place_rocks((0.0, 0.0), rng, density_per_m2=0.2, d_min_m=0.1, d_max_m=0.8, exponent=2.0, radius_m=10.0)
    ground = np.linspace(5.0, 6.0, len(f))
    verts, faces = rock_mesh(f, ground, rng, origin=(0.0, 0.0, 1.0))
    assert faces.max() < len(verts)
    # each rock's footprint is no wider than its diameter (+ bumps) and its base is slightly buried
    start = 0
    for i in range(len(f)):
        nv = 162 if f.diameter[i] >= 0.15 else 42
        vi = verts[start:start + nv]
        start += nv
        assert np.hypot(vi[:, 0] - f.x[i], vi[:, 1] - f.y[i]).max() <= 0.8 * f.diameter[i]
        assert vi[:, 2].min() + 1.0 < ground[i] < vi[:, 2].max() + 1.0
    assert start == len(verts)


def test_bilinear_height_on_a_plane():
    x0, y0, cell = 100.0, 500.0, 2.0
    rows, cols = 20, 30
    xs = x0 + (np.arange(cols) + 0.5) * cell
    ys = y0 - (np.arange(rows) + 0.5) * cell
    X, Y = np.meshgrid(xs, ys)
    z = 0.3 * X - 0.1 * Y + 7
    px = np.array([110.3, 140.0, 151.9])
    py = np.array([480.2, 470.0, 461.1])
    np.testing.assert_allclose(bilinear_height(z, x0, y0, cell, px, py), 0.3 * px - 0.1 * py + 7, atol=1e-9)
