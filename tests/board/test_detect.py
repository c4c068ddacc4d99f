"""Skyline detectors on analytic panoramas (known skyline function), and the DP solvers against
independent shortest-path implementations."""
from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest

from board.acquisition import PanoramaGeometry
from board.detect import DetectorParams, detect_baseline, detect_skyline
from board.detect.baseline import baseline_graph
from board.detect.graph_dp import shortest_path_dp, shortest_path_l1
from board.detect.sky_regions import _drop_short_runs, _largest_step_above, _sector_edges
from board.synthetic import SceneLook, SkylineFunction, synth_panorama

GEOM = PanoramaGeometry.full_circle(1200, 300, elevation_top_deg=30.0, elevation_bottom_deg=-15.0)
# the detector as it runs on images of this size, and coarse to fine (as on images of more than
# DetectorParams.max_direct_pixels): a copy reduced 2 times, then the band at full resolution
DIRECT = DetectorParams()
COARSE_TO_FINE = DetectorParams(max_direct_pixels=GEOM.width * GEOM.height // 4)


@pytest.fixture(params=[DIRECT, COARSE_TO_FINE], ids=["direct", "coarse_to_fine"])
def params(request):
    return request.param


def _u8(img):
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def _truth_rows(f, geom=GEOM):
    return geom.row_of_el(f(geom.azimuths_deg()))


# -- solvers ------------------------------------------------------------------------------------
def _dijkstra_reference(node, pair, vert):
    """The report's way: Dijkstra over the explicit graph (scipy), source before column 0, sink after the last."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    H, W = node.shape
    N = H * W
    src, dst, w = [], [], []
    for c in range(W):
        for r in range(H):
            if c == 0:
                src.append(N), dst.append(r * W), w.append(node[r, 0])
            if c == W - 1:
                src.append(r * W + c), dst.append(N + 1), w.append(1e-12)
            if c > 0:
                for d in (-1, 0, 1):
                    if 0 <= r + d < H:
                        src.append((r + d) * W + c - 1), dst.append(r * W + c), w.append(pair[d + 1, r, c] + node[r, c])
            if r > 0:
                src.append((r - 1) * W + c), dst.append(r * W + c), w.append(vert[r, c] + node[r, c])
                src.append(r * W + c), dst.append((r - 1) * W + c), w.append(vert[r, c] + node[r - 1, c])
    G = coo_matrix((w, (src, dst)), shape=(N + 2, N + 2)).tocsr()
    return dijkstra(G, indices=N)[N + 1]


@pytest.mark.parametrize("seed", range(4))
def test_dp_equals_dijkstra_on_the_same_graph(seed):
    pytest.importorskip("scipy")
    rng = np.random.default_rng(seed)
    H, W = 9, 11
    node, pair, vert = rng.random((H, W)), rng.random((3, H, W)), rng.random((H, W))
    res = shortest_path_dp(node, pair_cost=pair, vert_cost=vert)
    assert res.cost == pytest.approx(_dijkstra_reference(node, pair, vert), abs=1e-4)
    # the returned path has that cost
    rows_exit = res.rows_exit
    assert np.all(np.abs(np.diff(rows_exit)) <= H)


def test_dp_equals_dijkstra_on_the_report_graph():
    pytest.importorskip("scipy")
    f = SkylineFunction.random(4)
    g = PanoramaGeometry.full_circle(60, 24, elevation_top_deg=15, elevation_bottom_deg=-5)
    img = _u8(synth_panorama(g, f, noise_sigma=0.02, seed=4))
    gr = baseline_graph(img)
    res = shortest_path_dp(gr.node, pair_cost=gr.pair, vert_cost=gr.vert)
    assert res.cost == pytest.approx(_dijkstra_reference(gr.node, gr.pair, gr.vert), rel=1e-5)


@pytest.mark.parametrize("seed", range(5))
def test_l1_path_equals_brute_force(seed):
    rng = np.random.default_rng(seed)
    H, W = 5, 5
    node = rng.random((H, W))
    lam = float(rng.uniform(0, 0.6))
    res = shortest_path_l1(node, jump_cost=lam)
    best = min((sum(node[r[c], c] for c in range(W)) + lam * sum(abs(r[c] - r[c - 1]) for c in range(1, W)), r)
               for r in itertools.product(range(H), repeat=W))
    assert res.cost == pytest.approx(best[0], abs=1e-5)
    assert tuple(res.rows_top) == best[1]


@pytest.mark.parametrize("seed", range(5))
def test_l1_path_in_a_band_equals_brute_force(seed):
    # a band of rows that follows a line: row r of column c is image row r + off[c]; jumps in image rows
    rng = np.random.default_rng(100 + seed)
    H, W = 4, 5
    node = rng.random((H, W))
    off = rng.integers(-3, 4, W)
    lam = float(rng.uniform(0, 0.6))
    res = shortest_path_l1(node, jump_cost=lam, offsets=off)
    best = min((sum(node[r[c], c] for c in range(W))
                + lam * sum(abs(r[c] + off[c] - r[c - 1] - off[c - 1]) for c in range(1, W)), r)
               for r in itertools.product(range(H), repeat=W))
    assert res.cost == pytest.approx(best[0], abs=1e-5)
    assert tuple(res.rows_top) == best[1]


@pytest.mark.parametrize("seed", range(6))
def test_l1_path_across_every_kind_of_band_shift_equals_brute_force(seed):
    # the band moves by 0, within its height up and down, and by its height or more up and down (the whole
    # column outside the previous band): each shift has its own code path in the forward pass
    rng = np.random.default_rng(200 + seed)
    H = 4
    deltas = np.array([0, 2, -3, 5, -6, 1, -1, 4])[rng.permutation(8)][:5]
    off = np.concatenate([[0], np.cumsum(deltas)])
    W = off.size
    node = rng.random((H, W)) if seed % 2 else rng.integers(0, 3, (H, W)).astype(float)   # ties too
    lam = [0.0, 0.25, 0.5][seed % 3]
    res = shortest_path_l1(node, jump_cost=lam, offsets=off)
    best = min((sum(node[r[c], c] for c in range(W))
                + lam * sum(abs(r[c] + off[c] - r[c - 1] - off[c - 1]) for c in range(1, W)), r)
               for r in itertools.product(range(H), repeat=W))
    assert res.cost == pytest.approx(best[0], abs=1e-5)
    path_cost = (sum(node[res.rows_top[c], c] for c in range(W))
                 + lam * sum(abs(res.rows_top[c] + off[c] - res.rows_top[c - 1] - off[c - 1]) for c in range(1, W)))
    assert path_cost == pytest.approx(res.cost, abs=1e-5)   # the backtracked rows are a path of that cost


def test_l1_path_in_a_band_around_the_optimum_is_the_optimum():
    rng = np.random.default_rng(3)
    H, W, Hb = 120, 400, 24
    c = np.arange(W)
    valley = 60 + 30 * np.sin(2 * np.pi * c / W) + np.where((c > 100) & (c < 160), 25, 0)    # with cliffs
    node = np.abs(np.arange(H)[:, None] - valley[None, :]) * 0.05 + rng.random((H, W))
    full = shortest_path_l1(node, jump_cost=0.3, wrap=True, margin=80).rows_top
    off = np.clip(full - Hb // 2 + rng.integers(-5, 6, W), 0, H - Hb)
    band = node[off[None, :] + np.arange(Hb)[:, None], c[None, :]]
    res = shortest_path_l1(band, jump_cost=0.3, wrap=True, margin=80, offsets=off)
    np.testing.assert_array_equal(res.rows_top + off, full)


def test_wrapped_path_closes_the_circle():
    # a cost valley that is a sinusoid over the circle: the wrapped path must follow it across the seam
    H, W = 60, 400
    c = np.arange(W)
    valley = (30 + 20 * np.sin(2 * np.pi * c / W + 1.0)).round().astype(int)
    node = np.abs(np.arange(H)[:, None] - valley[None, :]).astype(float)
    res = shortest_path_l1(node, jump_cost=0.3, wrap=True, margin=50)
    np.testing.assert_array_equal(res.rows_top, valley)


# -- detectors --------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [11, 12, 13])
def test_clean_panorama_within_one_pixel(seed, params):
    f = SkylineFunction.random(seed)
    img = _u8(synth_panorama(GEOM, f, noise_sigma=0.01, seed=seed))
    det = detect_skyline(img, wrap=True, params=params)
    err = det.line_row - _truth_rows(f)
    assert det.valid.mean() >= 0.98
    assert np.nanmean(np.abs(err)) <= 0.5
    assert np.nanmax(np.abs(err)) <= 2.0


@pytest.mark.parametrize("look,name", [(SceneLook(sky_top=0.03, sky_horizon=0.03, ground=0.5), "black sky (Moon)"),
                                       (SceneLook(sky_top=0.35, sky_horizon=0.3, ground=0.75, texture=0.1),
                                        "sky darker than ground")])
def test_polarity_is_learnt_from_the_picture(look, name, params):
    f = SkylineFunction.random(21)
    img = _u8(synth_panorama(GEOM, f, look=look, noise_sigma=0.01, seed=2))
    det = detect_skyline(img, wrap=True, params=params)
    err = det.line_row - _truth_rows(f)
    assert det.valid.mean() >= 0.95, name
    assert np.nanmean(np.abs(err)) <= 0.6, name


def test_binary_panorama_half_pixel():
    f = SkylineFunction.random(5)
    g = GEOM
    el = g.elevations_deg()[:, None]
    terrain = el < f(g.azimuths_deg())[None, :]              # pixel-centre sampling, no anti-aliasing
    det = detect_skyline(terrain.astype(np.uint8) * 255, wrap=True)
    err = det.line_row - _truth_rows(f)
    assert det.valid.mean() >= 0.99
    assert np.nanmax(np.abs(err)) <= 0.75   # the line lies between two pixel centres: <= half a pixel + slack


@pytest.mark.parametrize("psf_px", [0.0, 0.5, 0.8])
def test_subpixel_line_without_pixel_locking(psf_px):
    # a straight edge climbing 3 rows round the circle (every sub-pixel phase, three times), each pixel the exact
    # area of ground it covers, blurred by a Gaussian of psf_px after sampling (as the simulator's lens does), in
    # linear 16-bit light with no noise: the line's error comes from the sub-pixel estimator alone.  A parabola
    # through the step's three samples pulls the line towards the sampled row ("pixel locking", up to 0.07 px);
    # through their logarithms (a Gaussian's peak, DetectorParams.subpixel_gaussian) it stays within 0.04 px,
    # unbiased; read through the box pixel's phase curve (DetectorParams.subpixel_phase) the sharp edge's line is
    # exact and a blurred one's never worse (the curve assumes a blur before sampling, which locks less)
    import cv2

    H, W = GEOM.height, GEOM.width
    c = np.arange(W)
    y = 150.0 + 3.0 * c / W + 0.3 * np.sin(2 * np.pi * c / W)             # the edge's row (continuous)
    img = np.clip(np.arange(H)[:, None] + 0.5 - y[None, :], 0.0, 1.0).astype(np.float32)
    if psf_px > 0:
        img = cv2.GaussianBlur(img, (1, 2 * int(math.ceil(3 * psf_px)) + 1), 0, sigmaY=psf_px)
    u16 = np.round((0.02 + 0.5 * img) * 65535).astype(np.uint16)
    errs = {}
    for name, kw in (("phase", {}), ("gaussian", {"subpixel_phase": False}),
                     ("parabola", {"subpixel_gaussian": False})):
        det = detect_skyline(u16, wrap=True, params=DetectorParams(transfer="linear", **kw))
        assert det.valid.all()
        errs[name] = det.line_row - y
    g, p, ph = errs["gaussian"], errs["parabola"], errs["phase"]
    assert np.abs(g).max() <= 0.04 and abs(g.mean()) <= 0.005
    assert np.abs(p).max() >= 0.05                               # the test can fail: the parabola locks
    assert g.std() <= 0.6 * p.std()
    assert abs(ph.mean()) <= 0.005 and ph.std() <= g.std() + 1e-3
    if psf_px == 0.0:
        assert np.abs(ph).max() <= 0.005 and np.abs(g).max() >= 0.03      # the Gaussian's lock, undone
    if psf_px == 0.5:
        assert ph.std() <= 0.7 * g.std()


def test_the_phase_curve_of_a_box_pixel_against_a_brute_force_peak():
    # board.detect.subpixel_phase's curve, checked against a brute-force edge: the edge's pixels integrated
    # numerically (1000 sub-rows per pixel, the lens as a sampled continuous Gaussian), blurred by the detector's
    # kernel, and the sub-pixel peak taken by the same three-sample Gaussian; its width measure reproduces
    # edge_width_px's definition on the same edges
    import cv2

    from board.detect import subpixel_phase as sp

    fine = 1000
    rows = 41
    for lens in (0.0, 0.3, 0.6):
        table = sp.phase_table(lens, 1.0)
        for phase in (-0.41, -0.17, 0.0, 0.23, 0.38):
            yy = (np.arange(rows * fine) + 0.5) / fine - 0.5          # sub-row centres, row k covering [k-.5, k+.5]
            edge = (yy >= 20.0 + phase).astype(np.float64)
            if lens > 0:
                kx = np.arange(-int(6 * lens * fine), int(6 * lens * fine) + 1) / fine
                k = np.exp(-0.5 * (kx / lens) ** 2)
                edge = np.convolve(edge, k / k.sum(), mode="same")
                edge[-int(6 * lens * fine):] = 1.0                    # the convolution's zero padding, undone
            pix = edge.reshape(rows, fine).mean(axis=1).astype(np.float32)[:, None].repeat(3, axis=1)
            kern = cv2.getGaussianKernel(7, 1.0, cv2.CV_32F)
            blur = cv2.sepFilter2D(pix, -1, np.ones((1, 1), np.float32), kern, borderType=cv2.BORDER_REFLECT)
            step = np.diff(blur[:, 0].astype(np.float64))              # step[i] between rows i and i + 1
            i = int(np.argmax(step))
            l0, l1, l2 = np.log(step[i - 1:i + 2])
            d = 0.5 * (l0 - l2) / (l0 - 2 * l1 + l2)
            line = (i + 1) - 0.5 + float(sp.undo_phase(np.array([d]), table)[0])   # _subpixel's rows
            assert abs(line - (20.0 + phase)) <= 2e-3, (lens, phase, line)
    # the width curve: a sharp edge measures 1 / (sqrt(2 pi) 0.75), and the inverse recovers the lens
    assert sp.model_width_px(0.0) == pytest.approx(1.0 / (0.75 * math.sqrt(2 * math.pi)), abs=2e-3)
    for lens in (0.25, 0.5, 0.9):
        assert sp.lens_sigma_from_width(sp.model_width_px(lens)) == pytest.approx(lens, abs=0.02)
    assert sp.lens_sigma_from_width(float("nan")) is None and sp.table_for_width(1.5, 1.0) is None


def test_noise_and_dust_masked_rather_than_wrong(params):
    f = SkylineFunction.random(31)
    look = SceneLook(dust=((40.0, 120.0, 0.9),))
    img = _u8(synth_panorama(GEOM, f, look=look, noise_sigma=0.04, seed=3))
    det = detect_skyline(img, wrap=True, params=params)
    err = det.line_row - _truth_rows(f)
    az = GEOM.azimuths_deg()
    dusty = (az > 45) & (az < 115)
    clear = (az < 35) | (az > 125)
    assert det.valid[clear].mean() >= 0.95
    assert det.valid[dusty].mean() <= 0.2          # doubtful sector masked
    assert np.nanmean(np.abs(err)) <= 1.0          # what is kept is right
    assert np.nanmax(np.abs(err)) <= 3.0


def test_glare_sector_masked(params):
    f = SkylineFunction.random(41)
    img = synth_panorama(GEOM, f, noise_sigma=0.02, seed=4)
    img[:, 200:330] = np.clip(img[:, 200:330] * 3.0, 0, 1)    # both sides of the line saturate
    det = detect_skyline(_u8(img), wrap=True, params=params)
    assert det.valid[210:320].mean() <= 0.1
    err = det.line_row - _truth_rows(f)
    assert np.nanmax(np.abs(err)) <= 3.0


def test_unseen_columns_are_never_given_a_line(params):
    f = SkylineFunction.random(51)
    img = _u8(synth_panorama(GEOM, f, noise_sigma=0.01, seed=5))
    seen = np.ones(img.shape, bool)
    seen[:, 500:800] = False
    img[~seen] = 0
    det = detect_skyline(img, seen=seen, wrap=True, params=params)
    assert not det.valid[500:800].any()
    err = det.line_row - _truth_rows(f)
    assert np.nanmean(np.abs(err)) <= 0.5


def test_line_above_the_view_is_masked(params):
    # the panorama's top cuts through the terrain in a sector: no sky seen there, the line is doubtful
    f = SkylineFunction(3.0, ((1, 1.0, 0.0),), ((180.0, 40.0, 20.0),))
    img = _u8(synth_panorama(GEOM, f, noise_sigma=0.01, seed=6))
    det = detect_skyline(img, wrap=True, params=params)
    az = GEOM.azimuths_deg()
    hidden = f(az) > 30.0 - GEOM.elevation_step_deg    # skyline at or above the top row there
    assert not det.valid[hidden].any()
    err = det.line_row - _truth_rows(f)
    # the peak's flanks climb 4 rows per column: a row error there is a fraction of a column sideways
    assert np.nanmean(np.abs(err)) <= 0.5 and np.nanmax(np.abs(err)) <= 3.0


def test_baseline_runs_the_report_method():
    # on a high-contrast scene without texture the report's graph finds the line too
    f = SkylineFunction.random(61, amplitude_deg=2.0, n_peaks=0)
    img = _u8(synth_panorama(GEOM, f, look=SceneLook(texture=0.0), noise_sigma=0.0))
    rows = detect_baseline(img, wrap=True)
    assert rows.shape == (GEOM.width,)
    assert np.median(np.abs(rows - _truth_rows(f))) <= 1.5


def test_large_panorama_coarse_to_fine_as_accurate_as_direct():
    # 2400 x 600 px (more than max_direct_pixels): reduced 2 times, then refined at full resolution
    g = PanoramaGeometry.full_circle(2400, 600, elevation_top_deg=30.0, elevation_bottom_deg=-15.0)
    f = SkylineFunction.random(14)
    img = _u8(synth_panorama(g, f, noise_sigma=0.02, seed=3))
    img = np.repeat(img[..., None], 3, axis=2)
    truth = _truth_rows(f, g)
    det = detect_skyline(img, wrap=True)
    assert det.diagnostics["pyramid_factor"] == 2
    direct = detect_skyline(img, wrap=True, params=DetectorParams(max_direct_pixels=0))
    err, err_direct = np.abs(det.line_row - truth), np.abs(direct.line_row - truth)
    assert det.valid.mean() >= 0.98 and det.valid.mean() >= direct.valid.mean() - 0.005
    assert np.nanmean(err) <= np.nanmean(err_direct) + 0.02
    assert np.nanmax(err) <= 2.0


def test_drop_short_runs_wraps():
    v = np.array([1, 1, 0, 0, 1, 0, 1, 1, 1, 0, 1, 1], bool)
    out = _drop_short_runs(v, 3, wrap=True)
    np.testing.assert_array_equal(out, [1, 1, 0, 0, 0, 0, 1, 1, 1, 0, 1, 1])
    out = _drop_short_runs(v, 3, wrap=False)
    np.testing.assert_array_equal(out, [0, 0, 0, 0, 0, 0, 1, 1, 1, 0, 0, 0])


def test_ground_brighter_than_sky_on_one_side_only(params):
    # sunlit flank: the ground is darker than the sky on one half of the circle, brighter on the other
    f = SkylineFunction.random(71)
    shaded = synth_panorama(GEOM, f, look=SceneLook(sky_top=0.6, sky_horizon=0.55, ground=0.3), noise_sigma=0.01)
    sunlit = synth_panorama(GEOM, f, look=SceneLook(sky_top=0.6, sky_horizon=0.55, ground=0.85, texture=0.08),
                            noise_sigma=0.01, seed=1)
    img = shaded.copy()
    img[:, GEOM.width // 2:] = sunlit[:, GEOM.width // 2:]
    det = detect_skyline(_u8(img), wrap=True, params=params)
    err = det.line_row - _truth_rows(f)
    half = GEOM.width // 2
    assert det.valid[:half].mean() >= 0.9 and det.valid[half:].mean() >= 0.9
    assert np.nanmean(np.abs(err)) <= 0.5


# -- issue 11: colour and hazy distant ridges -----------------------------------------------------
def _two_class_image(rows_far, rows_near, *, sky, ground, haze_t, noise=0.01, texture=0.03, seed=0):
    """(H, W, 3) float image: sky above ``rows_far``, hazy far terrain (ground mixed with the sky at
    transmission ``haze_t``) between the two lines, textured ground below ``rows_near``."""
    rng = np.random.default_rng(seed)
    H, W = GEOM.height, GEOM.width
    r = np.arange(H)[:, None] + 0.5
    sky = np.asarray(sky, float)
    ground = np.asarray(ground, float)
    img = np.broadcast_to(sky, (H, W, 3)).copy()
    img *= (1.0 + 0.1 * (r / H))[..., None]                 # the sky brightens towards the horizon
    far = (r >= rows_far[None, :]) & (r < rows_near[None, :])
    tex = texture * rng.standard_normal((H, W, 1))
    img[far] = (haze_t * (ground + 0.3 * tex) + (1 - haze_t) * img)[far]
    img[r >= rows_near[None, :]] = (ground + tex)[np.broadcast_to(r >= rows_near[None, :], (H, W))]
    return np.clip(img + noise * rng.standard_normal(img.shape), 0, 1)


def test_sky_and_ground_of_the_same_grey_told_apart_by_colour(params):
    f = SkylineFunction.random(5)
    rows = _truth_rows(f)
    # BGR: a bluish sky and a tan ground of about the same grey level (0.61 and 0.64)
    img = _two_class_image(rows, rows, sky=(0.70, 0.62, 0.55), ground=(0.45, 0.60, 0.78), haze_t=1.0)
    det = detect_skyline(_u8(img), wrap=True, params=params)
    assert det.valid.mean() >= 0.9
    assert np.nanmean(np.abs(det.line_row - rows)) <= 1.0
    grey_only = detect_skyline(_u8(img), wrap=True, params=DetectorParams(use_colour=False))
    assert grey_only.valid.mean() < 0.5                        # grey alone cannot see this boundary


def test_line_under_a_hazy_distant_ridge_is_never_kept(params):
    f = SkylineFunction.random(9)
    far = _truth_rows(f)
    near = far.copy()
    cols = np.arange(GEOM.width)
    sector = (cols > 300) & (cols < 700)
    near[sector] = far[sector] + 12 + 6 * np.sin(cols[sector] / 40.0)   # a nearer, lower ridge 3-4 deg down
    img = _two_class_image(far, near, sky=(0.6, 0.6, 0.6), ground=(0.3, 0.3, 0.3), haze_t=0.45)
    det = detect_skyline(_u8(img), wrap=True, params=params)
    kept = det.valid & sector
    # kept columns of the sector are on the far ridge (the skyline), never on the near one
    assert np.all(np.abs(det.line_row[kept] - far[kept]) <= 2.0)
    assert np.nanmean(np.abs(det.line_row[~sector] - far[~sector])) <= 1.0
    # without the step-above check the near ridge is what the line follows, with confidence
    unchecked = detect_skyline(_u8(img), wrap=True,
                               params=DetectorParams(above_step_range=(1e9, 2e9)))
    wrong = unchecked.valid & sector & (np.abs(unchecked.raw_row - far) > 4)
    assert wrong.sum() >= 20


def test_sunlit_strip_brighter_than_the_sky_above_a_shaded_slope_is_ground(params):
    """A shaded slope in front of a sunlit one that is brighter than a grey-blue sky (auto-exposed Earth
    view): the strongest step is the shaded/sunlit one, 3-4 deg below the skyline.  The sunlit strip's colour
    is the ground's, so the line must be on the sky/sunlit boundary or masked, never on the lower step."""
    f = SkylineFunction.random(23)
    far = _truth_rows(f)
    cols = np.arange(GEOM.width)
    sector = (cols > 400) & (cols < 640)
    near = far + np.where(sector, 14 + 4 * np.sin(cols / 30.0), 0.0)
    rng = np.random.default_rng(4)
    H, W = GEOM.height, GEOM.width
    r = np.arange(H)[:, None] + 0.5
    sky, sunlit, shaded = np.array([0.50, 0.46, 0.42]), np.array([0.55, 0.66, 0.80]), np.array([0.16, 0.18, 0.21])
    img = np.broadcast_to(sky, (H, W, 3)).copy() * (1.0 + 0.08 * (r / H))[..., None]
    tex = 0.01 * rng.standard_normal((H, W, 1))
    strip = (r >= far[None, :]) & (r < near[None, :])
    below = (r >= near[None, :]) & sector[None, :]
    img[strip] = (sunlit + tex)[strip]
    img[below] = (shaded + tex)[below]
    rest = (r >= far[None, :]) & ~sector[None, :]
    img[rest] = (sunlit + tex)[rest]
    img = np.clip(img + 0.01 * rng.standard_normal(img.shape), 0, 1)
    det = detect_skyline(_u8(img), wrap=True, params=params)
    kept = det.valid & sector
    assert np.all(np.abs(det.line_row[kept] - far[kept]) <= 3.0)   # the lower step is 10-18 rows down
    assert det.valid[~sector].mean() >= 0.9
    assert np.nanmean(np.abs(det.line_row[~sector] - far[~sector])) <= 1.0
    # the control, on the direct detector (coarse to fine, the line now stays up but is masked there without it)
    unchecked = detect_skyline(_u8(img), wrap=True, params=replace(DIRECT, colour_step_above=False))
    wrong = unchecked.valid & sector & (np.abs(unchecked.raw_row - far) > 6)
    assert wrong.sum() >= 10  # without the colour-only check the line follows the lower step, kept


# a sky drawn up to 60 deg, so that a halo is a small part of its sector (as on a real panorama)
TALL = PanoramaGeometry.full_circle(1200, 400, elevation_top_deg=60.0, elevation_bottom_deg=-15.0)


def _halo_scene(seed: int, *, sigma_deg: float, amplitude: float, above_deg: float):
    """A smooth sky (grey 0.50-0.55, noise 0.005) over textured darker ground (0.35 +- 0.06), with a sun
    halo (Gaussian, ``amplitude`` of full scale) centred ``above_deg`` above the skyline at azimuth 90."""
    f = SkylineFunction.random(seed)
    img = synth_panorama(TALL, f, look=SceneLook(sky_top=0.5, sky_horizon=0.55, ground=0.35, texture=0.06),
                         noise_sigma=0.005, seed=seed)
    az, el = TALL.azimuths_deg()[None, :], TALL.elevations_deg()[:, None]
    d2 = ((az - 90.0 + 180.0) % 360.0 - 180.0) ** 2 + (el - f(np.array([90.0]))[0] - above_deg) ** 2
    sky = el > f(TALL.azimuths_deg())[None, :]
    img = np.where(sky, img + amplitude * np.exp(-d2 / (2 * sigma_deg ** 2)), img)
    return _u8(img), _truth_rows(f, TALL)


@pytest.mark.parametrize("seed,sigma,amplitude,above", [(3, 5.0, 0.25, 8.0), (8, 6.0, 0.3, 10.0), (11, 4.0, 0.3, 6.0)])
def test_sun_halo_brighter_than_the_sky_is_sky(seed, sigma, amplitude, above):
    """A halo 0.25-0.3 brighter than a smooth sky (spread 0.005) over rough ground (spread 0.06): with one
    Gaussian per class the halo is more likely under the wide ground class, and the line went round the
    halo (80-130 rows above the skyline, masked: 75-100 % of the halo's 30 degrees lost).  With the classes
    monotone, a value beyond the sky's centre is sky: the skyline under the halo is found and kept."""
    img, rows = _halo_scene(seed, sigma_deg=sigma, amplitude=amplitude, above_deg=above)
    near = np.abs((TALL.azimuths_deg() - 90.0 + 180.0) % 360.0 - 180.0) < 15.0
    # coarse to fine also masks a few short runs of the reduced copy here, halo or not (its 8-bit sky
    # gradient reads as slightly rough): 0.85-0.92 of the halo's azimuths kept, 0.95-0.98 of all
    for P, near_min, all_min in ((DIRECT, 0.95, 0.98), (DetectorParams(max_direct_pixels=TALL.width * TALL.height // 4),
                                                        0.8, 0.95)):
        det = detect_skyline(img, wrap=True, params=P)
        assert det.valid[near].mean() >= near_min and det.valid.mean() >= all_min
        assert np.nanmax(np.abs(det.line_row - rows)) <= 1.0
    before = detect_skyline(img, wrap=True, params=replace(DIRECT, monotone_classes=False))
    assert before.valid[near].mean() <= 0.5                   # the control: the halo was taken for ground
    assert np.nanmax(np.abs(before.raw_row[near] - rows[near])) >= 40


@pytest.mark.parametrize("seed", [1, 2])
def test_sunlit_face_brighter_than_the_sky_over_shaded_ground_is_kept_coarse_to_fine(seed):
    """A sunlit face 60 rows deep (11 deg), brighter than the sky, over shaded ground, in one 36-deg sector.
    The reduced copy's classes are fitted over the whole sector, where the shaded ground is most of the
    ground: the step at the skyline runs against their polarity and its contrast check fails.  The band
    at full resolution sees mostly the sunlit face below the line and measures the step right: its
    confidence decides, the reduced copy's wide-window checks (glare, a step above, region) still cap it."""
    g = PanoramaGeometry.full_circle(1200, 400, elevation_top_deg=45.0, elevation_bottom_deg=-30.0)
    rng = np.random.default_rng(seed)
    f = SkylineFunction.random(seed)
    rows = _truth_rows(f, g)
    H, W = g.height, g.width
    r = np.arange(H)[:, None] + 0.5
    sector = (np.arange(W) > 300) & (np.arange(W) < 420)
    # BGR: a pale sky; a tan sunlit face brighter than it; the same soil in shade
    sky, sunlit, shaded = np.array([0.62, 0.55, 0.50]), np.array([0.62, 0.78, 0.92]), np.array([0.22, 0.26, 0.30])
    img = np.broadcast_to(sky, (H, W, 3)) * (1 + 0.05 * r / H)[..., None]
    tex = 0.02 * rng.standard_normal((H, W, 1))
    img = np.where((r >= rows[None, :])[..., None], shaded + tex, img)
    face = (r >= rows[None, :]) & (r < rows[None, :] + np.where(sector, 60.0, 0.0)[None, :])
    img = _u8(np.where(face[..., None], sunlit + tex, img) + 0.01 * rng.standard_normal((H, W, 3)))
    c2f = DetectorParams(max_direct_pixels=W * H // 4)
    det = detect_skyline(img, wrap=True, params=c2f)
    assert det.diagnostics["pyramid_factor"] == 2
    assert det.valid[sector].mean() >= 0.9 and det.valid.mean() >= 0.98
    assert np.nanmax(np.abs(det.line_row - rows)) <= 1.5
    capped = detect_skyline(img, wrap=True, params=replace(c2f, coarse_contrast_cap=True))
    assert capped.valid[sector].mean() <= 0.5          # the control: the reduced copy's contrast masked it


def test_line_on_the_local_grey_step_under_a_haze_band(params):
    """A noise-free sky brightening towards the horizon (haze), in 8 bits, over sunlit ground: the sky as a
    whole is darker than the ground, the sky just above the line as bright as it.  The sub-pixel line must
    use the step's local sign and size (before: the classes' sign, 1.3-1.6 px off on this scene)."""
    f = SkylineFunction.random(31)
    rows = _truth_rows(f)
    rng = np.random.default_rng(6)
    H, W = GEOM.height, GEOM.width
    r = np.arange(H)[:, None]                                         # pixel centres (the line's rows)
    depth = np.clip(rows[None, :] - r, 0, None)                       # rows above the skyline
    sky = np.array([0.54, 0.48, 0.44])[None, None, :] * (1.0 + 0.25 * np.exp(-depth / 12.0))[..., None]
    ground = np.array([0.45, 0.56, 0.68]) + 0.02 * rng.standard_normal((H, W, 1))
    cover = np.clip(r + 0.5 - rows[None, :], 0.0, 1.0)[..., None]    # ground share of each pixel
    img = cover * ground + (1.0 - cover) * sky
    det = detect_skyline(_u8(img), wrap=True, params=params)
    assert det.valid.mean() >= 0.9
    assert np.nanmean(np.abs(det.line_row - rows)) <= 0.5


def test_quantised_smooth_gradient_is_not_texture():
    """The roughness of an 8-bit smooth gradient (one grey level every few rows) is the flat sky's: below
    DetectorParams.quantisation_texture_levels grey levels it is quantisation (Mars 402, pose 6, clean look:
    the haze band above the horizon read as texture, the line ran along its top and 71 % of the columns were
    masked).  Real texture above the floor is measured as before."""
    from board.detect.sky_regions import _vertical_features

    H, W = 200, 50
    r = np.arange(H, dtype=float)[:, None]
    gradient = np.broadcast_to(0.45 + 0.12 * np.exp(-(H - r) / 30.0), (H, W))   # steepens towards the bottom
    flat = np.full((H, W), 0.45)
    rough = 0.45 + 0.02 * np.random.default_rng(1).standard_normal((H, W))
    P = DetectorParams()
    tex = {name: _vertical_features(_u8(img), P)[2] for name, img in
           (("gradient", gradient), ("flat", flat), ("rough", rough))}
    assert np.ptp(np.diff(_u8(gradient)[:, 0].astype(int))) >= 1               # the gradient does step in 8 bits
    np.testing.assert_array_equal(tex["gradient"], tex["flat"])
    assert np.median(tex["rough"]) > np.max(tex["flat"]) + 1.0                   # e-fold rougher: still texture
    unfloored = replace(P, quantisation_texture_levels=0.0)
    raw = {name: _vertical_features(_u8(img), unfloored)[2] for name, img in (("gradient", gradient), ("flat", flat))}
    assert np.max(raw["gradient"]) > np.max(raw["flat"]) + 0.5                   # the control: steps read as texture


def _slope_filling_the_top(sector, *, sky, ground, slope=(0.50, 0.60, 0.74), shade=0.8, seed=0):
    """(H, W, 3) float BGR image and truth rows: a bluish sky over tan ground, except in ``sector`` (a column
    mask) where a darker near slope of about the ground's colour (``slope`` times ``shade``) fills the view up to its
    top (the horizon is above the picture) and meets the flat foreground at a foot 4-6 deg below the
    horizontal."""
    f = SkylineFunction.random(seed + 61)
    rows = _truth_rows(f)
    rng = np.random.default_rng(seed)
    H, W = GEOM.height, GEOM.width
    r = np.arange(H)[:, None] + 0.5
    cols = np.arange(W)
    foot = GEOM.row_of_el(-5.0 + np.sin(cols / 25.0))
    sky_img = np.asarray(sky, float) * (1.0 + 0.1 * (r / H))[..., None]
    tex = 0.03 * rng.standard_normal((H, W, 1))
    ground_img = np.asarray(ground, float) + tex
    slope_img = shade * np.asarray(slope, float) + 0.5 * tex
    is_ground = np.where(sector[None, :], r >= foot[None, :], r >= rows[None, :])
    img = np.where(is_ground[..., None], ground_img, np.where(sector[None, :, None], slope_img, sky_img))
    return np.clip(img + 0.004 * rng.standard_normal(img.shape), 0, 1), rows, foot


def test_no_line_where_a_slope_of_the_grounds_colour_fills_the_top_of_the_view(params):
    """Near slopes fill the top of a NavCam view in some directions (held-out Baltoro: 5-14 % of the kept
    samples more than 1 deg off).  There is no sky in those columns: the per-sector classes take the slope for
    sky and the line falls on its foot, with full contrast.  The slope has the ground's colour, the sky
    elsewhere in the view another one: those columns are masked, the rest kept."""
    cols = np.arange(GEOM.width)
    sector = (cols > 300) & (cols < 620)
    img, rows, foot = _slope_filling_the_top(sector, sky=(0.70, 0.62, 0.55), ground=(0.45, 0.60, 0.78))
    det = detect_skyline(_u8(img), wrap=True, params=params)
    assert det.valid[sector].mean() <= 0.02
    inner = ~sector & (np.abs(cols - 460) > 180)                       # away from the sector's edges
    assert det.valid[inner].mean() >= 0.9
    assert np.nanmean(np.abs(det.line_row[inner] - rows[inner])) <= 1.0
    # the control: without the colour check the line is on the slope's foot there, and kept
    unchecked = detect_skyline(_u8(img), wrap=True, params=replace(params, sky_colour_min_contrast=np.inf))
    on_foot = unchecked.valid & sector & (np.abs(unchecked.raw_row - foot) < 3)
    assert on_foot.sum() >= 100
    # a view whose sky is the ground's colour everywhere (no colour cue): the check stands aside
    same = _u8(_slope_filling_the_top(np.zeros_like(sector), sky=(0.50, 0.66, 0.86), ground=(0.45, 0.60, 0.78))[0])
    grey_sky = detect_skyline(same, wrap=True, params=params)
    assert grey_sky.diagnostics["sky_ground_colour_contrast"] < DIRECT.sky_colour_min_contrast
    off = detect_skyline(same, wrap=True, params=replace(params, sky_colour_min_contrast=np.inf))
    np.testing.assert_array_equal(grey_sky.valid, off.valid)


def _slope_edge_in_front_of_a_far_ridge(far_level, seed=0):
    """(H, W) grey float image, truth rows, in-view and junction column masks: a dark near slope whose edge
    runs down across the view (from above its top, 0.3 deg of elevation per column) in front of a far ridge
    3 +- 2.5 deg up.  The sky brightens towards the horizon (0.66 -> 0.74); the far ridge, at ``far_level``,
    is nearer the sky's grey than the slope's (0.25): a monochrome NavCam's view of a sunlit far range past a
    shaded near slope (held-out Baltoro, session 27).  The horizon is the higher of the two edges."""
    rng = np.random.default_rng(seed)
    H, W = GEOM.height, GEOM.width
    r = np.arange(H)[:, None] + 0.5
    cols = np.arange(W)
    el_far = 3.0 + 1.5 * np.sin(cols / 13.0) + 1.0 * np.sin(cols / 41.0 + seed)
    el_slope = np.where((cols >= 250) & (cols < 700), 40.0 - 0.3 * (cols - 250), -90.0)
    row_far, row_slope = GEOM.row_of_el(el_far), GEOM.row_of_el(el_slope)
    t = np.clip((30.0 - GEOM.el_of_row(np.arange(H))) / 30.0, 0, 1)[:, None]
    tex = 0.02 * rng.standard_normal((H, W))
    img = np.where(r >= row_slope[None, :], 0.25 + 0.5 * tex,
                   np.where(r >= row_far[None, :], far_level + tex, 0.66 * (1 - t) + 0.74 * t))
    in_view = el_slope < 29.0
    junction = in_view & (el_slope < el_far) & (el_slope > -15.0)
    return (np.clip(img + 0.004 * rng.standard_normal(img.shape), 0, 1), np.minimum(row_far, row_slope),
            in_view, junction)


@pytest.mark.parametrize("far_level", [0.62, 0.5])
def test_the_far_ridge_behind_a_near_slopes_edge_is_found_again_above_the_step(params, far_level):
    """Past the point where a near slope's edge runs down in front of a far ridge, the smooth path keeps to
    the slope's strong edge, and those columns are masked for the sky-to-ground step above them (the far
    ridge).  The path solved again at or above that step finds the far ridge: more of those columns are
    kept, on the true horizon, and no column is kept wrong that was not before."""
    img, rows, in_view, junction = _slope_edge_in_front_of_a_far_ridge(far_level)
    det = detect_skyline(_u8(img), wrap=True, params=params)
    off = detect_skyline(_u8(img), wrap=True, params=replace(params, reseat_on_step_above=False))
    masked_before = junction & ~off.valid
    assert masked_before.sum() >= 5                               # the scene does defeat the first path
    gained = det.valid & ~off.valid & in_view
    assert gained.sum() >= max(5.0, 2.0 / 3.0 * masked_before.sum())   # two thirds of them at least come back
    assert np.max(np.abs(det.line_row[gained] - rows[gained])) <= 1.5
    wrong = in_view & det.valid & (np.abs(det.line_row - rows) > 2.0)
    wrong_before = in_view & off.valid & (np.abs(off.line_row - rows) > 2.0)
    assert not (wrong & ~wrong_before).any()
    # where nothing masks a column for a step above, the path and its confidence are the same
    far_away = in_view & ~junction & (np.abs(np.arange(GEOM.width) - 500) > 300)
    np.testing.assert_array_equal(det.valid[far_away], off.valid[far_away])


def _slope_under_a_high_horizon(sector, seed=0):
    """(H, W, 3) float BGR image and truth rows: as :func:`_slope_filling_the_top`, but in ``sector`` the
    slope's crest is the horizon, 22-26 deg up, with the sky above it near the top of the view."""
    f = SkylineFunction.random(seed + 61)
    rng = np.random.default_rng(seed)
    H, W = GEOM.height, GEOM.width
    r = np.arange(H)[:, None] + 0.5
    cols = np.arange(W)
    rows = np.where(sector, GEOM.row_of_el(24.0 + 2.0 * np.sin(cols / 17.0)), _truth_rows(f))
    foot = GEOM.row_of_el(-5.0 + np.sin(cols / 25.0))
    sky_img = np.array([0.70, 0.62, 0.55]) * (1.0 + 0.1 * (r / H))[..., None]
    tex = 0.03 * rng.standard_normal((H, W, 1))
    ground_img = np.array([0.45, 0.60, 0.78]) + tex
    slope_img = 0.8 * np.array([0.50, 0.60, 0.74]) + 0.5 * tex
    is_ground = np.where(sector[None, :], r >= foot[None, :], r >= rows[None, :])
    is_slope = sector[None, :] & (r >= rows[None, :]) & ~is_ground
    img = np.where(is_ground[..., None], ground_img, np.where(is_slope[..., None], slope_img, sky_img))
    return np.clip(img + 0.004 * rng.standard_normal(img.shape), 0, 1), rows


def test_the_horizon_above_a_near_slope_is_found_again_from_the_colours(params):
    """Half of the view is a near slope whose crest, 22-26 deg up, is the horizon (held-out Baltoro NavCam).
    The sector classes fitted on the slope put the line on its foot, where the colour check masks it; the
    detector then starts again from classes taken from the pixels' colour and finds the crest."""
    cols = np.arange(GEOM.width)
    sector = (cols > 200) & (cols < 800)
    img, rows = _slope_under_a_high_horizon(sector)
    det = detect_skyline(_u8(img), wrap=True, params=params)
    assert det.valid[sector].mean() >= 0.95 and det.valid[~sector].mean() >= 0.95
    assert np.nanmax(np.abs(det.line_row - rows)) <= 2.0
    # the control: one pass only masks a quarter of the sector (its line on the foot, which the colour check masks)
    once = detect_skyline(_u8(img), wrap=True, params=replace(params, colour_second_pass_fraction=np.inf,
                                                               colour_second_pass_masked=np.inf,
                                                               reseat_on_step_above=False))
    assert once.valid[sector].mean() <= 0.85
    assert np.nanmax(np.abs(once.line_row - rows)) <= 2.0      # what one pass keeps is right too


def test_a_grey_view_with_masked_columns_does_not_start_the_colour_second_pass(params):
    """The colour second pass starts its classes from the pixels' colour (their share of the way from the
    ground's colour to the sky's): a view whose sky and ground have one colour has no such share.  A grey
    lunar-like view (black sky, grey ground, three equal channels) whose ground fades into the sky over a third
    of the azimuths keeps its plain columns, masks the faded ones, and never runs that pass (before, the
    share was 0 / 0 there: a pass on empty classes and a division warning)."""
    import warnings

    H, W = GEOM.height, GEOM.width
    rows = np.full(W, 150.0) + 20.0 * np.sin(np.arange(W) * 2 * np.pi / W)
    r = np.arange(H)[:, None]
    ground = np.where(np.arange(W) < W // 3, 0.02, 0.45)[None, :]    # a third of the ground as dark as the sky
    img = np.where(r >= rows[None, :], ground, 0.02) + 0.003 * np.random.default_rng(3).standard_normal((H, W))
    grey3 = _u8(np.repeat(img[..., None], 3, axis=2))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        det = detect_skyline(grey3, wrap=True, params=params)
    assert "colour_second_pass" not in det.diagnostics
    plain = np.arange(W) >= W // 3 + 20
    assert det.valid[plain].mean() >= 0.95 and not det.valid[: W // 3 - 20].any()
    assert np.max(np.abs(det.line_row - rows)[det.valid]) <= 1.0


def _regolith_under_black_sky(f: SkylineFunction, level: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """uint8 BGR view on GEOM: brown regolith of grey ``level`` per column (DN, 15 % texture) below the skyline
    ``f``, over a black sky; sensor noise of 1.5 +- 1.5 DN everywhere."""
    ground = GEOM.elevations_deg()[:, None] < f(GEOM.azimuths_deg())[None, :]
    texture = 1 + 0.15 * rng.standard_normal((GEOM.height, GEOM.width))
    img = np.zeros((GEOM.height, GEOM.width, 3), np.float32)
    img[ground] = (level[None, :, None] * texture[..., None] * np.array([0.62, 0.8, 1.0]))[ground]   # BGR: brown
    img += rng.normal(1.5, 1.5, img.shape)
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_black_airless_sky_has_no_colour_to_veto_columns_with(params, seed):
    # the Moon's sky: black (sensor noise around 1.5 DN) over brown regolith from sunlit (200 DN) to dim (25 DN).
    # log(blue / red) of the black sky is the ratio of noise: the "sky coloured like the ground" check, were it
    # to read it, masks the columns whose noise happens to lean red (1-2 % here, a quarter of a rendered lunar
    # view with shaded regolith); a black window has no colour, and every column is kept
    rng = np.random.default_rng(seed)
    f = SkylineFunction.random(100 + seed)
    level = 25 + 175 * (0.5 + 0.5 * np.cos(np.radians(GEOM.azimuths_deg() - rng.uniform(0, 360))))
    det = detect_skyline(_regolith_under_black_sky(f, level, rng), wrap=True, params=params)
    assert det.diagnostics["sky_coloured_like_ground_fraction"] == 0.0
    assert det.valid.mean() >= 0.995
    err = np.abs(det.line_row - _truth_rows(f))[det.valid]
    assert np.median(err) <= 0.35                            # pixels (a hard edge: +-0.5 px of quantisation)
    assert err.max() * GEOM.elevation_step_deg <= 1.0        # no kept sample 1 degree off (6.7 px)


def test_step_noise_per_sector_equals_a_brute_force_mad():
    # a discriminant whose sky noise grows tenfold across the view: the per-column noise is the larger of the view's
    # and the sector's 1.4826 MAD of the 3-row steps more than 10 rows above the line, between sector centres
    rng = np.random.default_rng(5)
    H, W, k = 120, 96, 3
    sd = np.geomspace(0.01, 0.1, W)
    proj = (rng.standard_normal((H, W)) * sd).astype(np.float32)
    b = rng.integers(60, 100, W)
    seen = np.ones((H, W), bool)
    edges = _sector_edges(W, 8)
    _, view_noise, _ = _largest_step_above(proj, seen, b, k)
    _, noise, _ = _largest_step_above(proj, seen, b, k, edges, wrap=False)

    def mad(v):
        return 1.4826 * np.median(np.abs(v - np.median(v)))

    steps = {c: [proj[r:r + k, c].mean() - proj[r - k:r, c].mean() for r in range(k, H - k + 1) if r + k <= b[c] - 10]
             for c in range(W)}
    assert view_noise == pytest.approx(mad(np.concatenate([steps[c] for c in range(W)])), rel=1e-4)
    sector = [mad(np.concatenate([steps[c] for c in range(c0, c1)])) for c0, c1 in zip(edges[:-1], edges[1:])]
    centres = 0.5 * (edges[:-1] + edges[1:]) - 0.5
    expected = np.maximum(view_noise, np.interp(np.arange(W), centres, sector))
    np.testing.assert_allclose(noise, expected, rtol=1e-4)
    assert noise[-1] > 3 * view_noise > noise[0]                           # the test can fail: noise differs


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_dim_sector_under_a_black_sky_is_kept_where_its_sky_is_only_noise(params, seed):
    # the Moon: a black sky (1.5 +- 1.5 DN) over regolith lit at 60-200 DN, except a 90-deg sector of dim ground
    # (12 DN, 7 noise sigmas per pixel: plain to the eye).  The discriminant is scaled per column by its sector's
    # class contrast, so there the sky's noise is 15 times the view's: judged by the view's noise, the largest
    # noise step among a column's hundred sky rows passes for a ridge above the line and the whole sector is
    # masked.  Judged by its sector's noise (DetectorParams.above_step_sector_noise), the sector is kept, on the line
    rng = np.random.default_rng(seed)
    f = SkylineFunction.random(200 + seed)
    d = (GEOM.azimuths_deg() - rng.uniform(0, 360) + 180) % 360 - 180      # azimuth from the dim sector's centre
    level = np.where(np.abs(d) < 45, 12.0, 60 + 140 * (0.5 + 0.5 * np.cos(np.radians(d))))
    img = _regolith_under_black_sky(f, level, rng)
    dim = np.abs(d) < 40
    det = detect_skyline(img, wrap=True, params=params)
    err = np.abs(det.line_row - _truth_rows(f))
    assert det.valid[dim].mean() >= 0.8
    assert np.median(err[det.valid & dim]) <= 0.4                          # pixels
    assert err[det.valid].max() * GEOM.elevation_step_deg <= 1.0           # no kept sample 1 degree off
    # the view's noise alone masks the dim sector (the test can fail)
    old = detect_skyline(img, wrap=True, params=replace(params, above_step_sector_noise=False))
    assert old.valid[dim].mean() <= 0.2
    assert abs(old.valid[~dim].mean() - det.valid[~dim].mean()) <= 0.02   # the bright sectors as they were


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_shaded_far_ridge_over_a_lit_near_edge_under_a_black_sky_is_not_kept_as_the_edge(params, seed):
    # the Moon: a sunlit near floor (140 DN) whose edge is the skyline, except over 120 deg of azimuth where a far
    # ridge rises up to 6 deg behind it, in shade: lit only by the ground around it, 4 DN over a black sky of
    # 1.5 +- 1.5 DN.  Its step is a few hundredths of the classes' contrast and the line follows the lit edge
    # under it; averaged over 10 rows and 7 columns it is 6-12 noise sigmas of a sky with no gradient of its own
    # (DetectorParams.faint_ground_*): those columns are masked, the lit edge elsewhere is kept
    rng = np.random.default_rng(seed)
    az, el = GEOM.azimuths_deg(), GEOM.elevations_deg()
    floor = 2.0 + 0.8 * np.sin(np.radians(2 * az + 40 * seed))
    c0 = rng.uniform(-150, 90)
    inside = (az > c0) & (az < c0 + 120)
    ridge = np.where(inside, floor + 6.0 * np.sin(np.pi * np.clip((az - c0) / 120.0, 0, 1)), floor)
    lit = el[:, None] < floor[None, :]
    shaded = (el[:, None] < ridge[None, :]) & ~lit
    img = np.zeros((GEOM.height, GEOM.width, 3), np.float32)
    brown = np.array([0.62, 0.8, 1.0])                                     # BGR
    img[lit] = (140 * (1 + 0.1 * rng.standard_normal(lit.sum())))[:, None] * brown
    img[shaded] = (4.0 * (1 + 0.5 * rng.standard_normal(shaded.sum())))[:, None] * brown
    img += rng.normal(1.5, 1.5, img.shape)
    img = np.clip(img + 0.5, 0, 255).astype(np.uint8)
    det = detect_skyline(img, wrap=True, params=params)
    err_deg = np.abs(det.line_row - GEOM.row_of_el(np.maximum(floor, ridge))) * GEOM.elevation_step_deg
    under = ridge > floor + 0.3
    assert det.valid[~under].mean() >= 0.97                  # the lit edge where it is the skyline
    assert np.sum(err_deg[det.valid] > 1.0) <= 0.01 * det.valid.sum()
    # the same view without the check keeps the lit edge under the ridge (the test can fail)
    off = detect_skyline(img, wrap=True, params=replace(params, black_sky_grey=0.0))
    err_off = np.abs(off.line_row - GEOM.row_of_el(np.maximum(floor, ridge))) * GEOM.elevation_step_deg
    assert np.sum((err_off > 1.0) & off.valid) > 0.1 * under.sum()
