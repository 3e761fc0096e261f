"""The users'-conditions SBC of benchmarks/bench_sbc_users.py: its truths follow the fit's prior, its data carry the
prior's outliers, and its rank tests pass an exact posterior and reject one 30 % too narrow or too wide (power)."""

import math

import numpy as np
from scipy import stats

from bayestouch.inference import contact as cm
from benchmarks import bench_sbc_users as sb


def conjugate_ranks(n_sets: int, factor: float, seed: int) -> np.ndarray:
    """Ranks (n_sets, 2) of truths among L draws of the exact posterior of a normal mean (prior N(0, 1), one
    observation with noise sd 0.5), its spread multiplied by ``factor``; two independent quantities."""
    rng = np.random.default_rng(seed)
    mu = rng.normal(size=(n_sets, 2))
    y = mu + 0.5 * rng.normal(size=(n_sets, 2))
    post_var = 1.0 / (1.0 + 1.0 / 0.25)
    post_mean = post_var * y / 0.25
    draws = post_mean[:, None, :] + factor * math.sqrt(post_var) * rng.normal(size=(n_sets, sb.DRAWS, 2))
    return np.sum(draws < mu[:, None, :], axis=1)


def test_exact_posterior_passes_every_check():
    r = conjugate_ranks(200, 1.0, seed=1)
    cov, p, band = sb.coverage(r)
    assert np.all((cov >= band[0]) & (cov <= band[1]))
    assert np.all(sb.chi2_uniform(r) > 0.01)
    assert not sb.ecdf_outside(r).any()


def test_thirty_percent_too_narrow_is_rejected():
    """Power at the benchmark's size (200 sets): a posterior 30 % too narrow fails all three checks, for every seed
    (measured: 100 of 100 seeds for each check)."""
    for seed in (1, 2, 3):
        r = conjugate_ranks(200, 0.7, seed)
        cov, _, band = sb.coverage(r)
        assert np.all(cov < band[0])
        assert np.all(sb.chi2_uniform(r) < 0.01)
        assert sb.ecdf_outside(r).all()


def test_thirty_percent_too_wide_is_rejected_often_and_exact_rarely():
    """Over 40 replicate benchmarks of 200 sets, a posterior 30 % too wide lifts the coverage above its binomial band
    in ≥ 90 % of them and fails the chi-square test at 5 % in ≥ 75 % (measured 97 % and 90 % over 100); the exact
    posterior does either in ≤ 15 % (nominal 5 % each)."""
    wide = [conjugate_ranks(200, 1.3, 10 + s)[:, 0] for s in range(40)]
    exact = [conjugate_ranks(200, 1.0, 10 + s)[:, 0] for s in range(40)]

    def verdicts(ranks):
        cov, _, band = sb.coverage(ranks[:, None])
        return cov[0] > band[1], sb.chi2_uniform(ranks[:, None])[0] < 0.05

    w = np.array([verdicts(r) for r in wide])
    e = np.array([verdicts(r) for r in exact])
    assert w[:, 0].mean() >= 0.9 and w[:, 1].mean() >= 0.75
    assert e.any(axis=1).mean() <= 0.15


def test_squeezed_ranks_reproduce_a_narrow_posterior():
    """The negative control of the benchmark (draws squeezed about their median) is rejected like a truly narrow
    posterior; stretching by 1/0.7 undoes it within Monte Carlo error."""
    rng = np.random.default_rng(4)
    n = 200
    mu = rng.normal(size=(n, 1))
    centre = mu + rng.normal(size=(n, 1))  # the truth is a draw of its posterior N(centre, 1)
    draws = centre[:, None, :] + rng.normal(size=(n, sb.DRAWS, 1))
    truth_ranks = np.array([sb.ranks_of(mu[i], draws[i]) for i in range(n)])
    squeezed = np.array([sb.squeezed_ranks(mu[i], draws[i], 0.7) for i in range(n)])
    assert not sb.ecdf_outside(truth_ranks).any()
    assert sb.ecdf_outside(squeezed).all()
    unchanged = np.array([sb.squeezed_ranks(mu[i], draws[i], 1.0) for i in range(n)])
    assert np.array_equal(unchanged, truth_ranks)


