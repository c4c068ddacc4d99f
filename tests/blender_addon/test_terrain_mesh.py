"""Terrain meshes (bpy-free): heights and curvature, level nesting without cracks, skirts, chunking,
near-field refinement, and the curved scene's local vertical."""
from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator

from blender_addon.core.terrain_mesh import (SceneOffset, level_chunks, local_up_enu, quad_mask, refine_near_field,
                                             sample_height, scene_z, terrain_chunks)
from blender_addon.terrain.model import MultiResTerrain, TerrainLevel
from board.conventions import BODIES, Body


def _terrain(seed: int = 0, *, nan: bool = False) -> MultiResTerrain:
    rng = np.random.default_rng(seed)
    fine = rng.normal(0, 3, (40, 50)).astype(np.float32)         # 2 m cells, x -50..50, y -40..40
    coarse = rng.normal(0, 10, (30, 30)).astype(np.float32)      # 10 m cells, x -150..150
    if nan:
        fine[10:13, 20:22] = np.nan
    return MultiResTerrain([TerrainLevel(fine, -50.0, 40.0, 2.0), TerrainLevel(coarse, -150.0, 150.0, 10.0)],
                           "", BODIES["mars"], (0.0, 0.0))


def _centres(lev: TerrainLevel):
    rows, cols = lev.array.shape
    return lev.x0 + (np.arange(cols) + 0.5) * lev.cell_m, lev.y0 - (np.arange(rows) + 0.5) * lev.cell_m


def test_vertices_are_cell_centres_with_offset_and_curvature_drop():
    t = _terrain()
    off = SceneOffset(3.0, -2.0, 100.0)
    R = 5000.0                                                   # tiny body: a visible drop
    chunk = next(level_chunks(t, 0, offset=off, radius_m=R, chunk_cells=1000))
    top = chunk.vertices[: len(chunk.vertices) - 0]
    xs, ys = _centres(t.levels[0])
    # every terrain vertex (not skirt) lies on a cell centre with z = h - z_off - r^2 / 2R
    n_top = chunk.quads[: len(chunk.quads) - chunk.n_skirt].max() + 1
    v = top[:n_top].astype(float)
    c = np.rint((v[:, 0] + off.x_m - xs[0]) / 2.0).astype(int)
    r = np.rint((ys[0] - (v[:, 1] + off.y_m)) / 2.0).astype(int)
    np.testing.assert_allclose(v[:, 0] + off.x_m, xs[c], atol=1e-4)
    np.testing.assert_allclose(v[:, 1] + off.y_m, ys[r], atol=1e-4)
    d2 = (xs[c] - off.x_m) ** 2 + (ys[r] - off.y_m) ** 2
    expect = t.levels[0].array[r, c] - off.z_m - d2 / (2 * R)
    np.testing.assert_allclose(v[:, 2], expect, atol=1e-3)


def test_coarse_level_hole_meets_the_fine_level_without_overlap():
    t = _terrain()
    keep = quad_mask(t, 1)
    xs, ys = _centres(t.levels[1])
    fine_x0, fine_x1 = -49.0, 49.0                               # fine vertex extent
    fine_y0, fine_y1 = -39.0, 39.0
    for r in range(keep.shape[0]):
        for c in range(keep.shape[1]):
            qx0, qx1, qy1, qy0 = xs[c], xs[c + 1], ys[r], ys[r + 1]
            overlaps = qx1 > fine_x0 and qx0 < fine_x1 and qy1 > fine_y0 and qy0 < fine_y1
            corner_inside = any(fine_x0 < x < fine_x1 and fine_y0 < y < fine_y1
                                for x in (qx0, qx1) for y in (qy0, qy1))
            assert keep[r, c] == (not corner_inside)
            if keep[r, c]:
                # a kept coarse quad may touch the fine area only along a sliver < one coarse cell
                assert not overlaps or not (fine_x0 < (qx0 + qx1) / 2 < fine_x1 and fine_y0 < (qy0 + qy1) / 2 < fine_y1)


@pytest.mark.parametrize("nan", [False, True])
def test_every_border_edge_has_a_skirt(nan):
    """Watertight top surface: each edge between two top vertices belongs to exactly two faces."""
    t = _terrain(nan=nan)
    for k in range(2):
        chunk = next(level_chunks(t, k, offset=SceneOffset(0, 0, 0), chunk_cells=1000))
        n_terrain = len(chunk.quads) - chunk.n_skirt
        top_ids = set(chunk.quads[:n_terrain].ravel().tolist())
        edges = Counter()
        for q in chunk.quads:
            for a, b in zip(q, np.roll(q, -1)):
                edges[(min(a, b), max(a, b))] += 1
        top_edges = {e: n for e, n in edges.items() if e[0] in top_ids and e[1] in top_ids}
        assert set(top_edges.values()) == {2}, f"level {k}: open edges"
        assert chunk.n_skirt > 0
        low = chunk.vertices[chunk.quads[n_terrain:, 2]]
        high = chunk.vertices[chunk.quads[n_terrain:, 1]]
        assert np.all(low[:, 2] < high[:, 2] - 10.0)            # skirts hang down


