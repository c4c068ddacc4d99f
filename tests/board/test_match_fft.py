"""FFT scores equal a brute-force least-squares evaluation for every heading (full and partial)."""
import numpy as np
import pytest

from board.match.fft_score import lower_bound_full, prepare_query, score_block


def brute_force(e, db, model, ridge=0.0, start=0.0):
    """For every row p and shift a: min over (mu[, alpha, beta]) of sum_seen (e_j - s_(j+a) - model)^2 + ridge."""
    n = e.size
    seen = np.isfinite(e)
    t = np.radians(start + np.arange(n) * 360.0 / n)
    cols = [np.ones(n)] + ([np.cos(t), np.sin(t)] if model == "tilt" else [])
    X = np.stack(cols, axis=1)[seen]
    reg = np.zeros((X.shape[1], X.shape[1]))
    if model == "tilt":
        reg[1, 1] = reg[2, 2] = ridge
    out = np.empty((db.shape[0], n))
    for p in range(db.shape[0]):
        for a in range(n):
            r = (e - np.roll(db[p], -a))[seen]  # s_(j+a)
            coef = np.linalg.solve(X.T @ X + reg, X.T @ r)
            res = r - X @ coef
            out[p, a] = res @ res + coef @ reg @ coef
    return out


@pytest.mark.parametrize("n", [72, 45])
@pytest.mark.parametrize("model", ["offset", "tilt"])
@pytest.mark.parametrize("seen_deg", [360, 242, 65])
@pytest.mark.parametrize("ridge", [0.0, 3.0])
def test_fft_scores_equal_brute_force(n, model, seen_deg, ridge):
    rng = np.random.default_rng(n + seen_deg + int(ridge))
    db = rng.normal(5.0, 4.0, size=(7, n)).cumsum(axis=1) * 0.2 + rng.normal(0, 1, size=(7, 1)) * 30
    e = rng.normal(3.0, 2.0, size=n)
    m = int(round(seen_deg / 360 * n))
    start = rng.integers(0, n)
    if m < n:
        e[np.arange(start + m, start + n) % n] = np.nan  # seen arc wraps around zero
    q = prepare_query(e, model=model, ridge=ridge, azimuth_start_deg=12.5)
    got = score_block(q, db).scores
    want = brute_force(e, db, model, ridge, start=12.5)
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-9 * want.max())


@pytest.mark.parametrize("model", ["offset", "tilt"])
def test_nuisance_coefficients_recover_offset_and_harmonic(model):
    """A query equal to a shifted db skyline + offset + harmonic scores 0 at that shift, coefficients recovered."""
    rng = np.random.default_rng(3)
    n = 90
    db = rng.normal(0, 3, size=(4, n))
    a_true, p_true = 17, 2
    theta = np.radians(np.arange(n) * 4.0)
    truth = (2.5, 0.7, -1.2) if model == "tilt" else (2.5, 0.0, 0.0)
    e = np.roll(db[p_true], -a_true) + truth[0] + truth[1] * np.cos(theta) + truth[2] * np.sin(theta)
    for seen in (slice(None), slice(10, 60)):
        ee = np.full(n, np.nan)
        ee[seen] = e[seen]
        q = prepare_query(ee, model=model)
        blk = score_block(q, db)
        p, a = np.unravel_index(np.argmin(blk.scores), blk.scores.shape)
        assert (p, a) == (p_true, a_true)
        assert blk.scores[p, a] < 1e-9
        coef = q.minv @ blk.b[:, p, a]
        # mu is relative to the centring of both skylines; the harmonic coefficients are absolute
        np.testing.assert_allclose(coef[1:], truth[1:q.n_params], atol=1e-9)


@pytest.mark.parametrize("model", ["offset", "tilt"])
def test_parseval_lower_bound_holds_for_every_heading(model):
    rng = np.random.default_rng(5)
    db = rng.normal(0, 3, size=(50, 120)).cumsum(axis=1)
    e = rng.normal(0, 3, size=120).cumsum()
    q = prepare_query(e, model=model)
    s = db - db.mean(axis=1, keepdims=True)
    from board.match.fft_score import dft_rows
    lb = lower_bound_full(q, dft_rows(s))
    scores = score_block(q, db).scores
    assert np.all(lb <= scores.min(axis=1) * (1 + 1e-9) + 1e-9)
    assert np.all(lb > 0)


@pytest.mark.parametrize("model", ["offset", "tilt"])
@pytest.mark.parametrize("seen_deg", [242, 65])
def test_float32_scores_within_their_error_bound(model, seen_deg):
    """approx_scores_f32 differs from the float64 scores by less than f32_error_bound, row by row."""
    from board.match.fft_score import approx_scores_f32, f32_error_bound

    rng = np.random.default_rng(seen_deg)
    n = 360
    # rough skylines of very different amplitudes (0.1 to 30 degrees), plus one constant row
    db = rng.normal(0, 1, size=(60, n)).cumsum(axis=1) * rng.uniform(0.01, 3.0, size=(60, 1))
    db[0] = 4.0
    db -= db.mean(axis=1, keepdims=True)
    e = np.roll(db[7], -40) + rng.normal(0, 0.05, n) + 3.0
    e[np.arange(seen_deg, n)] = np.nan
    for ridge in (0.0, 2.0):
        q = prepare_query(e, model=model, ridge=ridge, azimuth_start_deg=-30.0)
        exact = score_block(q, db, want_b=False).scores
        approx = approx_scores_f32(q, db.astype(np.float32))
        bound = f32_error_bound(q, db)
        assert np.all(np.abs(approx - exact) <= bound[:, None])
        np.testing.assert_allclose(bound, f32_error_bound(q, db.astype(np.float32)), rtol=1e-5)


@pytest.mark.parametrize("n", [360, 72, 45])
@pytest.mark.parametrize("model", ["offset", "tilt"])
def test_float32_parseval_bound_is_a_lower_bound(n, model):
    """lower_bound_full_f32 never exceeds the exact best score, for skylines of very different
    amplitudes and offsets (a flat horizon high in the sky is the hard case for float32), and it is
    nearly as tight as the float64 bound where the rows vary by degrees."""
    from board.match.fft_score import dft_rows, lower_bound_full_f32

    rng = np.random.default_rng(n)
    rows = []
    for amp, off in ((0.01, 80.0), (0.3, 5.0), (3.0, 0.0), (30.0, -20.0)):
        rows.append(rng.normal(0, 1, size=(40, n)).cumsum(axis=1) * amp * 0.2 + off)
    db = np.concatenate(rows).astype(np.float32).astype(np.float64)  # values a float32 tile holds
    e = np.roll(db[50], -7) + rng.normal(0, 0.05, n)
    for ridge in (0.0, 2.0):
        q = prepare_query(e, model=model, ridge=ridge if model == "tilt" else 0.0)
        best = score_block(q, db, want_b=False).scores.min(axis=1)
        s32 = db.astype(np.float32)
        s32 -= s32.mean(axis=1, keepdims=True)  # centred in float32, as the search does
        lb32 = lower_bound_full_f32(q, s32)
        assert np.all(lb32 <= best)
        lb64 = lower_bound_full(q, dft_rows(db - db.mean(axis=1, keepdims=True)))
        rough = slice(80, 160)
        assert np.all(lb32[rough] >= 0.98 * lb64[rough])
