"""The sub-pixel line on the linear colour projected on the local sky -> ground colour difference.

Truth is analytic: a skyline whose pixels are integrated exactly over their area in linear light (each
channel), blurred by a Gaussian optics PSF, sRGB-encoded.  The sky is a blue grey and the ground a tan of
almost the same brightness, textured, and brighter in the two rows under the crest (a sunlit rim): the
grey step is weak and the texture moves it; the colour difference is large, and a pixel mixing sky and
ground is linear in its sky share in every channel, so the projected step's half-way point is the edge.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.special import erf

from board.detect import detect_skyline
from board.detect.sky_regions import DetectorParams
from board.transfer import srgb_encode

SKY_BGR = np.array([0.42, 0.33, 0.28])      # linear light, B G R (OpenCV order): a blue-grey sky
GROUND_BGR = np.array([0.20, 0.32, 0.42])   # a tan ground of about the sky's luminance


def _coverage(r, edge, s):
    def big_phi(t):
        return t * 0.5 * (1 + erf(t / np.sqrt(2))) + np.exp(-t * t / 2) / np.sqrt(2 * np.pi)

    return s * (big_phi((r + 0.5 - edge) / s) - big_phi((r - 0.5 - edge) / s))


def colour_edge_image(*, crest_gain: float, texture: float, width: int = 1440, height: int = 200, seed: int = 0,
                      psf_px: float = 0.6):
    """(uint8 BGR sRGB image, true edge row per column): ground below a smooth random skyline."""
    rng = np.random.default_rng(seed)
    c = np.arange(width)
    edge = 100.0 + sum(a * np.sin(2 * np.pi * k * c / width + p)
                       for k, a, p in zip(rng.integers(1, 9, 4), rng.uniform(2, 10, 4), rng.uniform(0, 6.3, 4)))
    r = np.arange(height)[:, None]
    ground = _coverage(r, edge[None, :], psf_px)                      # ground share of each pixel
    depth = r - edge[None, :]                                         # rows below the edge
    shade = 1.0 + texture * rng.standard_normal((height, width)) + crest_gain * ((depth > -0.5) & (depth < 2.0))
    lin = SKY_BGR[None, None, :] * (1 - ground[..., None]) + (GROUND_BGR[None, None, :] * shade[..., None]) \
        * ground[..., None]
    img = np.rint(np.clip(srgb_encode(np.clip(lin, 0, 1)), 0, 1) * 255).astype(np.uint8)
    return img, edge


def _errors(img, edge, **params):
    det = detect_skyline(img, wrap=True, transfer="srgb", params=replace(DetectorParams(), **params))
    return det.line_row - edge


def test_the_colour_step_places_the_line_where_the_log_chroma_step_is_biased():
    img, edge = colour_edge_image(crest_gain=0.0, texture=0.0)
    e_on, e_off = _errors(img, edge), _errors(img, edge, linear_colour_step=False)
    assert np.isfinite(e_on).mean() > 0.95 and np.isfinite(e_off).mean() > 0.95
    # rows: a line at y means rows < y are sky; the exact edge is where the pixels' ground share is half
    assert abs(np.nanmean(e_on)) < 0.01 and np.sqrt(np.nanmean(e_on ** 2)) < 0.04
    # the grey hardly steps here, so the line was on the log blue/red step: not linear in the mix, biased
    assert np.nanmean(e_off) > 0.04


def test_the_ground_s_shading_does_not_move_the_colour_step():
    """A textured ground (8 % per pixel) with a sunlit crest 25 % brighter in the two rows under the edge:
    the difference is taken across the ground's own colour, which shading only scales."""
    img, edge = colour_edge_image(crest_gain=0.25, texture=0.08)
    e_on, e_off = _errors(img, edge), _errors(img, edge, linear_colour_step=False)
    assert np.isfinite(e_on).mean() > 0.95
    assert abs(np.nanmean(e_on)) < 0.01 and np.sqrt(np.nanmean(e_on ** 2)) < 0.04
    assert np.sqrt(np.nanmean(e_on ** 2)) <= np.sqrt(np.nanmean(e_off ** 2))


def test_grey_images_and_colourless_skies_keep_the_grey_step():
    img, edge = colour_edge_image(crest_gain=0.0, texture=0.02)
    grey = np.rint(img.astype(np.float64).mean(axis=2)).astype(np.uint8)
    np.testing.assert_array_equal(_errors(grey, edge), _errors(grey, edge, linear_colour_step=False))
    # a sky of the ground's own colour (a grey lunar sky over grey regolith, only darker): nothing across it
    rng = np.random.default_rng(1)
    c = np.arange(1440)
    edge = 100.0 + 6.0 * np.sin(2 * np.pi * 3 * c / 1440)
    cov = _coverage(np.arange(200)[:, None], edge[None, :], 0.6)
    lin = (0.05 + 0.30 * cov * (1 + 0.03 * rng.standard_normal((200, 1440))))[..., None] * np.ones(3)
    img = np.rint(srgb_encode(np.clip(lin, 0, 1)) * 255).astype(np.uint8)
    np.testing.assert_allclose(_errors(img, edge), _errors(img, edge, linear_colour_step=False), atol=1e-6)


def test_a_channel_clipped_in_the_sky_is_left_out_of_the_colour_step():
    """A sky whose blue channel is over full scale (a high sun over a dark ground, exposed for the ground): the
    clipped channel is not linear in the mix; the step is taken on the other two, still on the edge."""
    global SKY_BGR
    saved = SKY_BGR
    try:
        SKY_BGR = np.array([3.0, 0.55, 0.30])          # blue far over full scale (0.7 px off if it were used)
        img, edge = colour_edge_image(crest_gain=0.0, texture=0.02)
    finally:
        SKY_BGR = saved
    assert (img[:60, :, 0] == 255).all()
    e_on = _errors(img, edge)
    assert np.isfinite(e_on).mean() > 0.95
    assert abs(np.nanmean(e_on)) < 0.03 and np.sqrt(np.nanmean(e_on ** 2)) < 0.06