def test_chunks_partition_the_level():
    t = _terrain(nan=True)
    off = SceneOffset(0, 0, 0)

    def quad_set(chunks):
        out = set()
        for ch in chunks:
            n = len(ch.quads) - ch.n_skirt
            for q in ch.quads[:n]:
                out.add(tuple(sorted(map(tuple, np.round(ch.vertices[q], 3).tolist()))))
        return out

    whole = list(level_chunks(t, 0, offset=off, chunk_cells=1000))
    parts = list(level_chunks(t, 0, offset=off, chunk_cells=7))
    assert len(whole) == 1 and len(parts) > 10
    assert all(len(p.quads) - p.n_skirt <= 49 for p in parts)
    assert quad_set(whole) == quad_set(parts)
    assert sum(p.n_skirt for p in parts) == whole[0].n_skirt    # chunk seams carry no skirts


def test_refinement_lies_on_the_bilinear_surface():
    t = _terrain()
    lev = t.levels[0]
    ref = refine_near_field(t, half_m=10.0, rings=((4, 3),))
    fine = ref.levels[0]
    assert fine.cell_m == pytest.approx(0.5) and len(ref.levels) == 3
    xs, ys = _centres(lev)
    interp = RegularGridInterpolator((-ys, xs), lev.array.astype(float))   # ascending axes
    fx, fy = _centres(fine)
    X, Y = np.meshgrid(fx, fy)
    np.testing.assert_allclose(fine.array, interp(np.stack([-Y, X], -1)), atol=1e-4)
    # the refined area is aligned with level-0 centres: its vertex extent starts on one
    assert np.min(np.abs(fx[0] - xs)) < 1e-9 and np.min(np.abs(fy[0] - ys)) < 1e-9
    # level 0 keeps no quad with a corner strictly inside the refined area
    keep = quad_mask(ref, 1)
    assert keep.sum() == (lev.array.shape[0] - 1) * (lev.array.shape[1] - 1) - (fine.array.shape[0] - 1) * (
        fine.array.shape[1] - 1) // 16
    # a small budget lowers the factor
    assert refine_near_field(t, half_m=10.0, rings=((4, 3),), max_quads=2000).meta["refined_factors"] == [2]
    # graded rings: finest inside, each ring's hole meets the next finer ring without overlap
    graded = refine_near_field(t, half_m=6.0, rings=((4, 2), (2, 6)))
    assert [lv.cell_m for lv in graded.levels] == [0.5, 1.0, 2.0, 10.0]
    for k in (1, 2):
        keep = quad_mask(graded, k)
        inner = graded.levels[k - 1].array.shape
        ratio = (graded.levels[k].cell_m / graded.levels[k - 1].cell_m) ** 2
        assert keep.size - keep.sum() == (inner[0] - 1) * (inner[1] - 1) / ratio
        for x, y in np.random.default_rng(4).uniform(-20, 20, (30, 2)):
            assert sample_height(graded, x, y) == pytest.approx(sample_height(t, x, y), abs=1e-4)


def test_sample_height_is_bilinear_on_the_finest_level():
    t = _terrain()
    lev = t.levels[0]
    xs, ys = _centres(lev)
    interp = RegularGridInterpolator((-ys, xs), lev.array.astype(float))
    rng = np.random.default_rng(3)
    for x, y in rng.uniform([-48, -38], [48, 38], (20, 2)):
        assert sample_height(t, x, y) == pytest.approx(float(interp([-y, x])[0]), abs=1e-4)
    # outside level 0 the coarse level answers
    assert np.isfinite(sample_height(t, 120.0, 0.0))


def test_local_vertical_makes_the_drop_relative_to_the_camera():
    """On the curved scene, a point d metres from a camera anywhere drops d^2/2R below its horizontal.

    Exact for the paraboloid up to the normal's length sqrt(1 + (r/R)^2), r the camera's distance
    from the scene origin: 1e-6 relative at 5 km on Mars.
    """
    R = BODIES["mars"].radius_m
    off = SceneOffset(1000.0, 2000.0, 0.0)
    rng = np.random.default_rng(5)
    for _ in range(20):
        p = off.x_m + rng.uniform(-5000, 5000), off.y_m + rng.uniform(-5000, 5000)
        q = p[0] + rng.uniform(-20000, 20000), p[1] + rng.uniform(-20000, 20000)
        up = local_up_enu(*p, off, R)
        zp = float(scene_z(0.0, *p, off, R))
        zq = float(scene_z(0.0, *q, off, R))
        v = np.array([q[0] - p[0], q[1] - p[1], zq - zp])
        height_above_tangent = float(v @ up)
        d = np.hypot(q[0] - p[0], q[1] - p[1])
        assert height_above_tangent == pytest.approx(-d * d / (2 * R), rel=1e-5)


def test_all_levels_are_meshed():
    t = _terrain()
    chunks = list(terrain_chunks(t, chunk_cells=16))
    assert {c.level for c in chunks} == {0, 1}
    assert all(c.vertices.dtype == np.float32 and c.quads.dtype == np.int32 for c in chunks)


def test_custom_body_radius_is_used():
    t = MultiResTerrain([TerrainLevel(np.zeros((5, 5), np.float32), 0, 5, 1.0)], "", Body("custom", 1e5), (2.5, 2.5))
    ch = next(terrain_chunks(t, radius_m=1e3))
    assert ch.vertices[:, 2].min() < 0
