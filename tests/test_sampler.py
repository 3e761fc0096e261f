"""The emcee engine (bayestouch.inference.sampler) on a target with a known posterior, and its bookkeeping:
seeding, resuming after an interruption, the time budget, and honest convergence diagnostics."""

import shutil

import numpy as np
import pytest

from bayestouch.errors import BadInput
from bayestouch.inference.sampler import Chain, convergence, sample

D = 3
TAU_PRIOR = 2.0  # prior sd of each coefficient
NOISE_SD = 0.5


def _problem():
    """y = A θ + ε, ε ~ N(0, s²I), θ ~ N(0, τ²I): the posterior is N(μ, Σ) with Σ = (AᵀA/s² + I/τ²)⁻¹,
    μ = Σ Aᵀy/s² (conjugate Gaussian linear model)."""
    rng = np.random.default_rng(7)
    A = rng.normal(size=(12, D))
    A[:, 1] += 0.8 * A[:, 0]  # correlated columns → correlated posterior
    y = A @ np.array([0.5, -1.0, 2.0]) + NOISE_SD * rng.normal(size=12)
    cov = np.linalg.inv(A.T @ A / NOISE_SD**2 + np.eye(D) / TAU_PRIOR**2)
    return A, y, cov @ A.T @ y / NOISE_SD**2, cov


def _log_prob(A, y, noise_var):
    def f(thetas):
        r = y[None, :] - thetas @ A.T
        return -0.5 * np.sum(r * r, axis=1) / noise_var - 0.5 * np.sum(thetas**2, axis=1) / TAU_PRIOR**2

    return f


def _start(seed=0, walkers=32):
    """An over-dispersed start (the posterior sds are ≈ 0.2)."""
    return np.random.default_rng(seed).normal(scale=1.0, size=(walkers, D))


def _de_moves():
    import emcee

    return [(emcee.moves.DEMove(), 1.0)]


KNOWN = {"walkers": 64, "steps": 700}  # 700 steps > 50 τ (τ ≈ 11 here), ESS ≈ 3000


def _agrees(chain: Chain, mean, cov, k: float = 4.0) -> bool:
    """Posterior mean, variances and correlations of ``chain`` match N(mean, cov) within k Monte-Carlo
    standard errors. ESS = S·W/τ_max (emcee's integrated autocorrelation time, the largest over parameters,
    so the ESS is conservative); MCSE of a mean = sd/√ESS; of a Gaussian sample variance, var·√(2/ESS); of a
    correlation, (1 − ρ²)/√ESS. With 15 statistics at k = 4 a correct sampler fails with probability < 1e-3."""
    flat = chain.kept.reshape(-1, D)
    ess = flat.shape[0] / chain.tau_max
    sd = np.sqrt(np.diag(cov))
    rho = cov / np.outer(sd, sd)
    m, c = flat.mean(axis=0), np.cov(flat.T)
    r = c / np.sqrt(np.outer(np.diag(c), np.diag(c)))
    iu = np.triu_indices(D, 1)
    return bool(
        np.all(np.abs(m - mean) < k * sd / np.sqrt(ess))
        and np.all(np.abs(np.diag(c) / sd**2 - 1) < k * np.sqrt(2 / ess))
        and np.all(np.abs(r[iu] - rho[iu]) < k * (1 - rho[iu] ** 2) / np.sqrt(ess))
    )


def _full_chain(path):
    import emcee

    return emcee.backends.HDFBackend(str(path), read_only=True).get_chain()


@pytest.fixture(scope="module")
def known(tmp_path_factory):
    A, y, mean, cov = _problem()
    path = tmp_path_factory.mktemp("known") / "chain.h5"
    ch = sample(
        _log_prob(A, y, NOISE_SD**2),
        _start(walkers=KNOWN["walkers"]),
        path,
        ndim=D,
        seed=3,
        progress=False,
        moves=_de_moves(),
        **KNOWN,
    )
    return A, y, mean, cov, ch


def test_known_posterior_recovered(known):
    A, y, mean, cov, ch = known
    assert np.isfinite(ch.tau_max) and ch.kept.shape[0] * ch.kept.shape[1] / ch.tau_max > 1000
    assert _agrees(ch, mean, cov)


def test_known_posterior_with_default_moves(tmp_path):
    """The engine's own moves (DE + the corrected snooker): emcee 3.1.6's DESnookerMove in their place gives
    variances ~10 % low here, which this check catches (see test_emcee_snooker_is_biased)."""
    A, y, mean, cov = _problem()
    ch = sample(
        _log_prob(A, y, NOISE_SD**2),
        _start(walkers=KNOWN["walkers"]),
        tmp_path / "d.h5",
        ndim=D,
        seed=3,
        progress=False,
        **KNOWN,
    )
    assert _agrees(ch, mean, cov)


