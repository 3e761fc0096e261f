"""Tempered SMC, the HMC and independence-mixture moves, and the mode finder, on targets with known answers."""

import emcee
import numpy as np
import pytest
from scipy.special import logsumexp

from bayestouch.inference.modes import find_modes
from bayestouch.inference.sampler import HamiltonianMove, IndependenceMixture, sample
from bayestouch.inference.smc import local_covariances, systematic_resample, tempered_smc

# a bimodal 2-D likelihood (a normalised density of θ): weights 0.3 / 0.7 at x = ∓4, sd 0.5, under a uniform
# prior on [-10, 10]²; evidence Z = 1/400 (the modes lie far inside the box)
W = np.array([0.3, 0.7])
MU = np.array([[-4.0, 0.0], [4.0, 0.0]])
SD = 0.5
BOX = 10.0


def _log_lik(x):
    x = np.atleast_2d(x)
    d2 = np.sum((x[:, None, :] - MU[None]) ** 2, axis=2)
    return logsumexp(np.log(W)[None] - 0.5 * d2 / SD**2 - np.log(2 * np.pi * SD**2), axis=1)


def _grad_log_lik(x):
    d2 = np.sum((x[:, None, :] - MU[None]) ** 2, axis=2)
    lw = np.log(W)[None] - 0.5 * d2 / SD**2
    r = np.exp(lw - logsumexp(lw, axis=1, keepdims=True))  # responsibilities
    return np.einsum("nk,nkd->nd", r, -(x[:, None, :] - MU[None]) / SD**2)


def _log_prior(x):
    x = np.atleast_2d(x)
    return np.where(np.all(np.abs(x) <= BOX, axis=1), 0.0, -np.inf)


def _sample_prior(count, rng):
    return rng.uniform(-BOX, BOX, (count, 2))


def _gradients(x):
    return _log_prior(x), _log_lik(x), np.zeros_like(x), _grad_log_lik(x)


@pytest.mark.parametrize("hmc", [False, True])
def test_smc_weights_modes_widths_and_evidence(hmc):
    r = tempered_smc(
        _log_lik,
        _log_prior,
        _sample_prior,
        np.random.default_rng(1),
        particles=2000,
        gradients=_gradients if hmc else None,
    )
    assert r.complete and r.betas[-1] == 1.0
    right = r.particles[:, 0] > 0
    n = len(right)
    # weight of the right mode: 0.7 ± 4 binomial sds of an ESS at least a quarter of the particles
    assert abs(right.mean() - 0.7) < 4 * np.sqrt(0.21 / (n / 4))
    # within-mode sd 0.5 per coordinate: a posterior 30 % too narrow (0.35) or too wide fails
    for m in (right, ~right):
        sd = r.particles[m].std(axis=0)
        assert np.all(np.abs(sd / SD - 1) < 0.12), sd
    # log-evidence −log 400 = −5.99; SMC's error here is a few tenths of a nat
    assert abs(r.log_evidence + np.log(4 * BOX**2)) < 0.3


def test_smc_negative_control_without_moves_collapses():
    """With no Metropolis steps the particles only reweight prior draws: the modes collapse onto a few particles
    (the test above would fail on this population)."""
    r = tempered_smc(
        _log_lik, _log_prior, _sample_prior, np.random.default_rng(1), particles=2000, min_steps=0, max_steps=0
    )
    assert len(np.unique(r.particles, axis=0)) < 200


def test_systematic_resample_counts():
    w = np.array([0.1, 0.2, 0.7])
    idx = systematic_resample(w, np.random.default_rng(0))
    counts = np.bincount(idx, minlength=3)
    assert np.all(np.abs(counts - 3 * w) < 1)


def test_local_covariances_of_separated_clusters_are_local():
    rng = np.random.default_rng(0)
    a = rng.normal([0, 0], [1.0, 0.1], (500, 2))
    b = rng.normal([100, 100], [0.1, 1.0], (500, 2))
    cov = local_covariances(np.vstack([a, b]), 400, np.array([0, 500]))
    # each neighbourhood sees its own cluster's anisotropy, not the 100-unit gap
    assert cov[0][0, 0] > 10 * cov[0][1, 1]
    assert cov[1][1, 1] > 10 * cov[1][0, 0]
    assert cov[0][0, 0] < 4.0


