"""Feature tracking (active search, spatial-diversity sampling) and the whole filter on a synthetic descent."""
import numpy as np
import pytest

from board.descent.features import Features, active_search, to_gray8
from board.descent.landmarks import diversity_score, sample_new
from board.descent.metrics import error_growth_percent, position_error
from board.descent.runner import MODES, run_sequence
from board.errors import InvalidInputError


def test_diversity_score_is_minus_log_of_the_gaussian_kde():
    rng = np.random.default_rng(0)
    tracked = rng.uniform(0, 640, (12, 2))
    cand = rng.uniform(0, 640, (30, 2))
    h = 50.0
    # brute force: the density as a plain double loop
    f = np.array([np.mean([np.exp(-np.sum((c - t) ** 2) / (2 * h * h)) / (2 * np.pi * h * h) for t in tracked])
                  for c in cand])
    np.testing.assert_allclose(diversity_score(cand, tracked, h), -np.log(f), rtol=1e-10)
    # far from every tracked landmark the score is finite (log-sum-exp) and larger
    far = diversity_score(np.array([[1e4, 1e4]]), tracked, h)
    assert np.isfinite(far).all() and far[0] > diversity_score(cand, tracked, h).max()


def test_diversity_sampling_draws_in_proportion_to_D_and_favours_the_empty_side():
    rng = np.random.default_rng(1)
    tracked = np.column_stack([rng.uniform(0, 300, 20), rng.uniform(0, 480, 20)])  # all on the left
    cand = np.column_stack([rng.uniform(0, 640, 300), rng.uniform(0, 480, 300)])
    right = cand[:, 0] > 320
    D = diversity_score(cand, tracked, 60.0)
    p_expect = D[right].sum() / D.sum()  # eq. 8's weights: P(first draw on the right)
    assert p_expect > right.mean() + 0.05  # the empty side is favoured over uniform sampling
    n = 600
    hits = sum(bool(right[sample_new(cand, tracked, 1, np.random.default_rng(s), bandwidth_px=60.0,
                                                  min_spacing_px=0.0)[0]])
               for s in range(n))
    assert abs(hits / n - p_expect) < 3 * np.sqrt(p_expect * (1 - p_expect) / n)
    hits_u = sum(bool(right[sample_new(cand, tracked, 1, np.random.default_rng(s), weighting="uniform",
                                                    min_spacing_px=0.0)[0]])
                 for s in range(n))
    assert abs(hits_u / n - right.mean()) < 3 * np.sqrt(0.25 / n)


def test_sampling_keeps_the_minimum_spacing():
    rng = np.random.default_rng(2)
    cand = rng.uniform(0, 200, (200, 2))
    pick = sample_new(cand, np.zeros((0, 2)), 30, rng, min_spacing_px=25.0)
    d = np.sqrt(((cand[pick][:, None] - cand[pick][None]) ** 2).sum(-1)) + np.eye(len(pick)) * 1e9
    assert d.min() >= 25.0


def test_active_search_gates_by_ellipse_and_ratio():
    rng = np.random.default_rng(3)
    desc = rng.normal(0, 40, (6, 128)).astype(np.float32)
    uv = np.array([[100, 100], [300, 200], [500, 400], [120, 104], [305, 200], [50, 400.0]])
    feats = Features(uv, desc)
    S = np.repeat((np.eye(2) * 4.0)[None], 3, axis=0)  # sigma 2 px: 3-sigma gate = 6 px
    pred = np.array([[101, 101], [302, 201], [450, 400.0]])
    lm_desc = np.stack([desc[0] + 1, desc[1] + 1, desc[2]])
    pairs = active_search(pred, S, lm_desc, feats)
    # landmark 0 -> kp 0 (kp 3 is outside its ellipse); 1 -> kp 1 (kp 4 inside but a worse descriptor);
    # landmark 2's keypoint is 50 px away, outside its gate
    assert pairs == [(0, 0), (1, 1)]
    # an ambiguous pair inside one ellipse fails the ratio test
    feats2 = Features(np.array([[100, 100], [102, 100.0]]), np.stack([desc[0], desc[0] + 6.0]))
    assert active_search(pred[:1], S[:1], desc[:1] + 3.0, feats2) == []  # equidistant descriptors
    assert active_search(pred[:1], S[:1], desc[:1] + 0.5, feats2) == [(0, 0)]  # a clear winner


def test_to_gray8_stretches_radiometric_frames():
    img = (np.arange(100 * 80).reshape(80, 100) + 20000).astype(np.uint16)
    g = to_gray8(img)
    assert g.dtype == np.uint8 and g.min() == 0 and g.max() == 255
    with pytest.raises(InvalidInputError, match="2-D"):
        to_gray8(np.zeros((4, 4, 3), np.uint8))


@pytest.fixture(scope="module")
def synthetic_sequence():
    from board.descent.synthetic import make_sequence
    return make_sequence(11, n_frames=10)


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["visible", "dual"])  # thermal and visible-64: tests/descent/test_eval_*
def test_filter_tracks_a_synthetic_descent(synthetic_sequence, mode):
    seq = synthetic_sequence
    res = run_sequence(seq, mode, seed=2)
    cams, n = MODES[mode]
    assert res.tum.shape == seq.groundtruth.shape
    assert res.landmarks[-1] == n * len(cams)
    assert np.median(res.matched[1:]) >= 0.6 * n * len(cams)
    err = position_error(res.tum, seq.groundtruth)
    E, _ = error_growth_percent(res.tum, seq.groundtruth)
    # the error grows by less than 2 % of the ~20 m travelled
    assert abs(E) < 2.0, (E, err)
    assert err.max() < err[0] + 1.0


def test_modes_and_cameras_are_checked(synthetic_sequence):
    with pytest.raises(InvalidInputError, match="mode"):
        run_sequence(synthetic_sequence, "infrared")
    seq = synthetic_sequence
    seq_vis = type(seq)(seq.meta, {"visible": seq.cameras["visible"]}, seq.frame_times, seq.imu, seq.altimeter,
                        seq.groundtruth, seq.gravity_w, seq.frames)
    with pytest.raises(InvalidInputError, match="thermal"):
        run_sequence(seq_vis, "dual")