def test_wrong_log_density_fails_the_same_check(known, tmp_path):
    """Negative control: the noise variance mis-scaled by 2 (posterior ~2× too wide) must fail ``_agrees``."""
    A, y, mean, cov, _ = known
    bad = sample(
        _log_prob(A, y, 2 * NOISE_SD**2),
        _start(walkers=KNOWN["walkers"]),
        tmp_path / "bad.h5",
        ndim=D,
        seed=3,
        progress=False,
        moves=_de_moves(),
        **KNOWN,
    )
    assert not _agrees(bad, mean, cov)


def test_convergence_claimed_for_long_chain_only(known, tmp_path):
    from numpyro.diagnostics import effective_sample_size, split_gelman_rubin

    A, y, mean, cov, ch = known
    # the same optimistic R-hat and ESS for both chains, so only the chain length decides
    assert convergence(np.ones(D), np.full(D, 1e6), ch)["converged"]
    short = sample(
        _log_prob(A, y, NOISE_SD**2),
        _start(),
        tmp_path / "short.h5",
        walkers=32,
        ndim=D,
        seed=3,
        steps=40,
        progress=False,
    )
    # even with perfect R-hat and ESS claimed, 40 steps are < 50 autocorrelation times
    assert not convergence(np.ones(D), np.full(D, 1e6), short)["converged"]
    per_walker = np.swapaxes(short.kept, 0, 1)
    assert not convergence(split_gelman_rubin(per_walker), effective_sample_size(per_walker), short)["converged"]


def _chain_of(steps: int, tau: float, budget: bool = False) -> Chain:
    kept = np.zeros((steps, 4, 2))
    return Chain(kept, np.zeros((steps, 4)), steps, 0, tau, 0.3, budget, 1.0, steps)


def test_a_chain_that_fails_convergence_says_which_check_and_how_much_longer():
    names = ["a", "b", "volume"]
    ok_r, ok_e = [1.001, 1.002, 1.003], [5000.0, 4000.0, 3000.0]
    # a converged chain (1000 kept steps > 50 τ of 10) has no reasons
    d = convergence(ok_r, ok_e, _chain_of(1000, 10.0), names=names)
    assert d["converged"] and d["not_converged_because"] == []
    # each failed check is named, the worst quantity first, and nothing that passed
    d = convergence([1.001, 1.08, 1.02], [5000.0, 120.0, 3000.0], _chain_of(1000, 10.0), names=names)
    why = d["not_converged_because"]
    assert not d["converged"] and len(why) == 3, why
    assert why[0].startswith("R-hat") and "2 quantities (b 1.080, volume 1.020)" in why[0], why[0]
    assert why[1].startswith("bulk ESS") and "1 quantity (b 120)" in why[1], why[1]
    assert "--steps" in why[2] and "--budget" not in why[2]
    # the chain too short for its τ: 400 kept steps of τ = 20 are 20 τ; 50 τ need 601 more steps
    why = convergence(ok_r, ok_e, _chain_of(400, 20.0, budget=True), names=names)["not_converged_because"]
    assert len(why) == 2 and "20 autocorrelation times of τ = 20 steps" in why[0] and "601 more steps" in why[0]
    assert "--budget" in why[1]
    # NaN (a quantity that never moved) fails and is named first
    why = convergence([1.001, float("nan"), 1.5], ok_e, _chain_of(1000, 10.0), names=names)["not_converged_because"]
    assert "(b nan, volume 1.500)" in why[0], why[0]
    with pytest.raises(ValueError, match="names"):
        convergence([1.5, 1.0], [10.0, 10.0], _chain_of(1000, 10.0), names=["only one"])


def test_seed_reproducible_and_distinct(tmp_path):
    A, y, _, _ = _problem()
    f = _log_prob(A, y, NOISE_SD**2)
    chains = []
    for name, seed in (("a", 11), ("b", 11), ("c", 12)):
        sample(f, _start(), tmp_path / f"{name}.h5", walkers=32, ndim=D, seed=seed, steps=60, progress=False)
        chains.append(_full_chain(tmp_path / f"{name}.h5"))
    assert np.array_equal(chains[0], chains[1])
    assert not np.allclose(chains[0][1:], chains[2][1:])  # step 0 is the shared start's first move at most


class _Interrupted(Exception):
    pass