def _gauss_logp(cov):
    inv = np.linalg.inv(cov)

    def logp(x):
        x = np.atleast_2d(x)
        return -0.5 * np.einsum("ni,ij,nj->n", x, inv, x)

    def grads(x):
        x = np.atleast_2d(x)
        return np.zeros(len(x)), logp(x), np.zeros_like(x), -x @ inv

    return logp, grads


def test_hamiltonian_move_samples_a_correlated_gaussian():
    cov = np.array([[1.0, 0.9, 0.0], [0.9, 1.0, 0.0], [0.0, 0.0, 0.01]])
    logp, grads = _gauss_logp(cov)
    w = 16
    chols = np.repeat(np.eye(3)[None] * 0.3, w, axis=0)  # a poor, isotropic mass matrix: correctness, not speed
    rng = np.random.default_rng(0)
    ch = sample(
        logp,
        rng.normal(size=(w, 3)) * 0.1,
        None,
        walkers=w,
        ndim=3,
        seed=0,
        steps=3000,
        progress=False,
        moves=[(HamiltonianMove(grads, chols, 0.1, steps=10), 1.0)],
    )
    x = ch.kept.reshape(-1, 3)
    var = x.var(axis=0)
    # ESS ≥ ~1000 → relative sd of a variance ≈ √(2/1000) = 4.5 %; tolerance 20 % (a 30 % error fails)
    assert np.all(np.abs(var / np.diag(cov) - 1) < 0.2), var
    assert abs(np.corrcoef(x[:, 0], x[:, 1])[0, 1] - 0.9) < 0.05


def _bimodal_chain(move, seed: int, walkers: int = 16):
    """3000 steps of the 2-D bimodal target with ``move`` alone, walkers started half in each mode."""
    start = MU[np.arange(walkers) % 2] + 0.1 * np.random.default_rng(0).normal(size=(walkers, 2))
    return sample(
        lambda x: _log_lik(x) + _log_prior(x),
        start,
        None,
        walkers=walkers,
        ndim=2,
        seed=seed,
        steps=3000,
        progress=False,
        moves=[(move, 1.0)],
    )


def test_independence_mixture_corrects_wrong_proposal_weights():
    """Target: the 2-D bimodal density (weights 0.3 / 0.7); proposal: equal weights on the two modes and too
    wide. The chain must recover 0.7, not the proposal's 0.5."""
    centres = MU.copy()
    chols = np.repeat(np.eye(2)[None] * 0.8, 2, axis=0)
    mix = IndependenceMixture(centres, chols, emcee.moves.DEMove())
    ch = _bimodal_chain(mix, seed=3)
    right = (ch.kept[..., 0] > 0).mean()
    assert abs(right - 0.7) < 0.04
    assert abs(ch.kept[..., 0][ch.kept[..., 0] > 0].std() - SD) < 0.05


def test_weighted_independence_mixture_samples_the_target_not_its_weights():
    """A mixture weighted 0.1 / 0.9 where the target holds 0.3 / 0.7: the component weights enter the proposal
    density, so the chain still gives 0.7. Negative control: the same draws scored as if the weights were equal
    (the weights left out of the density) give a chain that is off."""
    centres = MU.copy()
    chols = np.repeat(np.eye(2)[None] * 0.8, 2, axis=0)

    def run(mix):
        return (_bimodal_chain(mix, seed=4).kept[..., 0] > 0).mean()

    mix = IndependenceMixture(centres, chols, emcee.moves.DEMove(), weights=[0.9, 0.1])
    assert np.allclose(mix.weights, [0.9, 0.1])
    draws = mix.draw(np.random.RandomState(0), 20000)
    assert abs(np.mean(np.linalg.norm(draws - MU[0], axis=1) < np.linalg.norm(draws - MU[1], axis=1)) - 0.9) < 0.01
    assert abs(run(mix) - 0.7) < 0.04

    class Unweighted(IndependenceMixture):
        def log_g(self, x):
            saved = self._log_det
            self._log_det = saved + self._log_w
            try:
                return super().log_g(x)
            finally:
                self._log_det = saved

    bad = Unweighted(centres, chols, emcee.moves.DEMove(), weights=[0.9, 0.1])
    assert abs(run(bad) - 0.7) > 0.1
    with pytest.raises(ValueError, match="weights"):
        IndependenceMixture(centres, chols, emcee.moves.DEMove(), weights=[1.0, -1.0])


