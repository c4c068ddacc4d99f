"""Statistics of the descent evaluation against independent computations."""
import numpy as np
import pytest
from scipy import stats

from render_service.descent_eval.report import compute_tables, tables_markdown
from render_service.descent_eval.stats import bayes_paired, cohens_d, improvement_percent, mean_band


def test_improvement_and_cohens_d_by_hand():
    a = np.array([10.0, 12.0, 14.0])  # mean 12, var 4
    b = np.array([5.0, 6.0, 7.0])  # mean 6, var 1
    assert improvement_percent(a, b) == pytest.approx(50.0)
    assert cohens_d(a, b) == pytest.approx(6.0 / np.sqrt(2.5))
    assert cohens_d(b, a) == cohens_d(a, b)  # a magnitude, as the memorandum's table 2
    assert np.isnan(cohens_d(a[:1], b[:1]))


def test_paired_posterior_hdi_is_the_paired_t_interval():
    rng = np.random.default_rng(0)
    a = rng.normal(5.0, 1.0, 30)
    b = a - rng.normal(0.4, 0.6, 30)
    po = bayes_paired(a, b)
    ci = stats.ttest_rel(a, b).confidence_interval(0.95)  # frequentist twin under the flat prior
    assert po.mode == pytest.approx(np.mean(a - b))
    assert (po.hdi_lo, po.hdi_hi) == pytest.approx((ci.low, ci.high), rel=1e-9)
    assert po.n == 30


def test_rope_mass_matches_a_monte_carlo_of_the_normal_inverse_chi2_posterior():
    rng = np.random.default_rng(1)
    d = rng.normal(0.3, 0.8, 12)
    a, b = d + 3.0, np.full(12, 3.0)
    po = bayes_paired(a, b, rope=0.5)
    n, m, s2 = d.size, d.mean(), d.var(ddof=1)
    # sigma^2 | data ~ scaled-inv-chi2(n-1, s^2); mu | sigma^2, data ~ N(m, sigma^2 / n)   (BDA3 eq. 3.5-3.6)
    sig2 = (n - 1) * s2 / rng.chisquare(n - 1, 400_000)
    mu = rng.normal(m, np.sqrt(sig2 / n))
    mc = 100 * np.mean(np.abs(mu) <= 0.5)
    assert po.rope_percent == pytest.approx(mc, abs=0.5)
    lo, hi = np.percentile(mu, [2.5, 97.5])
    assert (po.hdi_lo, po.hdi_hi) == pytest.approx((lo, hi), abs=0.02)


def test_mean_band_is_the_t_interval_per_time():
    rng = np.random.default_rng(2)
    c = rng.normal(0, 1, (5, 7))
    m, h = mean_band(c)
    for j in range(7):
        ci = stats.t.interval(0.95, 4, loc=c[:, j].mean(), scale=stats.sem(c[:, j]))
        assert (m[j] - h[j], m[j] + h[j]) == pytest.approx(ci)


def _rows():
    rows = []
    rng = np.random.default_rng(3)
    for traj in (1, 2):
        for trial in range(4):
            base = rng.normal(5, 0.5)
            for mode, off in (("visible", 2.0), ("thermal", 1.0), ("dual", 0.0), ("visible-64", 1.5)):
                rows.append({"trajectory": traj, "trial": trial, "mode": mode, "E_percent": base + off})
    return rows


def test_tables_pair_trials_and_render_beside_the_memorandum():
    rows = _rows()
    modes = ("visible", "thermal", "dual", "visible-64")
    t = compute_tables(rows, modes)
    ev = np.array([r["E_percent"] for r in rows if r["trajectory"] == 1 and r["mode"] == "visible"])
    ed = np.array([r["E_percent"] for r in rows if r["trajectory"] == 1 and r["mode"] == "dual"])
    assert t["t1"][1]["visible"] == pytest.approx(ev.mean())
    assert t["t2"][1][("visible", "dual")][0] == pytest.approx(100 * (ev.mean() - ed.mean()) / ev.mean())
    po = t["t3"][1][("visible", "dual")]
    assert po.mode == pytest.approx(2.0) and po.hdi_lo == pytest.approx(2.0) and po.rope_percent < 1e-9
    md = tables_markdown(t, modes)
    assert "12.31" in md and "5.786" in md  # the memorandum's trajectory-1 figures sit beside ours
    header = [ln for ln in md.splitlines() if ln.startswith("| traj | Vis vs T-IR I")][0]
    sep = md.splitlines()[md.splitlines().index(header) + 1]
    assert header.count("|") == sep.count("|")