def test_resume_after_interruption(tmp_path):
    A, y, _, _ = _problem()
    f = _log_prob(A, y, NOISE_SD**2)
    sample(f, _start(), tmp_path / "full.h5", walkers=32, ndim=D, seed=5, steps=120, progress=False)
    full = _full_chain(tmp_path / "full.h5")
    calls = {"n": 0}

    def dies(thetas):  # a run killed after ~40 steps (2 log-prob calls per DE step, 4 per snooker step)
        calls["n"] += 1
        if calls["n"] > 100:
            raise _Interrupted
        return f(thetas)

    path = tmp_path / "cut.h5"
    with pytest.raises(_Interrupted):
        sample(dies, _start(), path, walkers=32, ndim=D, seed=5, steps=120, progress=False)
    cut = _full_chain(path)
    assert 0 < len(cut) < 120
    shutil.copy(path, tmp_path / "cut2.h5")
    ch = sample(f, _start(seed=99), path, walkers=32, ndim=D, seed=5, steps=120, resume=True, progress=False)
    resumed = _full_chain(path)
    assert ch.steps == 120 and resumed.shape == full.shape
    assert np.array_equal(resumed[: len(cut)], cut)  # nothing sampled before the kill is lost or changed
    assert np.array_equal(cut, full[: len(cut)])  # and it is the un-interrupted run's beginning
    sample(f, _start(seed=98), tmp_path / "cut2.h5", walkers=32, ndim=D, seed=5, steps=120, resume=True, progress=False)
    assert np.array_equal(_full_chain(tmp_path / "cut2.h5"), resumed)  # the continuation is reproducible
    # a resumed chain must match the ensemble it continues
    from bayestouch.errors import BadInput

    with pytest.raises(BadInput, match="walkers"):
        sample(f, _start(walkers=16), path, walkers=16, ndim=D, seed=5, steps=150, resume=True, progress=False)


def test_budget_stops_early_and_says_so(tmp_path):
    import time

    A, y, _, _ = _problem()
    f = _log_prob(A, y, NOISE_SD**2)

    def slow(thetas):
        time.sleep(0.002)
        return f(thetas)

    ch = sample(
        slow, _start(), tmp_path / "b.h5", walkers=32, ndim=D, seed=1, steps=100_000, budget_s=0.3, progress=False
    )
    assert ch.stopped_by_budget and 0 < ch.steps < 100_000
    assert len(_full_chain(tmp_path / "b.h5")) == ch.steps
    ok = sample(f, _start(), tmp_path / "ok.h5", walkers=32, ndim=D, seed=1, steps=20, budget_s=600, progress=False)
    assert not ok.stopped_by_budget and ok.steps == 20
    # a budget spent before the chain began (t0 long ago) still leaves min_steps steps, marked as stopped by it
    late = sample(
        f,
        _start(),
        tmp_path / "late.h5",
        walkers=32,
        ndim=D,
        seed=1,
        steps=500,
        budget_s=1.0,
        min_steps=40,
        t0=time.perf_counter() - 10.0,
        progress=False,
    )
    assert late.stopped_by_budget and late.steps == 40


def test_emcee_snooker_is_biased_and_ours_is_not():
    """Negative control for the moves: emcee 3.1.6's DESnookerMove alone leaves the target's variances ~50 % low,
    which the same check catches; the engine's corrected snooker alone passes it."""
    import emcee

    from bayestouch.inference.sampler import snooker_move

    A, y, mean, cov = _problem()
    run = {"walkers": 64, "steps": 1500}
    stock = sample(
        _log_prob(A, y, NOISE_SD**2),
        _start(walkers=64),
        None,
        ndim=D,
        seed=4,
        progress=False,
        moves=[(emcee.moves.DESnookerMove(), 1.0)],
        **run,
    )
    ours = sample(
        _log_prob(A, y, NOISE_SD**2),
        _start(walkers=64),
        None,
        ndim=D,
        seed=4,
        progress=False,
        moves=[(snooker_move(), 1.0)],
        **run,
    )
    assert not _agrees(stock, mean, cov)
    assert np.all(np.var(stock.kept.reshape(-1, D), axis=0) < 0.8 * np.diag(cov))
    assert _agrees(ours, mean, cov)


def test_snooker_leaves_a_walker_whose_archive_point_is_itself_where_it_is():
    """z = the walker (a copy of it in the other half): no direction to project on; the move proposes the walker
    itself with a zero log-Jacobian instead of 0/0 = NaN, on which emcee stops the run."""
    from bayestouch.inference.sampler import snooker_move

    move = snooker_move()
    s = np.array([[1.0, 2.0, 3.0], [0.5, 0.5, 0.5]])
    c = [np.array([[1.0, 2.0, 3.0]])] * 3  # every archive draw is the first walker
    q, log_jac = move.get_proposal(s, c, np.random.RandomState(0))
    assert np.all(np.isfinite(q)) and np.all(np.isfinite(log_jac))
    np.testing.assert_array_equal(q[0], s[0])
    assert log_jac[0] == 0.0
    # the other walker moves along the line through z, and its log-Jacobian is (d − 1) log(|q − z| / |x − z|)
    z = c[0][0]
    u = (s[1] - z) / np.linalg.norm(s[1] - z)
    assert np.linalg.norm(np.cross(q[1] - z, u)) < 1e-12
    assert log_jac[1] == 0.0  # z1 − z2 = 0: q = x