def test_find_modes_two_separated_one_skewed():
    rng = np.random.default_rng(0)
    two = np.vstack([rng.normal(0, 1, (700, 2)), rng.normal([8, 0], 1, (300, 2))])
    lab = find_modes(two, rng)
    assert lab.max() == 1
    assert abs((lab == 0).mean() - 0.7) < 0.02
    assert np.all(lab[:700] == 0)
    skewed = np.column_stack([rng.gamma(2.0, 1.0, 2000), rng.normal(0, 1, 2000)])
    assert find_modes(skewed, rng).max() == 0
    # two overlapping Gaussians 2 sds apart are one mode
    close = np.vstack([rng.normal(0, 1, (500, 2)), rng.normal([2, 0], 1, (500, 2))])
    assert find_modes(close, rng).max() == 0


def test_gaussian_mixture_recovers_a_known_mixture_and_bic_picks_its_size():
    """EM + BIC on draws of a known two-component mixture in 6 dimensions (weights 0.7/0.3, distinct
    covariances, scales from 1e-3 to 1 as θ's centre and log-axes have): weights, means and covariances within
    a few Monte Carlo standard errors, K = 2; negative control: one Gaussian gives K = 1."""
    from bayestouch.inference.modes import gaussian_mixture

    rng = np.random.default_rng(3)
    d, n = 6, 3000
    scale = np.array([1e-3, 1e-3, 1.0, 0.1, 0.1, 1.0])
    A = rng.normal(size=(d, d)) * 0.3 + np.eye(d)
    cov0, cov1 = A @ A.T, np.diag(rng.uniform(0.2, 1.0, d))
    mu1 = np.full(d, 4.0)
    k = rng.random(n) < 0.7
    z = np.where(k[:, None], rng.multivariate_normal(np.zeros(d), cov0, n), rng.multivariate_normal(mu1, cov1, n))
    w, mu, cov = gaussian_mixture(z * scale, rng)
    assert len(w) == 2
    se_w = np.sqrt(0.21 / n)
    assert abs(w[0] - 0.7) < 4 * se_w
    np.testing.assert_allclose(mu[0] / scale, 0.0, atol=4 * np.sqrt(np.diag(cov0).max() / (0.7 * n)))
    np.testing.assert_allclose(mu[1] / scale, mu1, atol=4 * np.sqrt(1.0 / (0.3 * n)))
    np.testing.assert_allclose(cov[0] / np.outer(scale, scale), cov0, atol=0.15 * np.diag(cov0).max())
    np.testing.assert_allclose(cov[1] / np.outer(scale, scale), cov1, atol=0.15)
    one = rng.multivariate_normal(np.zeros(d), cov0, n) * scale
    assert len(gaussian_mixture(one, rng)[0]) == 1
    with pytest.raises(ValueError, match="more than D"):
        gaussian_mixture(one[:6], rng)


# a correlated 2-D Gaussian (sds 2 and 0.5, correlation 0.8) and an independence mixture of the wrong place and
# size (the situation of an SMC run that found another mode, or a Laplace component for a wide ridge)
G_MEAN = np.array([1.0, -1.0])
G_COV = np.array([[4.0, 0.8], [0.8, 0.25]])


def _gauss(x):
    z = np.atleast_2d(x) - G_MEAN
    return -0.5 * np.einsum("ni,ij,nj->n", z, np.linalg.inv(G_COV), z)


def _wrong_mixture(adaptive: bool) -> IndependenceMixture:
    return IndependenceMixture(
        (G_MEAN + [3.0, 0.0])[None], 0.2 * np.eye(2)[None], emcee.moves.DEMove(), adaptive=adaptive
    )


def _mixture_run(mix, path, steps: int, resume: bool = False):
    start = G_MEAN + 0.1 * np.random.default_rng(0).normal(size=(16, 2))
    return sample(
        _gauss,
        start,
        path,
        walkers=16,
        ndim=2,
        seed=5,
        steps=steps,
        progress=False,
        adapt=True,
        moves=[(mix, 0.8), (emcee.moves.DEMove(), 0.2)],
        resume=resume,
    )


def test_adaptive_mixture_learns_the_posterior_its_start_got_wrong():
    """An adaptive mixture refitted to the chain (defensive share of the given one kept) is accepted most of the
    time and samples the target's covariance; the fixed mixture (negative control) almost never is."""
    mix = _wrong_mixture(adaptive=True)
    ch = _mixture_run(mix, None, 1600)
    assert ch.acceptance > 0.5
    # the given component keeps exactly the defensive share
    assert mix.weights[-1] == pytest.approx(mix.defensive)
    np.testing.assert_array_equal(mix.centres[-1], G_MEAN + [3.0, 0.0])
    x = ch.kept.reshape(-1, 2)
    # thousands of effective draws: a variance to ~5 %; tolerance 15 % (a 30 % error fails)
    assert np.all(np.abs(x.var(axis=0) / np.diag(G_COV) - 1) < 0.15), x.var(axis=0)
    assert np.corrcoef(x.T)[0, 1] == pytest.approx(0.8, abs=0.05)
    fixed = _wrong_mixture(adaptive=False)
    assert _mixture_run(fixed, None, 1600).acceptance < 0.2
    assert not fixed.refit(x, _gauss(x), np.random.default_rng(0))
    assert len(fixed.centres) == 1


