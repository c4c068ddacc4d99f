"""The streamed search equals exhaustive scoring of the whole database; pruning never changes the argmin."""
import numpy as np
import pytest

from board.match.fft_score import prepare_query, score_block
from board.match.search import Region, search


def _exhaustive(db, q):
    all_el = db.read_all().reshape(-1, q.n).astype(np.float64)
    s = score_block(q, all_el, want_b=False).scores
    return s.min(axis=1).reshape(db.grid.ny, db.grid.nx), s


def _assert_exact_pruning(pruned, ref, full, nx: int, factor: float) -> None:
    """Pruned search vs exhaustive scores ``ref`` (per position) and ``full`` (per position and heading):
    same argmin and best heading, exact scores within ``factor`` of the best, lower bounds elsewhere."""
    assert pruned.n_pruned > 0  # the bound did prune: the test exercises it
    assert pruned.argmin() == np.unravel_index(np.argmin(ref), ref.shape)
    best = ref.min()
    np.testing.assert_allclose(pruned.score.min(), best, rtol=1e-12)
    ex = pruned.exact
    np.testing.assert_allclose(pruned.score[ex], ref[ex], rtol=1e-9, atol=1e-9)
    assert np.all(pruned.score[~ex] <= ref[~ex] * (1 + 1e-9) + 1e-9)
    assert np.all(ex[ref <= factor * best])
    i, j = pruned.argmin()
    assert pruned.shift[i, j] == np.argmin(full[i * nx + j])


@pytest.mark.parametrize("model", ["offset", "tilt"])
@pytest.mark.parametrize("arc", [360, 120])
def test_streamed_search_equals_exhaustive(mountain_world, model, arc):
    w = mountain_world
    rng = np.random.default_rng(arc)
    x, y = w.random_xy(rng)
    sky = w.query(x, y, heading=rng.uniform(0, 360), noise=0.05, arc=arc, arc_start=30.0, rng=rng)
    q = prepare_query(sky.elevation_deg, model=model)
    smap = search(w.db, q, prune=False)
    ref, _ = _exhaustive(w.db, q)
    np.testing.assert_allclose(smap.score, ref, rtol=1e-9, atol=1e-9)
    assert smap.exact.all() and smap.n_pruned == 0


@pytest.mark.parametrize("model", ["offset", "tilt"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pruning_returns_the_exhaustive_argmin(mountain_world, model, seed):
    """Parseval pruning (full panoramas): same argmin, exact scores within the factor, bounds elsewhere."""
    w = mountain_world
    rng = np.random.default_rng(seed)
    x, y = w.random_xy(rng)
    pitch = rng.uniform(-3, 3) if model == "tilt" else 0.0  # the offset model is not tilt-invariant
    sky = w.query(x, y, heading=rng.uniform(0, 360), pitch=pitch, noise=0.1, rng=rng)
    q = prepare_query(sky.elevation_deg, model=model)
    pruned = search(w.db, q, prune=True, prune_factor=2.0)
    ref, full = _exhaustive(w.db, q)
    _assert_exact_pruning(pruned, ref, full, w.db.grid.nx, 2.0)


def test_region_disc_and_heading_window(mountain_world):
    w = mountain_world
    g = w.db.grid
    cx, cy = g.xy(g.ny // 2, g.nx // 2)
    reg = Region.disc(g, (cx + 2.0, cy - 1.0), 12.0)
    rr, cc = np.mgrid[reg.row0:reg.row0 + reg.nrows, reg.col0:reg.col0 + reg.ncols]
    x, y = g.xy(rr, cc)
    np.testing.assert_array_equal(reg.mask, np.hypot(x - cx - 2.0, y - cy + 1.0) <= 12.0)
    rng = np.random.default_rng(4)
    sky = w.query(cx, cy, heading=100.0, noise=0.05, rng=rng)
    q = prepare_query(sky.elevation_deg)
    allowed = np.zeros(q.n, bool)
    allowed[150:170] = True  # headings 150..169: the true 100 is excluded
    smap = search(w.db, q, region=reg, allowed_shifts=allowed)
    ok = np.isfinite(smap.score)
    assert ok.sum() == reg.mask.sum()
    assert np.all((smap.shift[ok] >= 150) & (smap.shift[ok] < 170))


def test_search_reads_the_database_tile_by_tile(mountain_world):
    """Bounded memory: the search never reads more than one tile of skylines at a time."""
    w = mountain_world
    db = w.db
    sizes = []
    orig = db.read_tile

    def spy(tile):
        out = orig(tile)
        sizes.append(out.shape[0] * out.shape[1])
        return out

    db.read_tile = spy
    try:
        sky = w.query(*w.random_xy(np.random.default_rng(0)), heading=10.0)
        search(db, prepare_query(sky.elevation_deg))
    finally:
        del db.read_tile
    assert len(sizes) == len(db.tiles)
    assert max(sizes) <= db.meta.tile_size ** 2


@pytest.mark.parametrize("model,arc,hold,window", [("offset", 242, None, False), ("tilt", 242, 8, False),
                                                    ("tilt", 120, None, True), ("offset", 65, 8, True)])
def test_partial_pruning_returns_the_exhaustive_argmin(mountain_world, monkeypatch, model, arc, hold, window):
    """Partial panoramas: float32 lower bounds prune exactly (same argmin, exact within the factor);
    ``hold`` forces the overflow path that reads tiles again, ``window`` a heading window."""
    import board.match.search as search_mod

    if hold is not None:
        monkeypatch.setattr(search_mod, "HOLD", hold)
    w = mountain_world
    rng = np.random.default_rng(arc + (hold or 0))
    x, y = w.random_xy(rng)
    pitch = rng.uniform(-3, 3) if model == "tilt" else 0.0
    heading = rng.uniform(0, 360)
    sky = w.query(x, y, heading=heading, pitch=pitch, noise=0.1, arc=arc, arc_start=-arc / 2, rng=rng)
    q = prepare_query(sky.elevation_deg, model=model)
    allowed = None
    if window:
        allowed = np.zeros(q.n, bool)
        allowed[(int(heading) + np.arange(-15, 16)) % q.n] = True
    pruned = search(w.db, q, prune=True, prune_factor=2.0, allowed_shifts=allowed)
    _, full = _exhaustive(w.db, q)
    if allowed is not None:
        full = full + np.where(allowed, 0.0, np.inf)
    ref = full.min(axis=1).reshape(w.db.grid.ny, w.db.grid.nx)
    _assert_exact_pruning(pruned, ref, full, w.db.grid.nx, 2.0)
    assert pruned.n_pruned == int((~pruned.exact).sum())