def test_prune_stuck_walkers_replaces_only_walkers_far_below_the_best():
    from bayestouch.inference.sampler import prune_stuck_walkers

    rng = np.random.default_rng(5)
    D = 11
    ens = rng.standard_normal((32, D))  # draws of N(0, I): log p = −½|x|² (up to a constant)
    stuck = np.arange(26, 32)
    ens[stuck] += 8.0  # a local trap: ½·64·11 = 352 nats below
    lp = -0.5 * np.sum(ens**2, axis=1)
    new, replaced = prune_stuck_walkers(ens, lp, np.random.default_rng(0))
    assert replaced == 6
    np.testing.assert_array_equal(new[:26], ens[:26])  # the plausible walkers are kept bit for bit
    assert np.all(np.abs(new[stuck]).max(axis=1) < 5.0)  # the replaced ones sit among the plausible ones
    # negative control: a true posterior sample loses no walker (P(prune one of 32) = 32e-4 at tail 1e-4)
    clean = rng.standard_normal((32, D))
    assert prune_stuck_walkers(clean, -0.5 * np.sum(clean**2, axis=1), np.random.default_rng(0))[1] == 0
    with pytest.raises(BadInput, match="start"):
        prune_stuck_walkers(clean, np.full(32, -np.inf), np.random.default_rng(0))


# ------------------------------------------------------------------------------------------ adaptive sampling


def test_integrated_time_equals_emcee():
    """The vectorised τ estimator is emcee's estimator, to rounding, on AR(1) chains of several lengths."""
    from emcee.autocorr import integrated_time as emcee_tau

    from bayestouch.inference.sampler import integrated_time

    rng = np.random.default_rng(0)
    e = rng.normal(size=(800, 16, 4))
    x = np.empty_like(e)
    x[0] = e[0]
    for t in range(1, len(e)):
        x[t] = np.array([0.0, 0.5, 0.9, 0.97]) * x[t - 1] + e[t]
    for n in (40, 333, 800):
        np.testing.assert_allclose(integrated_time(x[:n]), emcee_tau(x[:n], tol=0), rtol=1e-10)
    # AR(1) with φ = 0.9: τ = (1 + φ)/(1 − φ) = 19; the estimate on 800 × 16 draws is within 25 %
    assert abs(integrated_time(x)[2] / 19.0 - 1) < 0.25


def test_stationarity_guard():
    from bayestouch.inference.sampler import _stationary

    rng = np.random.default_rng(1)
    flat = -0.5 * rng.chisquare(11, size=(100, 32))  # log-densities of stationary draws, D = 11
    climbing = flat + np.linspace(-60.0, 0.0, 100)[:, None]  # an ensemble still rising towards the mode
    assert _stationary(flat) and not _stationary(climbing)
    assert not _stationary(np.full((100, 32), -np.inf))


