"""The reference report's skyline detector, reproduced as described (the baseline).

grey -> CLAHE -> Gaussian blur -> Canny (thresholds from Otsu) and Sobel magnitude -> a
multistage graph over the columns (moves to the next column and within the column) with the
cost of entering a node

    0.3 * |G(prev) - G(node)|  +  0.05 * (1 - G(node))  +  0.3 * (1 - E(node))  +  0.35 * row / (H - 1)

(G: Sobel magnitude scaled to [0, 1]; E: Canny edge, 0 or 1; the last term prefers high
rows), solved here by dynamic programming (:mod:`board.detect.graph_dp`) instead of the
report's Dijkstra; same graph, same optimum.  No confidence, no masking: every column gets
a row.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from board.detect.graph_dp import shortest_path_dp
from board.detect.preprocess import to_grey01

log = logging.getLogger(__name__)

W_GRAD_DIFF = 0.3
W_GRAD = 0.05
W_EDGE = 0.3
W_HEIGHT = 0.35


@dataclass(frozen=True)
class BaselineGraph:
    """node (H, W), pair (3, H, W), vert (H, W) costs of the report's graph (see the module docstring)."""

    node: np.ndarray
    pair: np.ndarray
    vert: np.ndarray


def baseline_features(image: np.ndarray, *, clahe_clip: float = 2.0, blur_sigma: float = 1.5
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Sobel magnitude G in [0, 1] and Canny edges E in {0, 1} (float32, (H, W)) as the report computes them."""
    import cv2

    grey, _ = to_grey01(image)
    g8 = np.clip(grey * 255.0 + 0.5, 0, 255).astype(np.uint8)
    g8 = cv2.createCLAHE(clipLimit=clahe_clip, tileGridSize=(8, 8)).apply(g8)
    g8 = cv2.GaussianBlur(g8, (0, 0), blur_sigma)
    otsu, _ = cv2.threshold(g8, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    edges = cv2.Canny(g8, 0.5 * otsu, otsu) > 0
    f = g8.astype(np.float32)
    gx = cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3)
    mag = cv2.magnitude(gx, gy)
    mag /= max(float(mag.max()), 1e-6)
    return mag, edges.astype(np.float32)


def baseline_graph(image: np.ndarray) -> BaselineGraph:
    """The report's cost graph for ``image`` (see the module docstring)."""
    G, E = baseline_features(image)
    H, W = G.shape
    height = (np.arange(H, dtype=np.float32) / max(H - 1, 1))[:, None]
    node = W_GRAD * (1.0 - G) + W_EDGE * (1.0 - E) + W_HEIGHT * height
    prevG = np.empty((3, H, W), dtype=np.float32)
    Gp = np.roll(G, 1, axis=1)                     # column c-1 (wraps for column 0)
    prevG[0, 1:] = Gp[:-1]
    prevG[0, 0] = Gp[0]
    prevG[1] = Gp
    prevG[2, :-1] = Gp[1:]
    prevG[2, -1] = Gp[-1]
    pair = W_GRAD_DIFF * np.abs(prevG - G[None])
    vert = np.zeros_like(G)
    vert[1:] = W_GRAD_DIFF * np.abs(G[1:] - G[:-1])
    return BaselineGraph(node.astype(np.float32), pair, vert)


def detect_baseline(image: np.ndarray, *, wrap: bool = False) -> np.ndarray:
    """Skyline row (int, topmost path row) of every column by the report's method; (W,) int array."""
    g = baseline_graph(image)
    return shortest_path_dp(g.node, pair_cost=g.pair, vert_cost=g.vert, wrap=wrap).rows_top
