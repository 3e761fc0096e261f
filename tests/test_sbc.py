"""Is the contact-level posterior right? A small simulation-based calibration (with an overconfident negative
control) and a NUTS cross-check of emcee on the same log-density."""

import numpy as np
import pytest
from scipy.stats import binom

from bayestouch.inference import sbc as cal

N_SETS, N_DRAWS = 30, 39  # 39 draws: the 2nd to 38th order statistics are an exact 90 % interval (k = 2)


def test_invariants_are_symmetry_invariant():
    rng = np.random.default_rng(0)
    th = cal.draw_prior(rng)
    perm = th.copy()
    perm[3:6] = th[[4, 5, 3]]  # permuted axes (with a matching rotation the same surface): same sorted axes
    perm[6:9] = 0.0
    a, b = cal.invariants(th), cal.invariants(perm)
    assert np.allclose(a, b)
    # volume: n = 2 gives the ellipsoid 4/3 π abc
    th[9] = np.log(2.0)
    assert cal.invariants(th)[8] == pytest.approx(4 / 3 * np.pi * np.prod(np.exp(th[3:6])), rel=1e-12)


def test_rank_and_coverage_bookkeeping():
    # ranks of exact draws are uniform; coverage_of is exact for L = 39 (k = 2 → 36/40)
    rng = np.random.default_rng(1)
    truths = rng.normal(size=(4000, 1))
    draws = rng.normal(size=(4000, N_DRAWS, 1))
    r = cal.ranks_of(truths, draws)
    cov, expected = cal.coverage_of(r, N_DRAWS, 0.9)
    assert expected == pytest.approx(0.9)
    assert abs(cov[0] - 0.9) < 4 * np.sqrt(0.09 / 4000)  # 4 binomial sds
    assert cal.uniformity_pvalues(r, N_DRAWS, 10)[0] > 1e-3
    # negative control: a 2× too narrow "posterior" fails both
    r_bad = cal.ranks_of(truths, 0.5 * draws)
    assert cal.coverage_of(r_bad, N_DRAWS)[0][0] < 0.7
    assert cal.uniformity_pvalues(r_bad, N_DRAWS, 10)[0] < 1e-6


@pytest.fixture(scope="module")
def small_sbc():
    """With the adaptive sampler that ``bayestouch fit`` uses (the engine's default moves are checked against known
    posteriors in test_sampler.py)."""
    return cal.sbc(N_SETS, seed=2, n_points=100, walkers=32, steps=400, n_draws=N_DRAWS, batch=10, adapt=True)


def _flagged(coverage) -> bool:
    """Pooled coverage below the 0.1 % quantile of Binomial(N_SETS, 0.9)/N_SETS: conservative, as if the nine
    quantities of one data set were one trial (they are correlated: axes, n and volume move together)."""
    return bool(np.mean(coverage) < binom.ppf(1e-3, N_SETS, 0.9) / N_SETS)


@pytest.mark.slow
def test_sbc_contact_posterior_is_calibrated(small_sbc):
    res = small_sbc
    assert res.ranks.shape == (N_SETS, len(cal.QUANTITIES)) and res.short == 0
    assert res.coverage_expected == pytest.approx(0.9)
    assert not _flagged(res.coverage), res.coverage
    # each quantity: 0.1 % binomial quantile; 9 of them → family-wise false alarm < 1 %
    assert np.all(res.coverage >= binom.ppf(1e-3, N_SETS, 0.9) / N_SETS), res.coverage
    assert np.min(res.chi2_p) > 1e-3 / len(res.names), res.chi2_p


@pytest.mark.slow
def test_sbc_flags_an_overconfident_posterior(small_sbc):
    """Negative control: the same draws shrunk to half their spread about their mean (a posterior 2× too sure)."""
    res = small_sbc
    mean = res.draws.mean(axis=1, keepdims=True)
    narrow = mean + 0.5 * (res.draws - mean)
    cov, _ = cal.coverage_of(cal.ranks_of(res.truths, narrow), N_DRAWS)
    assert _flagged(cov), cov


@pytest.mark.slow
def test_sbc_is_seeded():
    a = cal.sbc(2, seed=5, n_points=30, walkers=24, steps=120, n_draws=9, batch=2)
    b = cal.sbc(2, seed=5, n_points=30, walkers=24, steps=120, n_draws=9, batch=1)  # batching changes nothing
    assert np.array_equal(a.draws, b.draws) and np.array_equal(a.truths, b.truths)


@pytest.mark.slow
def test_nuts_agrees_with_emcee(tmp_path):
    """emcee (the engine with its default moves: with emcee 3.1.6's own snooker move in them, the sds came out
    8–18 % below NUTS's here) and numpyro NUTS on the same contact log-density and data: posterior
    means agree within 4 combined Monte-Carlo standard errors (MCSE = sd/√ESS, ESS from the integrated
    autocorrelation time of each sampler), posterior sds within 15 %."""
    from emcee.autocorr import integrated_time

    from bayestouch.inference.contact import make_log_prob
    from bayestouch.inference.nuts import nuts_contact
    from bayestouch.inference.run import start_ball
    from bayestouch.inference.sampler import sample

    rng = np.random.default_rng(3)
    theta0 = np.array(
        [0.001, -0.002, 0.0, np.log(0.04), np.log(0.027), np.log(0.015), 0.9, 0.6, -0.5, np.log(2.5), np.log(3e-4)]
    )
    pts = cal.simulate_points(theta0, 100, rng)
    logp, bounds = make_log_prob(pts)
    ch = sample(
        logp,
        start_ball(theta0, bounds, 32, rng),
        None,
        walkers=32,
        ndim=11,
        seed=4,
        steps=1500,
        progress=False,
    )
    e = ch.kept.reshape(-1, 11)
    ess_e = len(e) / integrated_time(ch.kept, tol=0)
    nuts = nuts_contact(pts, seed=4, num_warmup=300, num_samples=600, init=theta0)
    n = nuts["theta"][0]
    ess_n = len(n) / integrated_time(n[:, None, :], tol=0)
    assert nuts["diverging"].sum() == 0
    se = np.sqrt(e.var(axis=0) / ess_e + n.var(axis=0) / ess_n)
    z = (e.mean(axis=0) - n.mean(axis=0)) / se
    assert np.all(np.abs(z) < 4), z
    assert np.all(np.abs(e.std(axis=0) / n.std(axis=0) - 1) < 0.15), e.std(axis=0) / n.std(axis=0)
    # natural parameters are θ's transforms
    assert np.allclose(nuts["a"], np.exp(nuts["theta"][..., 3])) and np.allclose(
        nuts["n"], np.exp(nuts["theta"][..., 9])
    )