def _gamma_log_prob(thetas):
    """Independent Gamma(k = 3, scale 1) in each of 3 coordinates: mean 3, variance 3, kurtosis 5 (skewed, so a
    symmetric t proposal never matches it)."""
    t = np.asarray(thetas)
    inside = np.all(t > 0, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        lp = np.sum(2.0 * np.log(t) - t, axis=1)
    return np.where(inside, lp, -np.inf)


def _gamma_moments_agree(chain, k: float = 4.0) -> bool:
    """Mean and variance of every coordinate within k Monte-Carlo standard errors of Gamma(3, 1)'s: ESS = draws/τ_max;
    MCSE of a mean √(var/ESS), of a sample variance var·√((κ − 1)/ESS) with kurtosis κ = 3 + 6/k_shape = 5."""
    flat = chain.kept.reshape(-1, 3)
    ess = flat.shape[0] / chain.tau_max
    return bool(
        np.all(np.abs(flat.mean(axis=0) - 3.0) < k * np.sqrt(3.0 / ess))
        and np.all(np.abs(flat.var(axis=0) - 3.0) < k * 3.0 * np.sqrt(4.0 / ess))
    )


def test_independence_move_keeps_a_skewed_target_and_dropping_the_hastings_factor_does_not():
    """The t independence proposal alone (after a DE warm-up) samples a skewed Gamma target correctly; the same move
    with the proposal-density correction removed (accept on π(x')/π(x) only) samples ∝ π·g instead — too narrow —
    and fails the same check (negative control)."""
    import emcee

    from bayestouch.inference.sampler import IndependenceT

    class NoHastings(IndependenceT):
        def log_g(self, x):
            return np.zeros(len(x))

    start = np.random.default_rng(2).uniform(2.0, 4.0, size=(32, 3))
    run = {"walkers": 32, "ndim": 3, "steps": 1500, "progress": False, "adapt": True}
    good = sample(_gamma_log_prob, start, None, seed=6, moves=[(IndependenceT(emcee.moves.DEMove()), 1.0)], **run)
    bad = sample(_gamma_log_prob, start, None, seed=6, moves=[(NoHastings(emcee.moves.DEMove()), 1.0)], **run)
    assert good.acceptance > 0.3  # a fitted t proposal on a unimodal target: most proposals are accepted
    assert _gamma_moments_agree(good)
    assert not _gamma_moments_agree(bad)
    assert np.all(bad.kept.reshape(-1, 3).var(axis=0) < 0.8 * 3.0)


def test_adaptive_run_recovers_the_known_posterior_with_a_short_autocorrelation_time(known, tmp_path):
    """The adaptive moves on the linear-Gaussian target: the same moment check as DE, and τ at most a third of DE's
    (the independence proposal fitted to a Gaussian accepts most proposals)."""
    A, y, mean, cov, de_chain = known
    ch = sample(
        _log_prob(A, y, NOISE_SD**2),
        _start(walkers=KNOWN["walkers"]),
        tmp_path / "a.h5",
        ndim=D,
        seed=3,
        progress=False,
        adapt=True,
        **KNOWN,
    )
    assert ch.burn >= 100 and ch.tau_steps == KNOWN["steps"] - ch.burn  # τ of the kept draws
    assert _agrees(ch, mean, cov)
    assert ch.tau_max < de_chain.tau_max / 3, (ch.tau_max, de_chain.tau_max)


def test_adaptive_resume_rebuilds_the_proposal_of_the_uninterrupted_run(tmp_path):
    """The proposal at any step is a function of the stored chain: a run stopped at step 200 and resumed fits the same
    proposal (bit for bit) as the uninterrupted run did at step 200."""
    import emcee

    from bayestouch.inference.sampler import IndependenceT

    A, y, _, _ = _problem()
    f = _log_prob(A, y, NOISE_SD**2)

    def moves():
        ind = IndependenceT(emcee.moves.DEMove())
        return ind, [(ind, 0.8), (emcee.moves.DEMove(), 0.2)]

    ind_full, mv = moves()
    sample(
        f, _start(), tmp_path / "full.h5", walkers=32, ndim=D, seed=9, steps=250, progress=False, adapt=True, moves=mv
    )
    ind_cut, mv = moves()
    sample(
        f, _start(), tmp_path / "cut.h5", walkers=32, ndim=D, seed=9, steps=200, progress=False, adapt=True, moves=mv
    )
    np.testing.assert_array_equal(_full_chain(tmp_path / "cut.h5"), _full_chain(tmp_path / "full.h5")[:200])
    ind_resumed, mv = moves()
    sample(
        f,
        None,
        tmp_path / "cut.h5",
        walkers=32,
        ndim=D,
        seed=9,
        steps=200,
        progress=False,
        adapt=True,
        moves=mv,
        resume=True,
    )
    assert ind_full.mean is not None
    np.testing.assert_array_equal(ind_resumed.mean, ind_full.mean)
    np.testing.assert_array_equal(ind_resumed.chol, ind_full.chol)
    # negative control: the fit at step 100 (what a resume at step 150 would rebuild) is a different proposal
    ind_100, mv = moves()
    sample(
        f, _start(), tmp_path / "c100.h5", walkers=32, ndim=D, seed=9, steps=150, progress=False, adapt=True, moves=mv
    )
    assert not np.array_equal(ind_100.mean, ind_full.mean)


def test_a_given_proposal_starts_at_step_0_keeps_the_target_and_a_better_fit_replaces_a_poor_one(known, tmp_path):
    """``sample(..., proposal=(mean, cov))``: the independence move uses the given proposal from step 0 (τ and burn-in
    from step 0). The exact posterior as the proposal gives τ ≈ 1; a poor one (off by 1.5 sd, variances a quarter)
    still samples the known posterior (it only changes efficiency), and a refit, whose log weights spread less,
    replaces it (weight_spread orders the two proposals correctly on exact draws)."""
    import emcee

    from bayestouch.inference.sampler import IndependenceT, adaptive_moves

    A, y, mean, cov, _ = known
    f = _log_prob(A, y, NOISE_SD**2)
    exact = sample(
        f,
        _start(walkers=KNOWN["walkers"]),
        tmp_path / "e.h5",
        ndim=D,
        seed=4,
        progress=False,
        adapt=True,
        proposal=(mean, cov),
        moves=adaptive_moves(30.0),
        **KNOWN,
    )
    assert exact.burn == KNOWN["steps"] // 4 and exact.tau_steps == KNOWN["steps"] - exact.burn  # none skipped
    assert _agrees(exact, mean, cov)
    assert exact.tau_max < 2.0, exact.tau_max
    poor = (mean + 1.5 * np.sqrt(np.diag(cov)), 0.25 * cov)
    moves = adaptive_moves(30.0)
    ch = sample(
        f,
        _start(walkers=KNOWN["walkers"]),
        tmp_path / "p.h5",
        ndim=D,
        seed=4,
        progress=False,
        adapt=True,
        proposal=poor,
        moves=moves,
        **KNOWN,
    )
    assert _agrees(ch, mean, cov)
    ind = moves[0][0]
    assert not np.allclose(ind.mean, poor[0])  # replaced by a fit to the chain
    x = np.random.default_rng(0).multivariate_normal(mean, cov, 4000)
    lp = f(x)
    good, bad = IndependenceT(emcee.moves.DEMove(), 30.0), IndependenceT(emcee.moves.DEMove(), 30.0)
    good.set(mean, cov)
    bad.set(*poor)
    assert good.weight_spread(x, lp) < 0.3 < bad.weight_spread(x, lp)


def test_adaptive_resume_with_a_given_proposal_continues_bit_for_bit(tmp_path):
    """A run with a given proposal, stopped at step 90 (before the refit at 100) and resumed to 250, has the chain of
    the uninterrupted run bit for bit: the proposal in force is the given one, then replayed from it and the stored
    chain. Negative control: resumed without the given proposal, steps 90–100 fall back to DE and the chain
    differs."""
    from bayestouch.inference.sampler import adaptive_moves

    A, y, mean, cov = _problem()
    f = _log_prob(A, y, NOISE_SD**2)
    prop = (mean + 0.5 * np.sqrt(np.diag(cov)), 2.0 * cov)
    run = {"walkers": 32, "ndim": D, "seed": 9, "progress": False, "adapt": True, "proposal": prop}
    sample(f, _start(), tmp_path / "full.h5", steps=250, moves=adaptive_moves(30.0), **run)
    sample(f, _start(), tmp_path / "cut.h5", steps=90, moves=adaptive_moves(30.0), **run)
    shutil.copy(tmp_path / "cut.h5", tmp_path / "cut2.h5")
    sample(f, None, tmp_path / "cut.h5", steps=250, moves=adaptive_moves(30.0), resume=True, **run)
    np.testing.assert_array_equal(_full_chain(tmp_path / "cut.h5"), _full_chain(tmp_path / "full.h5"))
    sample(
        f, None, tmp_path / "cut2.h5", steps=250, moves=adaptive_moves(30.0), resume=True, **{**run, "proposal": None}
    )
    assert not np.array_equal(_full_chain(tmp_path / "cut2.h5"), _full_chain(tmp_path / "full.h5"))


def test_stop_rule_judges_the_monitored_quantities(tmp_path):
    """A converged Gaussian run stops well before its step cap; with a monitor whose quantity never mixes (a
    constant per walker, so R-hat is huge) the same run goes to the cap: the stopping rule checks what the summary
    will be judged on, not only the sampled parameters."""
    A, y, _, _ = _problem()
    f = _log_prob(A, y, NOISE_SD**2)
    kw = {
        "walkers": 32,
        "ndim": D,
        "seed": 1,
        "steps": 2000,
        "progress": False,
        "stop_when_converged": True,
        "adapt": True,
    }
    free = sample(f, _start(), tmp_path / "free.h5", **kw)
    assert free.steps < 2000, free.steps

    def stuck(flat):  # rows are step-major (S·W, D): walker = row % W
        return (np.arange(len(flat)) % 32)[:, None] + 1e-3 * flat[:, :1]

    held = sample(f, _start(), tmp_path / "held.h5", monitor=stuck, **kw)
    assert held.steps == 2000


def test_convergence_checks_map_each_step_through_the_monitor_once(tmp_path):
    """The stopping rule's checks map only the steps added since the last check: the monitor sees every draw of
    the chain exactly once over the whole run (rows counted), and the τ and burn-in it returns are those of the whole
    monitored chain mapped at once."""
    from bayestouch.inference.sampler import _tau_and_burn

    A, y, _, _ = _problem()
    f = _log_prob(A, y, NOISE_SD**2)
    kw = {"walkers": 32, "ndim": D, "seed": 1, "steps": 2000, "progress": False, "stop_when_converged": True}
    rows = []

    def counting(flat):
        rows.append(len(flat))
        return flat[:, :2] ** 2

    ch = sample(f, _start(), tmp_path / "a.h5", adapt=True, monitor=counting, **kw)
    assert ch.steps < 2000 and sum(rows) == ch.steps * 32
    assert len(rows) > 3  # several checks, each mapping its own new steps
    import emcee

    back = emcee.backends.HDFBackend(str(tmp_path / "a.h5"), read_only=True)
    full, lp = back.get_chain(), back.get_log_prob()
    tau, burn, _ = _tau_and_burn(full[:, :, :2] ** 2, True, log_prob=lp)
    assert ch.tau_max == float(np.max(tau)) and ch.burn == burn


def test_convergence_checks_thin_out_geometrically_so_long_runs_stay_linear():
    from bayestouch.inference.sampler import CHECK_GROWTH, _next_check

    lengths = [50]
    while lengths[-1] < 20_000:
        lengths.append(_next_check(lengths[-1], 50))
    gaps = np.diff(lengths)
    assert all(n % 50 == 0 for n in lengths)
    assert np.all(gaps >= 50) and np.all(gaps >= CHECK_GROWTH * np.asarray(lengths[:-1]))
    # no more than one check per 50 steps early on, and far fewer than a fixed spacing's 400 checks by 20 000 steps
    assert lengths[:11] == list(range(50, 551, 50))
    assert len(lengths) < 60
    # a gap never exceeds the growth fraction by more than one check interval (the run stops at most ~10 % late)
    assert np.all(gaps <= CHECK_GROWTH * np.asarray(lengths[:-1]) + 100)


def test_thinned_autocorrelation_time_is_the_whole_chains_and_falls_back_when_tau_is_short():
    """The convergence checks read τ from a long chain thinned to ~CHECK_STEPS steps: on AR(1) walkers with
    τ = (1 + ρ)/(1 − ρ) = 100 and 20,000 steps it equals the whole chain's estimate within 5 % (and the truth within
    the estimator's error); with τ ≈ 3 thinning would report ~k instead (negative control: thinned by hand, the
    estimate is 3× too large) and the whole chain is read."""
    from bayestouch.inference import sampler as S

    rng = np.random.default_rng(0)

    def ar1(tau, n, w=16):
        rho = (tau - 1) / (tau + 1)
        x = np.empty((n, w, 1))
        x[0] = rng.normal(size=(w, 1))
        e = rng.normal(size=(n, w, 1)) * np.sqrt(1 - rho**2)
        for t in range(1, n):
            x[t] = rho * x[t - 1] + e[t]
        return x

    long = ar1(100.0, 20000)
    full, thin = S.integrated_time(long)[0], S._thinned_time(long)[0]
    assert 20000 // S.CHECK_STEPS > 1
    assert abs(thin / full - 1) < 0.05 and abs(full / 100 - 1) < 0.15
    fast = ar1(3.0, 20000)
    k = 20000 // S.CHECK_STEPS
    by_hand = S.integrated_time(fast[::k])[0] * k
    assert by_hand > 2 * S.integrated_time(fast)[0]
    assert S._thinned_time(fast)[0] == S.integrated_time(fast)[0]


def test_ctrl_c_stops_after_the_step_saves_the_chain_and_prints_no_walkers(tmp_path, capsys):
    """A SIGINT while the log-density runs ends the chain after that step: the checkpoint holds the steps done and
    KeyboardInterrupt is raised outside emcee, which would otherwise print every walker and a traceback."""
    import os
    import signal
    import threading

    import emcee

    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers are installed from the main thread only")
    before = signal.getsignal(signal.SIGINT)
    calls = []

    def logp(x):
        calls.append(1)
        if len(calls) == 12:  # two half-batch calls per step: during step 6
            os.kill(os.getpid(), signal.SIGINT)
        return -0.5 * np.sum(np.asarray(x) ** 2, axis=1)

    start = np.random.default_rng(0).normal(size=(8, 2))
    with pytest.raises(KeyboardInterrupt):
        sample(logp, start, tmp_path / "c.h5", walkers=8, ndim=2, seed=0, steps=1000, progress=False)
    out = capsys.readouterr()
    assert "emcee" not in out.out + out.err and "params" not in out.out
    steps = emcee.backends.HDFBackend(str(tmp_path / "c.h5"), read_only=True).iteration
    assert 5 <= steps <= 7
    assert signal.getsignal(signal.SIGINT) is before  # the handler is restored


def test_proposals_of_a_degenerate_ensemble_are_finite():
    """An independence proposal fitted to an ensemble spread without bound along one direction (contacts in one
    plane) drew infinite coordinates, on which emcee stops the run ("At least one parameter value was infinite",
    issue 24, third review). Every draw is finite now, and one that overflowed lies far outside any prior (so it is
    rejected); negative control: an ordinary proposal's draws are unchanged."""
    from bayestouch.inference.sampler import OUTSIDE, IndependenceMixture, IndependenceT, finite_proposals

    rng = np.random.RandomState(0)
    move = IndependenceT(None)
    move.set(np.zeros(2), np.eye(2))
    move.chol = np.diag([1.0, 1e308])  # a scale whose t draws overflow
    x = move.draw(rng, 200)
    assert np.all(np.isfinite(x)) and np.any(np.abs(x) == OUTSIDE)
    mix = IndependenceMixture(np.array([[0.0, 800.0]]), np.array([np.diag([1.0, 50.0])]), None, 10.0, [1.0], [1])
    with np.errstate(over="raise"):  # the log column is exponentiated without overflow
        y = mix.draw(np.random.RandomState(1), 200)
    assert np.all(np.isfinite(y))
    ok = np.random.default_rng(2).normal(size=(50, 3))
    assert np.array_equal(finite_proposals(ok), ok)


def _ar1(n, walkers, dims, phi, rng):
    """Stationary AR(1) series (n, walkers, dims) of unit variance: integrated time (1 + φ)/(1 − φ)."""
    x = np.empty((n, walkers, dims))
    x[0] = rng.standard_normal((walkers, dims))
    e = rng.standard_normal((n, walkers, dims)) * np.sqrt(1 - phi**2)
    for t in range(1, n):
        x[t] = phi * x[t - 1] + e[t]
    return x


def test_tau_is_that_of_the_kept_draws_not_of_the_climb_before_them():
    """A chain that climbs for its first fifth (a drift of 30 sd, as walkers started 40 nats below the posterior
    do) and then mixes with τ = 19 steps: τ is estimated on the draws kept, and the length rule and convergence
    follow it. Negative control: the same climb spread over the whole chain is never stationary, and its τ stays
    that of the drift (hundreds of steps)."""
    from bayestouch.inference.sampler import _tau_and_burn

    rng = np.random.default_rng(7)
    n, w, d, phi = 4000, 32, 3, 0.9  # τ = 1.9 / 0.1 = 19
    x = _ar1(n, w, d, phi, rng)
    climb = np.clip(1 - np.arange(n) / (0.2 * n), 0, None)[:, None, None] * 30.0
    tau, burn, length = _tau_and_burn(x - climb, adapt=False)
    assert burn >= 0.2 * n and length == n - burn  # the climb's apparent τ (> 2 τ) sets a burn-in past it
    assert np.all(np.abs(tau - 19) < 4), tau  # emcee's estimator on 2000 × 32 draws: a few % error
    assert length > 50 * tau.max()
    # before: τ over the whole chain, climb included
    from bayestouch.inference.sampler import integrated_time

    assert integrated_time(x - climb).max() > 150
    drift = np.linspace(30, 0, n)[:, None, None]
    tau_d, _, length_d = _tau_and_burn(x - drift, adapt=False)
    assert tau_d.max() > 100 and length_d < 50 * tau_d.max(), tau_d


def test_burn_in_lasts_until_the_last_walker_reaches_the_typical_set():
    """A walker that climbs for 1,500 of 4,000 steps while the rest start in the typical set: the burn-in runs past
    its climb (the other walkers alone would have allowed 1,000 steps); an ensemble started in the typical set
    arrives within a few steps; a walker that never arrives keeps only the second half."""
    from bayestouch.inference.sampler import _tau_and_burn, arrival_step

    rng = np.random.default_rng(8)
    n, w = 4000, 32
    lp = rng.standard_normal((n, w)) * 2.5  # a 13-parameter posterior's log-density: sd √(13/2)
    assert arrival_step(lp) < 20
    late = lp.copy()
    late[:, 5] -= np.clip(1 - np.arange(n) / 1500, 0, None) * 40
    assert 1300 < arrival_step(late) <= 1500
    x = _ar1(n, w, 2, 0.5, rng)
    _, burn, _ = _tau_and_burn(x, adapt=False, log_prob=lp)
    _, burn_late, _ = _tau_and_burn(x, adapt=False, log_prob=late)
    assert burn == n // 4 and 1300 < burn_late <= 1500
    stuck = lp.copy()
    stuck[:, 5] -= 40
    assert arrival_step(stuck) == n
    assert _tau_and_burn(x, adapt=False, log_prob=stuck)[1] == n // 2


def test_a_falling_autocorrelation_time_counts_as_settled_a_growing_one_does_not():
    """The length rule trusts τ_max only once it has stopped growing between checks. A chain whose kernel speeds up
    (an adaptive proposal refitted: the first 1,500 steps mix with τ ≈ 66, the rest with τ = 9) shows a τ_max that
    falls from one check to the next, by far more than 5 %: settled (the earlier two-sided rule refused it and kept
    users'-like fits running thousands of steps past R-hat and ESS). The same two estimates in the other order, a
    τ_max still growing, are not settled (negative control), nor is a non-finite one."""
    from bayestouch.inference.sampler import TAU_GROWTH, integrated_time, tau_settled

    rng = np.random.default_rng(3)
    x = np.concatenate([_ar1(1500, 32, 2, 0.97, rng), _ar1(3000, 32, 2, 0.8, rng)])
    early = integrated_time(x[500:2000])  # a check's kept stretch (burn-in a quarter) at 2,000 steps
    late = integrated_time(x[1125:4500])  # and at 4,500
    assert late.max() < (1 - 2 * TAU_GROWTH) * early.max(), (early, late)
    assert tau_settled(late, early)
    assert not tau_settled(early, late)
    assert tau_settled(early * 1.04, early) and not tau_settled(early * 1.06, early)
    assert not tau_settled(np.array([np.nan, 3.0]), early) and not tau_settled(late, np.array([np.inf, 1.0]))
