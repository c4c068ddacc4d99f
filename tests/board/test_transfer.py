"""Transfer functions and the sub-pixel line on encoded images (board.transfer, the detector's linear step).

Truth is analytic: a skyline whose pixels are integrated exactly over their area in linear light,
blurred by a Gaussian optics PSF in linear light, then sRGB-encoded, as a camera (and the simulator)
records it.  The half-way point of such a step in the encoded values lies towards the dark side by a
predictable amount; on the linearised values it is where the edge is.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.special import erf

from board.acquisition import PanoramaGeometry, load_panorama, write_panorama
from board.detect import detect_skyline
from board.errors import FormatError, InvalidInputError
from board.transfer import check_transfer, srgb_decode, srgb_encode, to_linear


def test_decode_inverts_encode_and_the_lookup_tables_equal_the_formula():
    x = np.linspace(0.0, 1.0, 2001)
    np.testing.assert_allclose(srgb_decode(srgb_encode(x)), x, atol=1e-12)
    # the standard's fixed points: 0.5 encoded is 0.214 linear, the linear segment below 0.04045
    assert float(srgb_decode(np.array(0.5))) == pytest.approx(0.21404, abs=1e-5)
    assert float(srgb_decode(np.array(0.04))) == pytest.approx(0.04 / 12.92)
    for dtype, full in ((np.uint8, 255), (np.uint16, 65535)):
        v = np.arange(0, full + 1, max(full // 997, 1), dtype=dtype)
        np.testing.assert_allclose(to_linear(v, "srgb"), srgb_decode(v / full), rtol=0, atol=2e-7)
        np.testing.assert_allclose(to_linear(v, "linear"), v / full, atol=1e-7)
    assert to_linear(np.array([True, False]), "srgb").tolist() == [1.0, 0.0]


def test_unknown_transfer_is_refused_with_the_accepted_values():
    with pytest.raises(InvalidInputError, match="srgb, linear"):
        check_transfer("gamma2.2")
    assert check_transfer(" SRGB ") == "srgb"


def _edge_image(top: float, bottom: float, *, psf_px: float, width: int = 720, height: int = 160, seed: int = 0):
    """(encoded uint16 image, true edge row per column): a smooth random skyline, exact pixel-area
    coverage convolved with a Gaussian PSF of ``psf_px`` (all in linear light), then sRGB."""
    rng = np.random.default_rng(seed)
    c = np.arange(width)
    k = rng.integers(1, 6, 3)
    edge = 80.0 + sum(a * np.sin(2 * np.pi * kk * c / width + p)
                      for kk, a, p in zip(k, rng.uniform(2, 8, 3), rng.uniform(0, 6.3, 3)))
    r = np.arange(height)[:, None]
    # fraction of ground (below the edge) in a pixel [r - 0.5, r + 0.5] after the PSF: the integral of
    # Phi((y - edge) / s) over the pixel, exactly (antiderivative of the normal CDF)
    s = psf_px

    def big_phi(t):
        return t * 0.5 * (1 + erf(t / np.sqrt(2))) + np.exp(-t * t / 2) / np.sqrt(2 * np.pi)

    ground = s * (big_phi((r + 0.5 - edge[None, :]) / s) - big_phi((r - 0.5 - edge[None, :]) / s))
    lin = top + (bottom - top) * ground
    img = np.rint(srgb_encode(lin) * 65535).astype(np.uint16)
    return img, edge


@pytest.mark.parametrize("top,bottom", [(0.6, 0.08), (0.02, 0.35)], ids=["bright sky", "black sky"])
def test_line_is_placed_on_the_light_not_on_the_encoded_values(top, bottom):
    img, edge = _edge_image(top, bottom, psf_px=0.7)
    right = detect_skyline(img, wrap=True, transfer="srgb")
    wrong = detect_skyline(img, wrap=True, transfer="linear")   # the encoded values taken as light
    ok = np.isfinite(right.line_row) & np.isfinite(wrong.line_row)
    assert ok.mean() > 0.95
    err_right = right.line_row[ok] - edge[ok]
    err_wrong = wrong.line_row[ok] - edge[ok]
    # the detector's rows: a line at y means rows < y are sky, the boundary between rows b-1 and b is b-0.5
    assert abs(np.mean(err_right)) < 0.03, np.mean(err_right)
    assert np.median(np.abs(err_right)) < 0.05
    # encoded, the step's half-way point moves towards the dark side: into the ground under a bright sky
    # (rows grow downwards), into the sky over a dark one; 0.1 to 0.6 px for these levels and PSF
    dark_side = 1.0 if bottom < top else -1.0
    assert 0.08 < dark_side * np.mean(err_wrong) < 0.8, np.mean(err_wrong)


def test_manifest_transfer_round_trips_and_a_bad_one_is_refused(tmp_path):
    g = PanoramaGeometry.full_circle(72, 36, elevation_top_deg=45.0, elevation_bottom_deg=-45.0)
    img = np.zeros((36, 72), np.uint8)
    write_panorama(tmp_path / "lin", img, g, transfer="linear")
    assert load_panorama(tmp_path / "lin").transfer == "linear"
    write_panorama(tmp_path / "default", img, g)
    assert load_panorama(tmp_path / "default").transfer == "srgb"
    with pytest.raises(InvalidInputError, match="transfer"):
        write_panorama(tmp_path / "bad", img, g, transfer="log")
    assert not (tmp_path / "bad" / "panorama.json").exists()
    doc = json.loads((tmp_path / "lin" / "panorama.json").read_text())
    doc["transfer"] = "gamma"
    (tmp_path / "lin" / "panorama.json").write_text(json.dumps(doc))
    with pytest.raises(FormatError, match="transfer"):
        load_panorama(tmp_path / "lin")