def test_ecdf_band_holds_its_level():
    """The simultaneous band contains ~95 % of calibrated rank sets (binomial 99.9 % range for 400 of them)."""
    rng = np.random.default_rng(100)
    outside = [sb.ecdf_outside(rng.integers(0, sb.DRAWS + 1, (200, 1)))[0] for _ in range(400)]
    lo, hi = stats.binom.ppf([0.0005, 0.9995], 400, 0.05)
    assert lo <= sum(outside) <= hi


def test_truths_follow_the_fits_prior():
    p = cm.with_size_prior(cm.load_priors(), *sb.SIZE_PRIOR_M)
    mu, sd = cm.size_prior(p)
    rng = np.random.default_rng(5)
    th = [sb.draw_truth(rng) for _ in range(600)]
    log_a = np.log([t["axes"] for t in th]).ravel()
    assert stats.kstest(log_a, stats.norm(mu, sd).cdf).pvalue > 0.01
    u = (np.log([t["n"] for t in th]) - math.log(p.n_min)) / math.log(p.n_max / p.n_min)
    assert stats.kstest(u, "uniform").pvalue > 0.01
    u = (np.log([t["sigma"] for t in th]) - math.log(p.sigma_min)) / math.log(p.sigma_max / p.sigma_min)
    assert stats.kstest(u, "uniform").pvalue > 0.01
    w = np.array([[t["w_in"], t["w_out"]] for t in th]).ravel() / (0.5 * p.outlier_max)
    assert stats.kstest(w, "uniform").pvalue > 0.01


def test_data_sets_carry_the_priors_outliers_and_noise():
    """Over 15 sets the displaced fractions match the drawn w_in, w_out (binomial), displaced contacts lie on their
    side of the surface, and the others within 5 noise sds of it."""
    sets = [sb.make_sbc_set(s) for s in range(15)]
    m = np.array([len(s["points"]) for s in sets])
    assert m.min() >= sb.POINTS_RANGE[0] and m.max() <= sb.POINTS_RANGE[1]
    n_in = sum(int(np.sum(s["outlier_sign"] < 0)) for s in sets)
    expect = sum(s["theta"]["w_in"] * len(s["points"]) for s in sets)
    assert abs(n_in - expect) < 4 * math.sqrt(expect)
    for s in sets[:10]:
        t = s["truth"]
        theta = np.concatenate([t.centre, np.log(t.axes), t.angles, [math.log(float(t.n)), 0.0]])
        d = np.asarray(cm.residuals(theta, s["points"]))
        tol = 5 * s["theta"]["sigma"] + 1e-6
        sig = s["outlier_sign"]
        assert np.all(np.abs(d[sig == 0]) < tol)
        assert np.all(d[sig > 0] > 0) and np.all(d[sig < 0] < 0)
    assert all(len(s["free"]) > 0 for s in sets)


def test_local_mode_check_accepts_the_truth_and_rejects_a_wrong_one():
    """A data set with noise 0.03 % of its smallest semi-axis: the truth sits within ½χ²₁₃ of its local mode; the
    same truth with σ a quarter of it (a truth the data did not come from, the negative control) is rejected."""
    s = sb.make_sbc_set(4)
    got = sb.local_mode_gap(s)
    assert got["noise_ratio"] < 1e-3
    assert got["local_gap_p"] > 1e-3 and 0 <= got["local_gap"] < 20
    wrong = {**s, "theta": {**s["theta"], "sigma": 0.25 * s["theta"]["sigma"]}}
    bad = sb.local_mode_gap(wrong)
    assert bad["local_gap_p"] < 1e-6 and bad["local_gap"] > got["local_gap"] + 10


def test_noise_bands_split_coverage_and_the_local_check():
    rows = []
    for k, (ratio, rank, p) in enumerate([(5e-4, 50, 0.5), (5e-4, 0, 0.5), (0.2, 99, 0.001), (0.2, 40, 0.01)]):
        row = {"seed": k, "noise_ratio": ratio, "local_gap_p": p, "local_gap": 3.0}
        row |= {f"rank_{q}": rank for q in sb.QUANTITIES}
        rows.append(row)
    bands = sb.noise_bands(rows)["bands"]
    low, high = bands[0], bands[-1]
    assert (low["sets"], low["coverage_90_volume"], low["local_gap_rejected_5pct"]) == (2, 0.5, 0.0)
    assert (high["sets"], high["coverage_90_volume"], high["local_gap_rejected_5pct"]) == (2, 0.5, 1.0)
    assert bands[1]["sets"] == bands[2]["sets"] == 0 and bands[1]["coverage_90_volume"] is None
