"""Per-trajectory statistics of the evaluation (the memorandum's tables 1-3).

* improvement ``I = 100 (E_a - E_b) / E_a`` of the mean E of mode b over mode a (eq. 10);
* Cohen's d with the pooled standard deviation ``sqrt((s_a^2 + s_b^2) / 2)``, reported as a magnitude
  (as the memorandum's table 2; the sign is that of I);
* paired Bayesian t-test on the per-trial differences ``delta = E_a - E_b`` (percentage points):
  with the non-informative prior p(mu, sigma^2) ~ 1 / sigma^2 the posterior of the mean difference is a
  Student t with n - 1 degrees of freedom, location mean(delta) and scale sd(delta) / sqrt(n) (Gelman
  et al., BDA3, sec. 3.2).  Mode = mean(delta); 95 % HDI = mode +- t_0.975 scale (symmetric); the
  probability in the ROPE [-0.5, 0.5] pp is the posterior mass there.  The trials are independent
  simulations, so no correlation correction (cf. Benavoli et al. 2017 for cross-validation) applies.
  ROPE: +-0.5 percentage points of E, the half-width the memorandum's table 3 implies (e.g. its
  trajectory 4, Vis vs T-IR: mode -0.501 with 50 % in the ROPE).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

ROPE_PP = 0.5


def improvement_percent(e_a: np.ndarray, e_b: np.ndarray) -> float:
    ma = float(np.mean(e_a))
    return 100.0 * (ma - float(np.mean(e_b))) / ma if ma != 0 else float("nan")


def cohens_d(e_a: np.ndarray, e_b: np.ndarray) -> float:
    """|mean_a - mean_b| / pooled sd (sample sds, ddof 1); NaN with fewer than two trials."""
    a, b = np.asarray(e_a, float), np.asarray(e_b, float)
    if a.size < 2 or b.size < 2:
        return float("nan")
    s = math.sqrt((a.var(ddof=1) + b.var(ddof=1)) / 2.0)
    return abs(float(a.mean() - b.mean())) / s if s > 0 else float("inf")


@dataclass(frozen=True)
class PairedPosterior:
    """Posterior of the mean paired difference: mode, 95 % HDI (lo, hi), % of mass in the ROPE, n."""

    mode: float
    hdi_lo: float
    hdi_hi: float
    rope_percent: float
    n: int


def bayes_paired(e_a: np.ndarray, e_b: np.ndarray, *, rope: float = ROPE_PP, mass: float = 0.95) -> PairedPosterior:
    """Closed-form Student posterior of mean(E_a - E_b) over paired trials (see the module docstring)."""
    d = np.asarray(e_a, float) - np.asarray(e_b, float)
    n = d.size
    if n < 2:
        return PairedPosterior(float(d.mean()) if n else float("nan"), float("nan"), float("nan"), float("nan"), n)
    mu = float(d.mean())
    scale = float(d.std(ddof=1)) / math.sqrt(n)
    if scale == 0:
        inside = 100.0 if abs(mu) <= rope else 0.0
        return PairedPosterior(mu, mu, mu, inside, n)
    post = stats.t(df=n - 1, loc=mu, scale=scale)
    lo, hi = post.interval(mass)
    return PairedPosterior(mu, float(lo), float(hi), 100.0 * float(post.cdf(rope) - post.cdf(-rope)), n)


def mean_band(curves: np.ndarray, level: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Mean over trials (rows) of error curves and the half-width of its ``level`` t-interval (NaN-aware)."""
    c = np.asarray(curves, float)
    n = np.sum(np.isfinite(c), axis=0)
    m = np.nanmean(c, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.nanstd(c, axis=0, ddof=1) / np.sqrt(n)
        q = stats.t.ppf(0.5 + level / 2, np.maximum(n - 1, 1))
    return m, np.where(n >= 2, q * s, np.nan)