def test_adaptive_mixture_resume_replays_the_refits(tmp_path):
    """The mixture in force is a function of the stored chain: a run stopped at step 400 and resumed holds the
    mixture the uninterrupted run held there, and continues its chain bit for bit."""
    full = _wrong_mixture(adaptive=True)
    _mixture_run(full, tmp_path / "full.h5", 400)
    _mixture_run(_wrong_mixture(adaptive=True), tmp_path / "cut.h5", 300)
    resumed = _wrong_mixture(adaptive=True)
    _mixture_run(resumed, tmp_path / "cut.h5", 400, resume=True)
    assert len(full.centres) > 1
    np.testing.assert_array_equal(resumed.centres, full.centres)
    np.testing.assert_array_equal(resumed.chols, full.chols)
    a = emcee.backends.HDFBackend(str(tmp_path / "full.h5"), read_only=True).get_chain()
    b = emcee.backends.HDFBackend(str(tmp_path / "cut.h5"), read_only=True).get_chain()
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="defensive"):
        IndependenceMixture(G_MEAN[None], np.eye(2)[None], emcee.moves.DEMove(), defensive=1.0)


def test_hmc_steps_reuse_the_gradients_at_the_particles_and_move_them_exactly_as_without():
    """Three HMC steps with the gradient cache move the particles exactly as three without it (same seeds), with
    one gradient call fewer per step after the first; a cache holding wrong gradients changes the moves (the
    control: the cached values are really used)."""
    from bayestouch.inference.smc import hmc_step

    def run(cache, calls):
        def counted(y):
            calls.append(len(y))
            return _gradients(y)

        rng = np.random.default_rng(5)
        x = rng.normal(4.0, 1.0, (256, 2))
        lp, ll = _log_prior(x), _log_lik(x)
        chol = np.broadcast_to(0.5 * np.eye(2), (256, 2, 2))
        acc = [hmc_step(x, lp, ll, chol, 0.7, 0.4, 5, counted, rng, cache=cache) for _ in range(3)]
        return x, lp, ll, acc

    plain_calls, cached_calls = [], []
    plain = run(None, plain_calls)
    cached = run({}, cached_calls)
    for a, b in zip(plain, cached, strict=True):
        np.testing.assert_array_equal(a, b)
    assert len(plain_calls) == 3 * 6 and len(cached_calls) == 3 * 6 - 2
    wrong_calls: list = []
    rng = np.random.default_rng(5)
    x0 = rng.normal(4.0, 1.0, (256, 2))
    wrong = run({"ga": np.zeros_like(x0), "gb": np.full_like(x0, 50.0)}, wrong_calls)
    assert not np.array_equal(wrong[0], plain[0])


def test_tempered_smc_with_the_gradient_cache_is_the_smc_without_it(monkeypatch):
    """The whole tempering with gradients: its particles, temperatures and evidence are those of the same run whose
    HMC steps recompute every gradient (the cache dropped), bit for bit, with fewer gradient calls."""
    from bayestouch.inference import smc

    calls = {"n": 0}

    def counted(y):
        calls["n"] += 1
        return _gradients(y)

    def run():
        calls["n"] = 0
        r = tempered_smc(
            _log_lik, _log_prior, _sample_prior, np.random.default_rng(4), particles=500, gradients=counted
        )
        return r, calls["n"]

    cached, n_cached = run()
    plain_step = smc.hmc_step
    monkeypatch.setattr(smc, "hmc_step", lambda *a, cache=None, **k: plain_step(*a, **k))
    plain, n_plain = run()
    np.testing.assert_array_equal(cached.particles, plain.particles)
    np.testing.assert_array_equal(cached.betas, plain.betas)
    assert cached.log_evidence == plain.log_evidence
    stages = len(plain.betas) - 1
    assert n_plain - n_cached == 2 * stages  # the second and third HMC steps of every stage start from the cache
